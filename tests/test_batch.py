"""`warp-hair batch` on a real local Ray cluster (one node on this machine, 2 CPUs), and its report in a real
headless Chromium.

The batch's fits are the shipped targets at short settings: the properties tested (the same fitted values as the
same fits run one by one, bit for bit; every job done after a worker is killed; a rerun doing nothing again; a
split render equal to one machine's) do not depend on how good the fits are. Without Ray (the `cluster` extra) or
Chromium (Debian's `chromium`) the tests that need them skip, saying so; CI installs both (.ci/run).
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from test_calibrate import BETA_N, BLOCK_TOML

import targets
from optimize import FitSettings, fit, load_target
from optimize.batch import load_manifest, run_batch, store
from optimize.batch.report import number, sigma
from optimize.batch.split import assemble, part_pixels
from warp_hair.io import read_exr
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

wp.config.quiet = True

SHORT = {"iters": 4, "spp": 4, "refine": 1}
FITS = ("black_straight", "blonde_straight")
SCENE = targets.path("black_straight") / "scene_front.toml"

MANIFEST = f"""
[batch]
cpus_per_job = 1

[defaults.fit]
iters = {SHORT["iters"]}
spp = {SHORT["spp"]}
refine = {SHORT["refine"]}

[[fit]]
target = "black_straight"
export = ["mitsuba", "pbrt"]

[[fit]]
target = "blonde_straight"

[[fit]]
target = "black_straight"
name = "bad_loss"
loss = "l3"

[[render]]
scene = "{SCENE}"
name = "front"
spp = 8
split = 3

[[calibrate]]
scene = "block.toml"
sigma_a = [0.01, 0.1]
beta_n = {list(BETA_N)}
"""


def ray_module():
    return pytest.importorskip("ray", reason="warp-hair batch needs Ray: pip install -e '.[cluster]'")


@pytest.fixture(scope="module")
def cluster():
    """A local Ray cluster of one node with 2 CPUs; yields its address, for a second driver to join."""
    ray = ray_module()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def one_by_one():
    """The batch's fits run one by one in this process, with all its threads."""
    return {name: fit(load_target(targets.path(name)), FitSettings(**SHORT), progress=False) for name in FITS}


@pytest.fixture(scope="module")
def batch(cluster, tmp_path_factory):
    folder = tmp_path_factory.mktemp("batch")
    (folder / "block.toml").write_text(BLOCK_TOML)
    (folder / "looks.toml").write_text(MANIFEST)
    manifest = load_manifest(folder / "looks.toml")
    return manifest, run_batch(manifest, progress=False)


def test_a_split_render_is_the_whole_render_bit_for_bit():
    scene = load_scene(SCENE)
    whole = render(scene, spp=4, seed=7, threads=2)
    pieces = []
    for k, threads in zip(range(3), (1, 2, 1)):  # the parts with different thread counts, as workers would
        pixels = part_pixels(scene.camera.resolution, k, 3)
        image, stderr = render(scene, spp=4, seed=7, threads=threads, pixels=pixels, return_stderr=True)
        pieces.append((pixels, image.reshape(-1, 3)[pixels], stderr.reshape(-1, 3)[pixels]))
    assert np.array_equal(assemble(scene.camera.resolution, pieces)[0], whole)
    with pytest.raises(ValueError, match="cover 2304 of 2304 pixels \\(768 more than once\\)"):
        assemble(scene.camera.resolution, pieces + pieces[:1])


@pytest.mark.parametrize(
    "text, message",
    [
        ("[[fit]]\ntarget = 'black_straight'\nitres = 3\n", r"\[\[fit\]\] #1: unknown key\(s\) \['itres'\]"),
        (
            "[batch]\nretries = -1\n[[fit]]\ntarget = 'black_straight'\n",
            r"\[batch\] retries must be a whole number >= 0",
        ),
        (
            "[[fit]]\ntarget = 'black_straight'\n[[fit]]\ntarget = 'black_straight'\n",
            "another entry is named 'black_straight'",
        ),
        ("[[render]]\nscene = 'a.toml'\nsplit = 0\n", r"\[\[render\]\] #1 split must be a whole number >= 1, got 0"),
        ("[[fit]]\ntarget = 'black_straight'\nname = '../x'\n", "name '../x' must be letters"),
        ("[batch]\n", "the manifest lists no work"),
        ("[[fits]]\n", r"unknown table\(s\) \['fits'\]"),
    ],
)
def test_manifest_errors_name_the_entry_and_key(tmp_path, text, message):
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_manifest(path)


