"""The built wheel works on its own: installed in a fresh virtual environment, away from the source checkout,
`warp-hair targets list` finds the shipped targets (package data), every product module imports without the
test-only code, and none of that code (tests/, tests/helpers/: the references, the derivative oracle) is in it.

The fresh environment reuses this one's installed dependencies through a .pth line (no network, no copies) but
not its editable install of warp-hair: a plain path in a .pth file adds the directory without running the
editable finder that lives there.
"""

import shutil
import subprocess
import sys
import sysconfig
import textwrap
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# What the wheel is built from (with this environment's setuptools, the test extra's); the rest of the checkout
# (tests, benchmarks, .venv) stays out of the build.
SOURCES = ("pyproject.toml", "README.md", "warp_hair", "optimize", "targets")
# Imported in the fresh environment: every module of the product, with the test-only code made unimportable.
IMPORT_CHECK = textwrap.dedent(
    """
    import importlib, importlib.abc, pkgutil, sys
    from pathlib import Path

    TEST_ONLY = ("tests", "helpers", "reference_model", "reference_bvh", "sphere", "bsdf_grad")

    class Refuse(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if any(name == t or name.startswith(t + ".") for t in TEST_ONLY):
                raise ImportError(f"the product imports test-only code: {name}")
            return None

    sys.meta_path.insert(0, Refuse())
    import optimize, targets, warp_hair

    venv = Path(sys.prefix).resolve()
    for package in (warp_hair, optimize, targets):
        assert venv in Path(package.__file__).resolve().parents, f"{package.__name__} from {package.__file__}"
    names = [m.name for p in (warp_hair, optimize) for m in pkgutil.walk_packages(p.__path__, p.__name__ + ".")]
    for name in names:
        importlib.import_module(name)
    print(len(names), "modules")
    """
)


def _run(args, cwd, **kwargs):
    result = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=300, **kwargs)
    assert result.returncode == 0, f"{' '.join(map(str, args))}\n{result.stdout}\n{result.stderr}"
    return result.stdout


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from this checkout."""
    base = tmp_path_factory.mktemp("wheel")
    source = base / "source"
    source.mkdir()
    for name in SOURCES:
        item = ROOT / name
        if item.is_dir():
            shutil.copytree(item, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(item, source / name)
    dist = base / "dist"
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-w",
            dist,
            source,
        ],
        cwd=base,
    )
    (built,) = dist.glob("warp_hair-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory):
    """A fresh venv with the wheel installed; returns its bin directory."""
    base = tmp_path_factory.mktemp("venv")
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=base)
    python = venv / "bin" / "python"
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=base).strip())
    here = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "dependencies.pth").write_text("".join(f"{p}\n" for p in sorted(here)))
    _run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps", "--no-index", wheel], cwd=base)
    return venv / "bin"


def _clean_env():
    import os

    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}


def test_installed_wheel_lists_the_shipped_targets(installed, tmp_path):
    import targets

    out = _run([installed / "warp-hair", "targets", "list"], cwd=tmp_path, env=_clean_env())
    listed = [line.split(":")[0] for line in out.splitlines()]
    assert listed == targets.names() and "black_straight" in listed


def test_installed_wheel_imports_without_the_tests(installed, tmp_path):
    out = _run([installed / "python", "-c", IMPORT_CHECK], cwd=tmp_path, env=_clean_env())
    assert int(out.split()[0]) > 40


def test_no_test_code_ships(wheel):
    """Only the three packages and their metadata; no test module, test helper or test-only package among them
    (the test oracle and the references live in tests/helpers/, which the build never sees)."""
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    modules = [n for n in names if n.endswith(".py")]
    assert {n.split("/")[0] for n in modules} == {"warp_hair", "optimize", "targets"}
    test_code = [
        n
        for n in modules
        if {"tests", "testing", "helpers"} & set(n.split("/")[:-1])
        or Path(n).name.startswith("test_")
        or Path(n).name in ("conftest.py", "bsdf_grad.py")
    ]
    assert test_code == [], f"test code in the wheel: {test_code}"
    assert "warp_hair/model/bsdf.py" in modules and "optimize/fit.py" in modules


def test_installed_wheel_does_not_rewrite_its_shipped_targets(installed, tmp_path):
    result = subprocess.run(
        [installed / "warp-hair", "targets", "make", "black_straight"],
        cwd=tmp_path,
        env=_clean_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2
    assert "a shipped target of the installed warp-hair package" in result.stderr and "cp -r" in result.stderr
