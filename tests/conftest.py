"""Fixtures shared by the test files; the shared code they use is in tests/helpers/."""

import pytest
from helpers.scenes import TINY_SCENE


@pytest.fixture
def tiny_scene(tmp_path):
    """The command-line tests' 12×8 scene (helpers.scenes.TINY_SCENE) as a file."""
    path = tmp_path / "tiny.toml"
    path.write_text(TINY_SCENE)
    return path
