"""The batch manifest: a TOML file listing the work, read into jobs.

    [batch]
    output = "looks_out"       # results beside the manifest (default: <manifest stem>_out)
    cpus_per_job = 1           # CPUs each job declares to Ray, and the Warp threads it renders with
    retries = 2                # times a job is rerun after its worker died (killed, out of memory)

    [defaults.fit]             # settings every [[fit]] starts from (the same keys as [[fit]])
    iters = 60

    [[fit]]
    target = "black_straight"  # a shipped target or a directory, relative to the manifest
    name = "black"             # optional: the job's name and results folder (default: the target's name)
    fit = ["albedo", "beta_m", "beta_n"]
    spp = 16                   # iters, spp, loss, lr, seed, patience, refine, batch, model_error as `warp-hair fit`
    init = { beta_m = 0.4 }    # start values; fix = { alpha = 2.0 } overrides controls not fitted
    export = ["mitsuba", "pbrt"]

    [[render]]
    scene = "swatch.toml"      # spp, seed (default: the scene's [render]), exposure of the PNG preview
    split = 4                  # jobs the image is split into (each renders every 4th range of pixels)

    [[calibrate]]
    scene = "block.toml"       # sigma_a, beta_n (the grid), spp, seed as `warp-hair calibrate`

Each job gets a key: a hash of its settings, the contents of its input files and warp-hair's version. A job whose
results carry the same key is finished and a rerun skips it; change a setting, a target's image or the version,
and it runs again.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import warp_hair
from warp_hair.io import read_toml

from ..latents import SPECS

KINDS = ("fit", "render", "calibrate")
BATCH_KEYS = {"output", "cpus_per_job", "retries"}
FIT_KEYS = {
    "name",
    "target",
    "fit",
    "iters",
    "spp",
    "loss",
    "lr",
    "seed",
    "patience",
    "refine",
    "batch",
    "model_error",
    "init",
    "fix",
    "export",
}
RENDER_KEYS = {"name", "scene", "spp", "seed", "split", "exposure"}
CALIBRATE_KEYS = {"name", "scene", "sigma_a", "beta_n", "spp", "seed"}
KEYS = {"fit": FIT_KEYS, "render": RENDER_KEYS, "calibrate": CALIBRATE_KEYS}
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
DEFAULT_RETRIES = 2


@dataclass(frozen=True)
class Job:
    """One Ray task's worth of work. A split render is several jobs (its parts) with one `group`."""

    name: str  # unique in the batch: its results are OUT/jobs/<name>/ (a split render's parts: <group>.part<k>of<n>)
    kind: str  # "fit", "render" (a part of one) or "calibrate"
    spec: dict  # the manifest's table with the defaults applied and paths resolved
    key: str  # settings + inputs + version: results with another key are stale
    group: str  # the manifest entry's name (a render's parts share it)
    part: tuple = (0, 1)  # (k, n): the k-th of a render's n parts


@dataclass
class Manifest:
    path: Path
    output: Path
    cpus_per_job: int
    retries: int
    jobs: list = field(default_factory=list)

    def groups(self) -> dict:
        """Manifest entry name → its jobs, in manifest order."""
        out: dict = {}
        for job in self.jobs:
            out.setdefault(job.group, []).append(job)
        return out


def load_manifest(path, output=None) -> Manifest:
    """Read and check a manifest; a ValueError names the file, the entry and the key of any problem."""
    path = Path(path)
    data = read_toml(path, "manifest")
    unknown = sorted(set(data) - {"batch", "defaults", *KINDS})
    if unknown:
        raise ValueError(
            f"{path}: unknown table(s) {unknown}; a manifest has [batch], [defaults.fit|render|calibrate] "
            "and [[fit]], [[render]], [[calibrate]] entries"
        )
    batch = _table(data.get("batch", {}), f"{path} [batch]")
    _check_keys(batch, BATCH_KEYS, f"{path} [batch]")
    base = path.parent
    out = Path(output) if output is not None else base / batch.get("output", f"{path.stem}_out")
    manifest = Manifest(
        path=path,
        output=out,
        cpus_per_job=_integer(batch.get("cpus_per_job", 1), f"{path} [batch] cpus_per_job", 1),
        retries=_integer(batch.get("retries", DEFAULT_RETRIES), f"{path} [batch] retries", 0),
    )
    defaults = _table(data.get("defaults", {}), f"{path} [defaults]")
    _check_keys(defaults, set(KINDS), f"{path} [defaults]")
    for kind in KINDS:
        default = _table(defaults.get(kind, {}), f"{path} [defaults.{kind}]")
        _check_keys(default, KEYS[kind] - {"name", "target", "scene"}, f"{path} [defaults.{kind}]")
        entries = data.get(kind, [])
        if not isinstance(entries, list):
            raise ValueError(f"{path}: {kind} must be an array of tables ([[{kind}]]), got a {type(entries).__name__}")
        for index, entry in enumerate(entries):
            where = f"{path} [[{kind}]] #{index + 1}"
            entry = {**default, **_table(entry, where)}
            _check_keys(entry, KEYS[kind], where)
            jobs = _jobs(kind, entry, base, where)
            if jobs[0].group in {job.group for job in manifest.jobs}:
                raise ValueError(
                    f"{where}: another entry is named {jobs[0].group!r} too (names default to the "
                    "target's or scene's); give one of them another name = \"...\""
                )
            manifest.jobs.extend(jobs)
    if not manifest.jobs:
        raise ValueError(f"{path}: the manifest lists no work: add [[fit]], [[render]] or [[calibrate]] entries")
    return manifest


