"""The shipped fit targets, as package data: each subdirectory is a target (optimize/target.py describes the layout).

    import targets
    targets.names()                  # ["auburn_curly", "black_straight", ...]
    targets.path("black_straight")   # the directory, in the source checkout or the installed package

The directories are found through importlib.resources, so they are the same in a source checkout, an editable
install and an installed wheel. Only a source checkout's copy is meant to be rewritten (`warp-hair targets make`):
`is_source_checkout()` tells which one this is.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

TARGET_FILE = "target.toml"


def root() -> Path:
    """The directory holding the shipped targets."""
    files = resources.files(__name__)
    if not isinstance(files, Path):
        raise RuntimeError(f"the shipped targets ({files}) are not a directory on disk; install warp-hair unzipped")
    return files


def names() -> list[str]:
    """The shipped targets' names, sorted."""
    return sorted(p.name for p in root().iterdir() if (p / TARGET_FILE).is_file())


def path(name: str) -> Path:
    """The directory of the shipped target `name`; FileNotFoundError naming the shipped ones if there is none."""
    directory = root() / name
    if not name or "/" in name or "\\" in name or not (directory / TARGET_FILE).is_file():
        raise FileNotFoundError(f"{name}: not a shipped target (shipped: {', '.join(names())})")
    return directory


def is_source_checkout() -> bool:
    """Whether the shipped targets are a source checkout's (beside pyproject.toml), not an installed package's."""
    return (root().parent / "pyproject.toml").is_file()
