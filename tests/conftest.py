"""Fixtures shared by the test files; the shared code they use is in tests/helpers/."""

import pytest
import warp as wp
from helpers.scenes import TINY_SCENE

# The test program's own choice (the library leaves Warp's log level alone): Warp logs every module load at INFO.
wp.config.log_level = wp.LOG_WARNING


@pytest.fixture
def tiny_scene(tmp_path):
    """The command-line tests' 12×8 scene (helpers.scenes.TINY_SCENE) as a file."""
    path = tmp_path / "tiny.toml"
    path.write_text(TINY_SCENE)
    return path