def _jobs(kind: str, entry: dict, base: Path, where: str) -> list:
    if kind == "fit":
        from ..target import resolve_target

        if "target" not in entry:
            raise ValueError(f"{where}: missing key 'target' (a shipped target's name or a target directory)")
        given = str(entry["target"])
        try:  # a missing target fails its job (load_inputs says so), not the manifest
            directory = resolve_target(str(base / given) if (base / given).exists() else given).resolve()
        except FileNotFoundError:
            directory = base / given
        spec = {**entry, "target": str(directory)}
        spec["fit"] = _names(spec.get("fit", None), f"{where} fit")
        spec["export"] = _names(spec.get("export", []), f"{where} export")
        for option in ("init", "fix"):
            spec[option] = _controls(spec.get(option, {}), f"{where} {option}")
        inputs = sorted(p for p in directory.iterdir() if p.is_file()) if directory.is_dir() else []
        name = _name(entry.get("name", directory.name), where)
        return [Job(name, kind, spec, _key(kind, spec, inputs), name)]
    if "scene" not in entry:
        raise ValueError(f"{where}: missing key 'scene' (a scene file, relative to the manifest)")
    scene = (base / str(entry["scene"])).resolve()
    spec = {**entry, "scene": str(scene)}
    # A missing scene, or a bad spp or seed, fails its job (jobs.load_inputs), as a fit's bad values do.
    inputs = [scene, *_scene_files(scene)] if scene.is_file() else []
    name = _name(entry.get("name", scene.stem), where)
    if kind == "calibrate":
        return [Job(name, kind, spec, _key(kind, spec, inputs), name)]
    split = _integer(spec.pop("split", 1), f"{where} split", 1)
    key = _key(kind, {**spec, "split": split}, inputs)
    if split == 1:
        return [Job(name, kind, spec, key, name)]
    return [Job(f"{name}.part{k}of{split}", kind, spec, key, name, (k, split)) for k in range(split)]


def _scene_files(scene: Path) -> list:
    """The files a scene file names ([fibers] file, [[lights]] file): part of what a render depends on."""
    try:
        data = tomllib.loads(scene.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []  # load_scene reports it, with its own words
    tables = [data.get("fibers", {}), *data.get("lights", [])]
    files = [scene.parent / t["file"] for t in tables if isinstance(t, dict) and isinstance(t.get("file"), str)]
    return [f for f in files if f.is_file()]


def _key(kind: str, spec: dict, inputs) -> str:
    digest = hashlib.sha256(json.dumps([kind, spec, warp_hair.__version__], sort_keys=True, default=str).encode())
    for path in inputs:
        digest.update(path.name.encode())
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:16]


def _name(value, where: str) -> str:
    if not isinstance(value, str) or not NAME.match(value):
        raise ValueError(f"{where}: name {value!r} must be letters, digits, '_', '-' or '.' (it names a folder)")
    return value


def _names(value, where: str):
    if value is None:
        return None
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{where}: must be a list of names or a comma-separated string, got {value!r}")
    return value


def _controls(value, where: str) -> dict:
    table = _table(value, where)
    unknown = sorted(set(table) - set(SPECS))
    if unknown:
        raise ValueError(f"{where}: unknown control(s) {unknown}; allowed: {list(SPECS)}")
    return table


def _table(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise ValueError(f"{where}: must be a table, got {type(value).__name__}")
    return dict(value)


def _check_keys(table: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _integer(value, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{where} must be a whole number >= {minimum}, got {value!r}")
    return value
