"""Other realisations of a generated groom (warp_hair.realisation) and the fit over them (optimize/realisations.py)."""

import dataclasses
import shutil
import warnings

import numpy as np
import pytest
import tomlkit
import torch
from helpers.scenes import front_camera, swatch_scene, toml_text, write_front_back_target

from optimize.fit import FitSettings, check_settings, fit
from optimize.linearize import Linearization, crossed_curvature
from optimize.realisations import Realisations, pooled_jacobians, realisation_spread, realisation_term
from optimize.report import format_table
from optimize.target import load_target, make_target
from warp_hair.geometry.generators import curly, swatch, wavy
from warp_hair.geometry.interpenetration import InterpenetrationWarning
from warp_hair.realisation import realisation, realisation_draw, realisation_views
from warp_hair.renderer.gradients import render_grad
from warp_hair.renderer.prepare import prepare_views
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict
from warp_hair.torch import default_grad_seed, render_torch_pair

LIGHTS = [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}]
HAIR = {"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.35}


def _roots_x(assembly, count):
    return assembly.points.reshape(count, -1, 3)[:, 0, 0]


@pytest.mark.parametrize("generator", [swatch, wavy, curly])
def test_shift_zero_is_the_recipe_as_it_was(generator):
    a = generator(count=40, layers=2, length=0.3, segments=6, seed=5)
    b = generator(count=40, layers=2, length=0.3, segments=6, seed=5, shift=0.0)
    np.testing.assert_array_equal(a.points, b.points)


def test_shift_moves_the_lattice_and_keeps_the_swatch():
    """Without jitter the strands lie on the lattice: a shift moves every strand's axis by shift × spacing modulo
    the layer's width, keeps them left to right in each layer and within the width (plus a spacing's rounding)."""
    count, layers, width = 40, 2, 0.4
    spacing = width / (count // layers)
    plain = _roots_x(swatch(count=count, layers=layers, width=width, jitter=0.0, segments=4), count)
    moved = _roots_x(swatch(count=count, layers=layers, width=width, jitter=0.0, segments=4, shift=0.3), count)
    for layer in range(layers):
        a, b = plain[layer * 20 : (layer + 1) * 20], moved[layer * 20 : (layer + 1) * 20]
        assert np.all(np.diff(b) > 0)  # left to right
        np.testing.assert_allclose(np.diff(b), spacing, rtol=1e-6)  # the assembly holds float32
        # The same lattice, moved: every shifted position is an unshifted one plus 0.3 spacing, modulo the width.
        phase = np.mod((b - a.min()) / spacing - 0.3, 1.0)
        np.testing.assert_allclose(np.minimum(phase, 1 - phase), 0, atol=1e-5)
        assert np.abs(b).max() <= width / 2 * (1 + 1e-6)
    assert not np.allclose(plain, moved)


@pytest.mark.parametrize("shift", [-0.1, 1.0, float("nan")])
def test_bad_shift_names_it(shift):
    with pytest.raises(ValueError, match="shift"):
        swatch(count=10, layers=2, segments=4, shift=shift)


def test_realisation_is_reproducible_and_other_strands():
    scene = swatch_scene(HAIR, LIGHTS, resolution=(8, 8))
    assert realisation(scene, 0) is scene
    one, again, two = realisation(scene, 1), realisation(scene, 1), realisation(scene, 2)
    np.testing.assert_array_equal(one.fibers.points, again.fibers.points)
    assert one.fibers.points.shape == scene.fibers.points.shape
    assert not np.allclose(one.fibers.points, scene.fibers.points)
    assert not np.allclose(one.fibers.points, two.fibers.points)
    assert one.camera == scene.camera and one.hair == scene.hair
    draw = realisation_draw(scene, 1)
    assert set(draw) == {"seed", "shift"} and 0 <= draw["shift"] < 1


def test_a_wavy_swatchs_realisations_keep_where_its_waves_crest():
    """phase_jitter 0: every fiber waves in step, at the swatch's shared phase; another realisation moves the
    strands but not the crests (each strand's sideways swing about its axis is the same function of y)."""
    data = {
        "camera": front_camera(0.3, (8, 8)),
        "lights": LIGHTS,
        "fibers": {"generator": "wavy", "count": 20, "layers": 2, "length": 0.3, "phase_jitter": 0.0, "seed": 9},
        "hair": HAIR,
    }
    scene = scene_from_dict(data)
    other = realisation(scene, 4)

    def swing(assembly):
        x = assembly.points.reshape(20, -1, 3)[..., 0]
        return x - x.mean(axis=1, keepdims=True)  # about each strand's mean: its wave (and its slow wander)

    # The wander (up to jitter/8 of a spacing) differs between realisations; the wave (amplitude 0.02) does not.
    assert np.abs(swing(other.fibers) - swing(scene.fibers)).max() < 0.1 * 0.02 + 2 * 0.25 / 8 * 0.0128
    data["fibers"]["phase"] = realisation_draw(scene, 4)["phase"] + np.pi  # crests half a wave along
    assert np.abs(swing(scene_from_dict(data).fibers) - swing(scene.fibers)).max() > 0.03


def test_realisations_redraw_clumps_strays_and_layer_phases_and_keep_the_recipe():
    """A wavy recipe with clumps, strays and a phase per layer: each realisation draws other clump guides, other
    strays and other phases for the deeper layers, and keeps what the recipe states: four clumps meeting at
    their guides' tips, three strays, and the front layer's waves cresting where the scene's do."""
    fibers = {
        "generator": "wavy", "count": 30, "layers": 3, "length": 0.3, "width": 0.15, "segments": 30, "seed": 9,
        "phase_jitter": 0.0, "layer_phase_jitter": 1.0, "clumps": 4, "clump_strength": 1.0, "strays": 3,
        "stray_lift": 0.03,
    }  # fmt: skip
    scene = scene_from_dict({"camera": front_camera(0.3, (8, 8)), "lights": LIGHTS, "fibers": fibers, "hair": HAIR})
    recipe = {key: value for key, value in fibers.items() if key != "generator"}

    def strands(index):
        """(guides, strays, each layer's wave) of realisation `index`, taken apart by generating it without
        strays, and without clumps as well."""
        arguments = {**recipe, **(realisation_draw(scene, index) if index else {})}
        drop = ("clumps", "clump_strength", "strays", "stray_lift")
        points = [
            generator(**{key: v for key, v in arguments.items() if key not in omit}).points.reshape(30, -1, 3)
            for generator, omit in ((wavy, drop), (wavy, drop[2:]), (wavy, ()))
        ]
        plain, clumped, full = points
        np.testing.assert_array_equal(full.reshape(-1, 3), realisation(scene, index).fibers.points)
        straight_keys = ("count", "layers", "length", "width", "segments", "seed", "shift")
        straight = swatch(**{key: arguments[key] for key in straight_keys if key in arguments})
        wave = (plain[..., 0] - straight.points.reshape(30, -1, 3)[..., 0])[::10]  # one fiber per layer
        guides = np.flatnonzero(np.all(clumped == plain, axis=(1, 2)))
        strays = np.flatnonzero(np.any(full != clumped, axis=(1, 2)))
        assert len(guides) == 4 and len(np.unique(clumped[:, -1], axis=0)) == 4 and len(strays) == 3
        return set(guides), set(strays), wave

    guides, strays, wave = strands(0)
    others = [strands(k) for k in (1, 2, 3)]
    assert all(other[0] != guides for other in others) and all(other[1] != strays for other in others)
    for _, _, other_wave in others:
        np.testing.assert_allclose(other_wave[0], wave[0], atol=1e-6)  # the front layer's crests stay
    assert max(np.abs(other[2][1:] - wave[1:]).max() for other in others) > 0.01  # amplitude 0.02: redrawn
    assert set(realisation(scene, 1).source["fibers"].items()) - set(scene.source["fibers"].items()) <= {
        ("seed", realisation_draw(scene, 1)["seed"]),
        ("shift", realisation_draw(scene, 1)["shift"]),
        ("phase", realisation_draw(scene, 1)["phase"]),
    }


def test_realisation_of_a_file_groom_says_why(tmp_path):
    fibers = tmp_path / "fibers.txt"
    fibers.write_text("0 -0.1 0 0.004\n0 0.1 0 0.004\n", encoding="utf-8")
    scene = scene_from_dict(
        {
            "camera": front_camera(0.3, (8, 8)),
            "lights": LIGHTS,
            "fibers": {"file": str(fibers)},
            "hair": HAIR,
        }
    )
    with pytest.raises(ValueError, match="generator"):
        realisation(scene, 1)


def test_pair_of_scenes_renders_one_realisation_each_and_crosses_them():
    scene = swatch_scene(HAIR, LIGHTS, resolution=(10, 10), render_table={"spp": 4, "max_depth": 8, "seed": 1})
    other = realisation(scene, 1)
    beta_n = torch.tensor(0.25, requires_grad=True)  # exact in float32
    pair = render_torch_pair((scene, other), {"beta_n": beta_n}, spp=4, seed=7)
    seeds = (7, default_grad_seed(7))
    hair = scene.hair.replace(beta_n=0.25)
    scenes = [dataclasses.replace(s, hair=hair) for s in (scene, other)]
    for image, s, seed in zip(pair, scenes, seeds):
        np.testing.assert_allclose(image.detach().numpy(), render(s, spp=4, seed=seed), rtol=1e-5, atol=1e-7)
    loss = 0.5 * ((pair[0] - 0.2) ** 2).sum() + 0.5 * ((pair[1] - 0.05) ** 2).sum()
    loss.backward()
    adjoints = [(pair[0] - 0.2).detach().numpy(), (pair[1] - 0.05).detach().numpy()]
    # Each adjoint meets the Jacobian of the other render: its realisation and its seed.
    crossed = (
        render_grad(scenes[1], adjoints[0], spp=4, seed=seeds[1])["beta_n"]
        + render_grad(scenes[0], adjoints[1], spp=4, seed=seeds[0])["beta_n"]
    )
    np.testing.assert_allclose(beta_n.grad.item(), crossed, rtol=1e-5)


def test_pool_pairs_are_two_different_realisations(tmp_path):
    directory = tmp_path / "t"
    shutil.copytree("targets/cycles_brown_straight", directory)
    target = load_target(directory)
    realisations = Realisations(target, pool=3)
    for seed in range(6):
        pairs = realisations.pair(seed)
        assert len(pairs) == len(target.images)
        for a, b in pairs:
            assert a is not b and not np.allclose(a.scene.fibers.points, b.scene.fibers.points)
    # Both images of a pass show the same strands.
    first = realisations.scenes(1)
    np.testing.assert_array_equal(first[0].scene.fibers.points, first[1].scene.fibers.points)


def test_the_views_of_a_realisation_share_its_strands_and_their_bvh_and_render_as_alone():
    """A target's views of one realisation hold one assembly, drawn once, and one BVH (realisation_views,
    prepare_views); each renders bit for bit as that view realised and prepared alone."""
    target = load_target("targets/cycles_brown_straight")
    scenes = [image.scene for image in target.images]
    views = realisation_views(scenes, 3)
    assert views[1].fibers is views[0].fibers and views[1].camera == scenes[1].camera
    prepared = prepare_views(views)
    assert prepared[1].bvh is prepared[0].bvh
    for scene, view in zip(scenes, prepared):
        alone = realisation(scene, 3)
        np.testing.assert_array_equal(view.scene.fibers.points, alone.fibers.points)
        assert view.scene.source == alone.source
        np.testing.assert_array_equal(render(view, spp=1, seed=4), render(alone, spp=1, seed=4))
    assert realisation_views(scenes, 0) == scenes  # realisation 0 is the scenes themselves


def test_a_recipes_strands_passing_through_each_other_are_said_once_for_all_its_realisations():
    """Clumps pull a recipe's strands through each other in every realisation; a fit draws dozens, and each new
    assembly would warn again: the fit's realisations say it once, naming the first."""
    target = load_target("targets/blender_clumped")
    realisations = Realisations(target, pool=3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for index in (1, 2, 3):
            realisations.scenes(index)
            realisations.views(1000 + index, realisations.drawn(index))  # as the arrangement's columns draw them
    said = [str(w.message) for w in caught if issubclass(w.category, InterpenetrationWarning)]
    assert len(said) == 1 and "pairs of strands interpenetrate" in said[0], said
    assert "in realisation 1 of the recipe; later ones are not reported" in said[0]


def test_target_realisations_key(tmp_path):
    directory = tmp_path / "t"
    shutil.copytree("targets/cycles_brown_straight", directory)
    spec = directory / "target.toml"
    document = tomlkit.parse(spec.read_text(encoding="utf-8"))
    document["realisations"] = "random"
    spec.write_text(tomlkit.dumps(document), encoding="utf-8")
    assert load_target(directory).realisations == "random"
    document["realisations"] = "sometimes"
    spec.write_text(tomlkit.dumps(document), encoding="utf-8")
    with pytest.raises(ValueError, match=r"target.toml: realisations = 'sometimes'; allowed: \['fixed', 'random'\]"):
        load_target(directory)


def _linearization(residuals, jacobian, weights):
    n = residuals.shape[1]
    return Linearization(
        values={"beta_n": 0.3},
        residuals=residuals,
        variances=np.zeros((2, n)),
        jacobians=np.stack([jacobian, jacobian]),
        images=[],
        loss_weights=weights,
    )


def test_realisation_term_is_the_spread_of_the_estimates_and_drops_render_noise():
    """Without render noise (both passes alike) the term is the covariance over the realisations of the estimate
    H⁻¹ Aᵀ W r_k each would give; noise independent between the passes leaves it unbiased, where the covariance
    of either pass alone would add the noise's."""
    rng = np.random.default_rng(0)
    n, k = 60, 400
    jacobian = rng.normal(size=(n, 2))
    weights = np.full(n, 1.0 / n)
    lin = _linearization(np.zeros((2, n)), jacobian, weights)
    realised = rng.normal(scale=0.5, size=(k, n))
    clean = [_linearization(np.stack([r, r]), jacobian, weights) for r in realised]
    gain = np.linalg.pinv(lin.curvature) @ (jacobian * weights[:, None]).T
    expected = np.cov((realised @ gain.T).T)
    term = realisation_term(lin, clean)
    np.testing.assert_allclose(term.covariance, expected, rtol=1e-9, atol=1e-12)

    # Noise independent between the passes, 4 times the realisations' variance (1 against 0.25 per residual).
    k = 4000
    realised = rng.normal(scale=0.5, size=(k, n))
    noisy = [
        _linearization(np.stack([r + rng.normal(size=n), r + rng.normal(size=n)]), jacobian, weights) for r in realised
    ]
    truth = 0.25 * gain @ gain.T
    crossed = realisation_term(lin, noisy).covariance
    one_pass = np.cov((np.stack([x.residuals[0] for x in noisy]) @ gain.T).T)
    # One pass alone overstates the term 5-fold; the crossed passes are unbiased, within their sampling error
    # (relative s.d. about (1 + 0.25) / 0.25 / sqrt(k) = 0.08: the bound is ~4 of those).
    assert np.all(np.diag(one_pass) > 4 * np.diag(truth))
    np.testing.assert_allclose(np.diag(crossed), np.diag(truth), rtol=0.3)


def test_the_arrangement_part_of_the_realisation_term_is_counted_from_its_prior():
    """Where each realisation also draws how the strands lie (ψ_k from a prior), the spread that ψ makes is taken
    out of each estimate and counted from the prior's covariance (a control variate, realisations.py): over many
    sets of K = 8 realisations it is unbiased, as the plain term is, and scatters far less from set to set."""
    rng = np.random.default_rng(3)
    n, k, sets = 60, 8, 300
    jacobian = rng.normal(size=(n, 2))
    weights = np.full(n, 1.0 / n)
    lin = _linearization(np.zeros((2, n)), jacobian, weights)
    gain = np.linalg.pinv(lin.curvature) @ (jacobian * weights[:, None]).T
    columns = rng.normal(size=(n, 1))  # ∂r/∂ψ
    low, high = 0.05, 0.4
    prior = np.array([[(high - low) ** 2 / 12]])
    seed_scale = 0.02  # the seed's part, a small share as on the Blender swatches
    truth = gain @ (columns @ prior @ columns.T + seed_scale**2 * np.eye(n)) @ gain.T
    plain, controlled = [], []
    for _ in range(sets):
        draws = rng.uniform(low, high, size=(k, 1))
        realised = draws @ columns.T + rng.normal(scale=seed_scale, size=(k, n))
        lins = [
            _linearization(np.stack([r + 0.01 * rng.normal(size=n), r + 0.01 * rng.normal(size=n)]), jacobian, weights)
            for r in realised
        ]
        plain.append(np.diag(realisation_spread(gain, lins)[0]))
        covariance, _, part = realisation_spread(gain, lins, (draws, columns, prior))
        np.testing.assert_allclose(part, gain @ columns @ prior @ columns.T @ gain.T)
        controlled.append(np.diag(covariance))
    plain, controlled = np.array(plain), np.array(controlled)
    # Both unbiased within their sampling error over the sets (plain: about √(2/7)/√300 = 3% relative).
    np.testing.assert_allclose(plain.mean(axis=0), np.diag(truth), rtol=0.12)
    np.testing.assert_allclose(controlled.mean(axis=0), np.diag(truth), rtol=0.12)
    # The plain term's relative scatter is that of an 8-sample variance (about a half); the control's a tenth of it.
    assert np.all(plain.std(axis=0) / np.diag(truth) > 0.35)
    assert np.all(controlled.std(axis=0) < 0.2 * plain.std(axis=0))


def test_the_realisation_term_pools_its_jacobians_into_the_curvature():
    """A weak, noisy column (mean 0.1 a residual, noise 0.7): the crossed curvature from the refinement's 16
    Jacobians scatters by about a quarter of itself over draws. With the K = 8 realisation linearisations' 16
    more it stays unbiased and scatters less: by between 1/2 (the noise-by-noise part of a crossed sum of n
    draws falls as 1/n) and 1/√2 (the signal-by-noise part, as 1/√n)."""
    rng = np.random.default_rng(3)
    n, trials, weights = 420, 300, np.full(420, 1.0 / 420)
    column = np.full((n, 1), 0.1)

    def draw(count):
        return column + 0.7 * rng.normal(size=(count, n, 1))

    single, pooled = [], []
    for _ in range(trials):
        lin = _linearization(np.zeros((2, n)), column, weights)
        lin = dataclasses.replace(lin, jacobians=draw(2), earlier_jacobians=draw(14), curvature=None)
        others = [dataclasses.replace(lin, jacobians=draw(2), earlier_jacobians=None, curvature=None) for _ in range(8)]
        both = pooled_jacobians(lin, others)
        assert both.all_jacobians.shape[0] == 32
        everything = np.concatenate([lin.earlier_jacobians, *[o.jacobians for o in others], lin.jacobians])
        np.testing.assert_allclose(both.curvature, crossed_curvature(everything, weights), rtol=1e-12)
        single.append(lin.curvature[0, 0])
        pooled.append(both.curvature[0, 0])
    truth = float(weights @ column[:, 0] ** 2)
    single, pooled = np.array(single), np.array(pooled)
    for values in (single, pooled):
        assert abs(values.mean() - truth) < 4 * values.std() / np.sqrt(trials)
    assert single.std() > 0.2 * truth
    assert 0.45 < pooled.std() / single.std() < 0.75


def _tiny_scene(direction):
    return toml_text(
        {
            "camera": front_camera(0.2, (8, 8)),
            "lights": [{"type": "directional", "direction": direction, "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {"generator": "swatch", "count": 30, "layers": 2, "length": 0.3, "width": 0.24, "drape": 0.2},
            "hair": HAIR,
            "render": {"spp": 8, "max_depth": 8, "seed": 2},
        }
    )


def test_a_fit_over_random_realisations_reports_the_realisation_term(tmp_path):
    directory = write_front_back_target(tmp_path, _tiny_scene)
    make_target(directory)
    target = load_target(directory)
    with pytest.raises(ValueError, match=r"realisations = 'sometimes'"):
        check_settings(target, FitSettings(realisations="sometimes"))
    with pytest.raises(ValueError, match="realisation_samples must be an integer >= 2"):
        check_settings(target, FitSettings(realisation_samples=1))
    result = fit(
        target, progress=False, realisations="random", iters=3, spp=2, refine=2, realisation_samples=3, batch=None
    )
    parts = result.uncertainty_parts
    for name in ("albedo", "beta_m", "beta_n"):
        noise, model, realised = (np.asarray(parts[key][name]) for key in ("noise", "model", "realisation"))
        # Two noisy Gauss–Newton steps at 2 spp leave some direction undetermined: its range's part (uncertainty.py).
        ranged = 0.0 if parts["range"] is None else np.asarray(parts["range"][name])
        np.testing.assert_allclose(result.uncertainties[name], np.sqrt(noise**2 + model**2 + realised**2 + ranged**2))
    # Other strands give other estimates: the term is not zero for the controls the strands' placement moves.
    assert max(np.max(parts["realisation"][name]) for name in ("albedo", "beta_m", "beta_n")) > 0
    assert "± realisation" in format_table(result, {})
    # A fixed fit of the same target has no realisation term.
    fixed = fit(target, progress=False, iters=2, spp=2, refine=0, batch=None)
    assert fixed.uncertainty_parts["realisation"] is None


@pytest.mark.parametrize("extra", [{"curve": "catmull-rom"}, {"random_seed": 3}])
def test_a_wavy_recipe_drawn_as_a_curve_or_with_a_random_seed_has_realisations(extra):
    """The [fibers] keys that are not the generator's (how the strands are drawn, their random values) stay out
    of the shared wave phase's generator run (a TypeError deep in realisation.py before)."""
    scene = scene_from_dict(
        {
            "camera": front_camera(0.3, (8, 8)),
            "lights": LIGHTS,
            "fibers": {"generator": "wavy", "count": 20, "layers": 2, **extra},
            "hair": HAIR,
        }
    )
    other = realisation(scene, 2)
    assert other.fibers.num_strands == scene.fibers.num_strands
    assert not np.array_equal(other.fibers.points, scene.fibers.points)
    assert (other.fibers.strand_random is not None) == ("random_seed" in extra)


def test_a_photos_gains_spread_over_the_realisations_is_their_joint_least_squares_move():
    """Each realisation moves a photo's log-gains as the joint least-squares solve over gains and controls would
    (Frisch–Waugh–Lovell: the gains take the residuals' part along their columns, then follow the hair's move on
    the rest); the realisation term of the gains (`camera_spread`) is that move's covariance over the realisations.
    Here a realisation mostly changes the overall brightness, which the hair's own covariance carried over
    (`follow`) does not see at all."""
    from optimize.camera import Projection
    from optimize.realisations import camera_spread

    rng = np.random.default_rng(5)
    n, k = 90, 300
    columns = np.stack([np.ones(n), np.tile([1.0, 0.0], n // 2)], axis=1) * rng.uniform(0.5, 1.5, size=(n, 1))
    jacobian = rng.normal(size=(n, 2))
    weights = rng.uniform(0.5, 2.0, size=n) / n
    projection = Projection(None, columns, weights, jacobian, ["gain", "white_balance[r]"])
    projected = projection.apply(jacobian)
    shifts = rng.normal(scale=0.05, size=k)[:, None] * columns[:, 0] + rng.normal(scale=0.01, size=(k, n))

    def realisation(r):
        lin = _linearization(np.stack([projection.apply(r)] * 2), projected, weights)
        return dataclasses.replace(lin, camera=projection, camera_moves=np.stack([projection.coefficients(r)] * 2))

    lins = [realisation(r) for r in shifts]
    fitted = dataclasses.replace(realisation(np.zeros(n)), camera_moves=None)
    gain = np.linalg.pinv(projected.T @ (weights[:, None] * projected)) @ (projected * weights[:, None]).T
    both = np.concatenate([columns, jacobian], axis=1)
    joint = -np.linalg.pinv(both.T @ (weights[:, None] * both)) @ (both * weights[:, None]).T @ shifts.T
    expected = np.cov(joint[:2])
    np.testing.assert_allclose(camera_spread(projection, gain, lins), expected, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(realisation_term(fitted, lins).camera, expected, rtol=1e-6, atol=1e-12)
    # The hair's spread carried over alone: far less than the gains' own.
    hair = np.cov(joint[2:])
    assert np.all(np.diag(projection.follow @ hair @ projection.follow.T) < 0.1 * np.diag(expected))
    assert camera_spread(None, gain, lins) is None
