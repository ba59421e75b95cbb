"""`warp-hair gradcheck`: render_grad against finite differences of the loss, on a tiny sparse scene."""

import re

import pytest
from helpers.scenes import SPARSE_HAIR, sparse_scene_dict, toml_text

from warp_hair.cli import main
from warp_hair.gradcheck import GradcheckRow, gradcheck, target_hair

# 12×12 px, the gradient checks' sparse scene at 16 spp (helpers.scenes.sparse_scene_dict).
SPARSE_SCENE = toml_text(sparse_scene_dict(SPARSE_HAIR, (12, 12), spp=16))


@pytest.fixture
def sparse_scene_file(tmp_path):
    path = tmp_path / "sparse.toml"
    path.write_text(SPARSE_SCENE)
    return path


def test_gradcheck_prints_a_row_per_control(sparse_scene_file, capsys):
    # 16 seed pairs: the verdict's standard error comes from their spread, and the differences are heavy-tailed
    # (a step of η flips lobe choices of the BSDF samples that bring this scene's sky): with 4 pairs (3 degrees of
    # freedom) η's row once read 5.7 standard errors off where 16 read 2.3.
    assert main(["gradcheck", str(sparse_scene_file), "--spp", "64", "--seeds", "16", "--params", "albedo,eta"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line for line in out.splitlines() if re.match(r"(albedo\[[rgb]\]|eta)\s", line)}
    assert set(rows) == {"albedo[r]", "albedo[g]", "albedo[b]", "eta"}, out
    for _control, line in rows.items():
        assert line.split()[-1] == "OK", out
    assert "4/4 OK" in out


def test_unknown_control_exits_2(sparse_scene_file, capsys):
    assert main(["gradcheck", str(sparse_scene_file), "--params", "albedo,bogus"]) == 2
    err = capsys.readouterr().err
    assert "warp-hair: error:" in err and "'bogus'" in err


def test_step_outside_the_range_is_an_error(sparse_scene_file, capsys):
    assert main(["gradcheck", str(sparse_scene_file), "--params", "beta_m", "--eps", "0.5"]) == 2
    assert "use a smaller --eps" in capsys.readouterr().err


def test_target_perturbation():
    scene = load_scene_from_text(SPARSE_SCENE)
    moved = target_hair(scene.hair, ["albedo", "beta_m", "alpha", "eta"])
    assert moved.albedo == pytest.approx((0.63, 0.45, 0.27))
    assert (moved.beta_m, moved.alpha, moved.eta) == pytest.approx((0.35, 5.0, 1.60))
    assert (moved.beta_n, moved.r_roughness_scale) == (0.35, 1.5)  # unchecked controls stay
    # An upward step that would leave the range is taken downward.
    assert target_hair(scene.hair.replace(beta_m=0.98), ["beta_m"]).beta_m == pytest.approx(0.93)


def test_verdict_rule():
    row = GradcheckRow("eta", "eta", None, 0.04, grad=1.02, grad_se=0.1, fd=1.0, fd_se=0.1, se=0.001)
    assert row.ok  # within 3%
    row = GradcheckRow("eta", "eta", None, 0.04, grad=1.2, grad_se=0.1, fd=1.0, fd_se=0.1, se=0.1)
    assert row.ok and row.z == pytest.approx(2.0)  # within 3 SE
    row = GradcheckRow("eta", "eta", None, 0.04, grad=1.5, grad_se=0.1, fd=1.0, fd_se=0.1, se=0.1)
    assert not row.ok and row.relative_difference == pytest.approx(0.5)


def test_gradcheck_needs_two_seeds():
    with pytest.raises(ValueError, match="seeds must be at least 2"):
        gradcheck(load_scene_from_text(SPARSE_SCENE), ["eta"], seeds=1)


def load_scene_from_text(text):
    import tomllib

    from warp_hair.scene import scene_from_dict

    return scene_from_dict(tomllib.loads(text))