def test_command_line_errors(tmp_path, capsys):
    from optimize.cli import main

    assert main(["batch", str(tmp_path / "none.toml")]) == 2
    assert "none.toml: manifest not found" in capsys.readouterr().err
    (tmp_path / "m.toml").write_text("[[fit]]\ntarget = 'black_straight'\n")
    assert main(["batch", str(tmp_path / "m.toml"), "--cpus-per-job", "0"]) == 2
    assert "--cpus-per-job must be a whole number >= 1, got 0" in capsys.readouterr().err


def test_batch_fits_equal_the_same_fits_run_one_by_one(batch, one_by_one):
    manifest, outcome = batch
    assert sorted(outcome.failed) == ["bad_loss"] and not outcome.interrupted
    status = store.read_status(manifest.output, "bad_loss")
    assert "unknown loss 'l3'" in status["error"]  # a project error, reported for its job alone
    for name, result in one_by_one.items():
        params = json.loads((store.job_dir(manifest.output, name) / "params.json").read_text())
        assert params["fitted"] == result.values and params["uncertainty"] == result.uncertainties
        assert store.read_status(manifest.output, name)["threads"] == 1  # its declared CPUs, not the node's
    assert (store.job_dir(manifest.output, "black_straight") / "hair_mitsuba.xml").is_file()
    summary = {row["name"]: row for row in json.loads((manifest.output / "summary.json").read_text())}
    assert summary["black_straight"]["fitted"] == one_by_one["black_straight"].values
    assert summary["front"]["status"] == "done" and summary["block"]["status"] == "done"
    assert summary["bad_loss"]["status"] == "failed"
    csv = (manifest.output / "summary.csv").read_text().splitlines()
    assert csv[0].startswith("name,kind,status,seconds,error") and "albedo.r.sigma" in csv[0] and len(csv) == 6


def test_split_render_in_the_batch_is_one_machines_render(batch):
    manifest, _ = batch
    image, metadata = read_exr(store.job_dir(manifest.output, "front") / "image.exr")
    scene = load_scene(SCENE)
    assert metadata["warp_hair"]["spp"] == 8
    assert np.array_equal(image, render(scene, spp=8, seed=scene.render.seed))


def test_a_rerun_does_no_finished_work_again(batch):
    manifest, first = batch
    stamps = {name: (store.job_dir(manifest.output, name) / "status.json").stat().st_mtime_ns for name in first.done}
    again = run_batch(load_manifest(manifest.path), progress=False)
    assert again.done == [] and sorted(again.skipped) == sorted(first.done) and again.failed == ["bad_loss"]
    assert stamps == {
        name: (store.job_dir(manifest.output, name) / "status.json").stat().st_mtime_ns for name in first.done
    }


def test_a_worker_killed_mid_batch_costs_one_retry(cluster, one_by_one, tmp_path):
    (tmp_path / "m.toml").write_text(MANIFEST.split('[[fit]]\ntarget = "black_straight"\nname')[0])
    manifest = load_manifest(tmp_path / "m.toml")
    killed = []

    def kill_one_fit():
        deadline = time.time() + 120
        while time.time() < deadline and not killed:
            for pid, title in _task_processes("ray::warp-hair fit"):
                time.sleep(1.0)  # mid-job
                os.kill(pid, signal.SIGKILL)
                killed.append((pid, title))
                return
            time.sleep(0.1)

    killer = threading.Thread(target=kill_one_fit)
    killer.start()
    outcome = run_batch(manifest, progress=False)
    killer.join()
    assert killed, "no fit task was seen running"
    assert sorted(outcome.done) == sorted(FITS) and outcome.failed == []
    for name, result in one_by_one.items():
        status = store.read_status(manifest.output, name)
        assert status["pid"] != killed[0][0]  # finished by another worker ...
        params = json.loads((store.job_dir(manifest.output, name) / "params.json").read_text())
        assert params["fitted"] == result.values  # ... with the same result


