"""What a job is made of and what it does: inputs loaded on the driver, the work done on a worker.

The driver loads each job's inputs (`load_inputs`: a fit's Target and FitSettings, a render's or calibration's
Scene), so that bad input is reported for that job before anything runs, and the loaded objects travel to the
workers through Ray's object store: a worker needs warp-hair installed, not the manifest's files. A worker runs
`execute` and returns its results as {file name: bytes}; the driver writes them beside the manifest. A project
error (bad input, an unwritable file, out of memory) comes back as {"error": message}, the CLI's words for it;
anything else is a bug and reaches the driver as Ray's task error.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import tempfile
from pathlib import Path

import numpy as np

import warp_hair

# The errors that are the user's to fix, as the command line sorts them (warp_hair/cli.py main).
PROJECT_ERRORS = (ValueError, OSError, MemoryError)
FIT_OPTIONS = ("iters", "spp", "loss", "lr", "seed", "patience", "refine", "batch", "model_error")


def load_inputs(job):
    """The job's payload for `execute`: (Target, FitSettings) for a fit, the Scene otherwise. Its values are
    checked here, as a fit's are, so that a bad one fails its job alone, before anything runs."""
    if job.kind == "fit":
        return _fit_inputs(job.spec)
    from warp_hair.scene import load_scene

    scene = load_scene(job.spec["scene"])
    render_sampling(job, scene)
    if job.kind == "calibrate":
        from warp_hair.calibrate import DEFAULT_BETA_N, DEFAULT_SIGMA_A, check_grid

        check_grid(job.spec.get("sigma_a", DEFAULT_SIGMA_A), job.spec.get("beta_n", DEFAULT_BETA_N))
    return scene


def _fit_inputs(spec: dict):
    from warp_hair.export import parse_renderers

    from ..fit import FitSettings, check_settings
    from ..latents import DEFAULT_FIT, as_values
    from ..target import fix_controls, load_target

    target = load_target(spec["target"])
    options = {key: spec[key] for key in FIT_OPTIONS if key in spec}
    if options.get("batch") == "all":
        options["batch"] = None
    controls = tuple(spec["fit"] or DEFAULT_FIT)
    init = {name: as_values(name, v) for name, v in spec["init"].items()}
    fixed = {name: as_values(name, v) for name, v in spec["fix"].items()}
    both = sorted(set(fixed) & set(controls))
    if both:
        raise ValueError(f"control(s) {both} are both fixed (fix) and fitted (fit); choose one")
    if fixed:
        fix_controls(target, fixed)
    settings = FitSettings(controls=controls, init=init, **options)
    check_settings(target, settings)
    if spec["export"]:
        parse_renderers(",".join(spec["export"]))
    return target, settings


def execute(job, payload, threads: int, version: str) -> dict:
    """Run `job` with `threads` Warp (and torch) threads, the CPUs its task declared; {"files": {name: bytes}}
    or {"error": message}."""
    if version != warp_hair.__version__:
        return {
            "error": f"this worker has warp-hair {warp_hair.__version__}, the driver {version}: install the "
            f"same version on every node"
        }
    import torch

    torch.set_num_threads(threads)
    try:
        if job.kind == "fit":
            return _fit(job, *payload, threads)
        if job.kind == "render":
            return {"files": _render_part(job, payload, threads)}
        return {"files": _calibrate(job, payload, threads)}
    except MemoryError:
        return {"error": "out of memory; lower the resolution, spp or fiber count, or give the job a larger node"}
    except PROJECT_ERRORS as error:
        return {"error": str(error)}


def _fit(job, target, settings, threads: int) -> dict:
    """{"files": what `warp-hair fit` writes, the exports and the thumbnails}, and for a fit that failed
    (verdict.py) its reasons as the job's error: its files stay to be looked at, its numbers are no result."""
    from warp_hair.export import default_filename, export

    from ..fit import fit
    from ..report import write_outputs

    # The object store hands out read-only arrays; the fit's torch tensors want their own, writable copies.
    target = copy.deepcopy(target)
    settings = dataclasses.replace(settings, threads=threads)
    result = fit(target, settings, progress=False)
    if result.stop_reason == "interrupted":  # a fit stopped from outside is no result: the job is not finished
        raise KeyboardInterrupt
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        # The report's thumbnails are comparison.png's panels (report.write_thumbnails).
        params = write_outputs(folder, result, target, settings, thumbnails=True)[0]
        for renderer in job.spec["export"]:
            export(params, to=renderer, path=folder / default_filename(renderer))
        files = {p.name: p.read_bytes() for p in sorted(folder.iterdir())}
    if result.failed:
        return {"files": files, "error": "the fit failed: " + "; ".join(result.failures)}
    return {"files": files}


def render_sampling(job, scene) -> tuple:
    """(spp, seed) of a render or calibration job: the manifest's, else the scene's [render] table; a ValueError
    names the bad one."""
    from warp_hair.renderer.prepare import sampling

    return sampling(scene, job.spec.get("spp"), job.spec.get("seed"))


def _render_part(job, scene, threads: int) -> dict:
    """A split render's part: its pixels' values, for the driver to put together; an unsplit render: its files."""
    from warp_hair.renderer.render import render

    from .split import part_pixels

    spp, seed = render_sampling(job, scene)
    if job.part[1] == 1:
        return render_files(job, scene, *render(scene, spp=spp, seed=seed, threads=threads, return_stderr=True))
    pixels = part_pixels(scene.camera.resolution, *job.part)
    image, stderr = render(scene, spp=spp, seed=seed, threads=threads, pixels=pixels, return_stderr=True)
    buffer = io.BytesIO()
    np.savez(buffer, pixels=pixels, image=image.reshape(-1, 3)[pixels], stderr=stderr.reshape(-1, 3)[pixels])
    return {"part.npz": buffer.getvalue()}


def render_files(job, scene, image, stderr) -> dict:
    """A render's results, {file name: bytes}: image.exr (with the render's metadata), stderr.exr, preview.png."""
    from warp_hair.io import write_exr, write_png
    from warp_hair.renderer.render import render_metadata

    spp, seed = render_sampling(job, scene)
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        write_exr(folder / "image.exr", image, render_metadata(scene, spp, seed))
        write_exr(folder / "stderr.exr", stderr)
        write_png(folder / "preview.png", image, exposure=job.spec.get("exposure", 1.0))
        return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


def _calibrate(job, scene, threads: int) -> dict:
    import json

    from warp_hair.calibrate import DEFAULT_BETA_N, DEFAULT_SIGMA_A, calibrate, inversion_toml

    result = calibrate(
        scene,
        job.spec.get("sigma_a", DEFAULT_SIGMA_A),
        job.spec.get("beta_n", DEFAULT_BETA_N),
        spp=job.spec.get("spp"),
        seed=job.spec.get("seed"),
        threads=threads,
    )
    record = {
        "coefficients": [float(p) for p in result.coefficients],
        "sigma_a": result.sigma_a.tolist(),
        "beta_n": result.beta_n.tolist(),
        "albedo": result.albedo.tolist(),
        "stderr": result.stderr.tolist(),
        "fitted": result.fitted.tolist(),
        "pixels": result.pixels,
        "chi2_per_dof": result.chi2_per_dof,
    }
    text = f"{result.table()}\n{result.summary()}\n\n{inversion_toml(result.coefficients)}"
    return {"calibration.json": (json.dumps(record, indent=2) + "\n").encode(), "calibration.txt": text.encode()}