def test_ctrl_c_stops_within_seconds_and_keeps_what_finished(cluster, tmp_path):
    (tmp_path / "m.toml").write_text(f"""
[[render]]
scene = "{SCENE}"
spp = 1

[[fit]]
target = "black_straight"
iters = 1000
refine = 0
""")
    command = [sys.executable, "-m", "optimize.cli", "batch", str(tmp_path / "m.toml"), "--address", cluster]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    render_done = store.job_dir(tmp_path / "m_out", "scene_front") / "status.json"
    deadline = time.time() + 120
    while time.time() < deadline and not (render_done.exists() and _task_processes("ray::warp-hair fit")):
        assert process.poll() is None, process.communicate()
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    start = time.time()
    _, err = process.communicate(timeout=30)
    assert time.time() - start < 10 and process.returncode == 130, err
    assert json.loads(render_done.read_text())["status"] == "done"
    summary = {row["name"]: row["status"] for row in json.loads((tmp_path / "m_out" / "summary.json").read_text())}
    assert summary == {"scene_front": "done", "black_straight": "pending"}
    # Ray stops a cancelled task's worker asynchronously; on a loaded machine that can take a while. (The check
    # sees every Ray worker on the machine: it assumes no other batch runs beside the suite.)
    deadline = time.time() + 30
    while _task_processes("ray::warp-hair fit") and time.time() < deadline:
        time.sleep(0.2)
    assert not _task_processes("ray::warp-hair fit")  # the cancelled task's worker was stopped


def test_the_report_shows_every_image_and_number_in_a_browser(batch, tmp_path):
    manifest, _ = batch
    seen = _open_in_chromium(manifest.output / "report.html", tmp_path)
    assert len(seen["images"]) == 2 * 3 + 2 * 3 + 2 + 1  # thumbnails of 2 fits' 2 images, 2 plots, 1 preview
    assert all(image["complete"] and image["width"] > 0 for image in seen["images"]), seen["images"]
    text = seen["text"]
    for row in json.loads((manifest.output / "summary.json").read_text()):
        assert row["name"] in text
        if row["kind"] == "fit" and row["status"] == "done":
            for key, show in (("fitted", number), ("sigma", sigma), ("true", number)):
                for value in row[key].values():
                    for v in np.atleast_1d(value):
                        assert show(v) in text, (row["name"], key, show(v))
        if row["status"] == "failed":
            assert row["error"] in text
    assert '<bsdf type="hair"' in text and 'Material "hair"' in text  # the export snippets
    assert "P(β_n) coefficients" in text


CHECK = """<script>window.addEventListener("load", () => {
  const images = Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete, width: i.naturalWidth}));
  const out = document.createElement("pre");
  out.id = "browser-check";
  out.textContent = JSON.stringify({images: images, text: document.body.innerText});
  document.body.appendChild(out);
});</script>"""


def _open_in_chromium(page: Path, tmp_path: Path) -> dict:
    """What Chromium loaded and shows of `page`: each image's state, and the page's rendered text. A copy of the
    page with a script that writes them into the page once it has loaded, dumped by headless Chromium."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("Chromium is not installed (apt-get install chromium); the report's browser check needs it")
    copy = tmp_path / "report_checked.html"
    copy.write_text(page.read_text(encoding="utf-8").replace("</body>", CHECK + "</body>"), encoding="utf-8")
    result = subprocess.run(
        [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=10000",
            f"--user-data-dir={tmp_path / 'chromium'}",
            "--dump-dom",
            copy.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    found = re.search(r'<pre id="browser-check">(.*?)</pre>', result.stdout, re.S)
    assert found, result.stderr[-2000:]
    return json.loads(html.unescape(found.group(1)))


def _task_processes(prefix: str) -> list:
    """(pid, title) of the Ray workers whose process title starts with `prefix` (Ray titles a worker with the
    task it runs: "ray::<task name>")."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                title = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
            except OSError:
                continue
            if title.startswith(prefix):
                found.append((int(entry), title))
    return found
