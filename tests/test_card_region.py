"""A grey card marked in a photo (optimize/card_region.py): its radiance without rendering (warp_hair/grey_card.py)
against warp-hair's render of a modelled `[card]`, the gains it pins, the linearisation with its rows, bad input."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest
import torch
from helpers.cards import with_card
from helpers.photo_args import photo_args
from helpers.scenes import front_camera
from PIL import Image

import targets
from optimize import camera, card_region
from optimize.fit import FitSettings
from optimize.linearize import linearize
from optimize.target import load_target
from optimize.uncertainty import brightness_sensitivity
from warp_hair.grey_card import card_normal, card_radiance, environment_irradiance
from warp_hair.io import write_exr
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

SOURCE = "photo_blonde_straight_png"


def _card_scene(lights, tmp_path=None):
    """One short thin fiber at the centre, a [card] of albedo (0.5, 0.3, 0.18) behind it, filling the view."""
    return scene_from_dict(
        {
            "camera": front_camera(0.3, (24, 24)),
            "lights": lights,
            "fibers": {"generator": "swatch", "count": 1, "layers": 1, "length": 0.04, "radius": 0.001, "seed": 1},
            "hair": {"albedo": [0.5, 0.5, 0.5]},
            "render": {"spp": 16, "max_depth": 8, "seed": 2},
            "card": {"albedo": [0.5, 0.3, 0.18]},
        },
        base_dir=tmp_path,
    )


def _sky(tmp_path):
    """A lat-long map brighter overhead (+y), toward +x and toward the camera (+z), so that the cosine weighting
    and the map's orientation matter: a card facing −z would see 0.35-0.41 of its irradiance."""
    h, w = 16, 32
    theta = (np.arange(h) + 0.5) / h * math.pi
    phi = (np.arange(w) + 0.5) / w * 2 * math.pi
    sky = (
        0.2
        + np.cos(theta)[:, None, None].clip(0) * np.array([1.0, 0.8, 0.6])
        + (0.5 * np.sin(phi) - 0.8 * np.cos(phi)).clip(0)[None, :, None]
    )
    write_exr(tmp_path / "sky.exr", np.broadcast_to(sky, (h, w, 3)).astype(np.float32))
    return tmp_path / "sky.exr"


@pytest.mark.parametrize("light", ["directional", "constant sky", "sky map"])
def test_analytic_card_radiance_matches_the_rendered_card(tmp_path, light):
    """ρ/π · E agrees with warp-hair's path-traced [card] (in the open, away from the one small fiber) within its
    Monte Carlo error: a directional light's irradiance times the cosine, a sky's cosine-weighted integral."""
    lights = {
        "directional": [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 2.0, 1.0]}],
        "constant sky": [{"type": "environment", "radiance": [0.4, 0.5, 0.6]}],
        "sky map": [{"type": "environment", "file": "sky.exr"}],
    }[light]
    if light == "sky map":
        _sky(tmp_path)
    scene = _card_scene(lights, tmp_path)
    image, stderr = render(scene, threads=2, return_stderr=True)
    y, x = np.mgrid[0:24, 0:24]
    open_card = (np.abs(x - 11.5) > 6) | (np.abs(y - 11.5) > 6)  # the fiber and its shadow lie within the middle
    mean = image[open_card].astype(np.float64).mean(axis=0)
    error = np.sqrt((stderr[open_card].astype(np.float64) ** 2).sum(axis=0)) / open_card.sum()
    expected = card_radiance(scene, scene.card.albedo, card_normal(scene, "camera"))
    if light == "directional":  # a delta light on a Lambertian card: every sample the same, up to float32
        np.testing.assert_allclose(mean, expected, rtol=1e-5)
    else:
        assert (error > 0).all() and (error < 0.01 * expected).all()
        assert (np.abs(mean - expected) < 4 * error).all(), (mean, expected, error)


def test_environment_integral_of_a_constant_map_is_pi():
    for normal in ([0, 0, 1], [0, 1, 0], [0.3, -0.5, 0.8]):
        n = np.array(normal, float) / np.linalg.norm(normal)
        assert environment_irradiance(np.ones((8, 16, 3), np.float32), n) == pytest.approx([math.pi] * 3, rel=1e-4)


def test_card_normal_faces_the_camera():
    scene = _card_scene([{"type": "environment", "radiance": [1.0, 1.0, 1.0]}])
    assert np.allclose(card_normal(scene, "camera"), [0, 0, 1])
    assert np.allclose(card_normal(scene, [0, 0.6, -0.8]), [0, -0.6, 0.8])  # the face the camera sees
    with pytest.raises(ValueError, match="edge-on"):
        card_normal(scene, [1, 0, 0.05])
    with pytest.raises(ValueError, match="finite nonzero"):
        card_normal(scene, [0, 0, 0])


def _exr_card_target(tmp_path, box=(0, 8, 0, 8)):
    """The photo-like target as linear EXR (decoded), with a card pasted into the front view at its true gains
    times the card's radiance: no quantisation on the card."""
    directory = tmp_path / "exr_card"
    with_card(targets.path(SOURCE), directory, box=box)
    loaded = load_target(directory)
    spec = (directory / "target.toml").read_text()
    truth = json.loads((directory / "camera_truth.json").read_text())
    for image in loaded.images:
        linear = image.image.copy()
        if image.card is not None:
            y0, y1, x0, x1 = box
            linear[y0:y1, x0:x1] = truth["gains"][image.name] * np.asarray(truth["white_balance"]) * image.card.radiance
        write_exr(directory / f"{image.name}.exr", linear.astype(np.float32))
        spec = spec.replace(f'"{image.name}.png"', f'"{image.name}.exr"')
    (directory / "target.toml").write_text(spec)
    return directory, truth


def test_a_card_alone_gives_the_true_gains_exactly(tmp_path):
    """The card's terms alone (no hair) solve to the front view's true gain and the white balance, to rounding;
    and hair renders that agree with the same gains leave them there."""
    directory, truth = _exr_card_target(tmp_path)
    target = load_target(directory)
    assert (target.gains, target.white_balance) == ("per-image", "fit")  # a card makes them unknowns in an EXR
    front = target.images[0]
    assert front.card is not None and target.images[1].card is None and not front.mask[:8, :8].any()
    scales = [1.0, 1.0]
    a, b = card_region.sums(target, "l2", 4, scales)
    solved = camera.solve(a, b, target)
    assert solved.g[0] == pytest.approx(truth["gains"]["front"], rel=1e-6)
    np.testing.assert_allclose(solved.w, truth["white_balance"], rtol=1e-6)
    # Hair "renders" the targets' own pixels over the true gains: every term agrees, the solve is exact.
    gains = np.array([truth["gains"][im.name] for im in target.images])[:, None] * np.asarray(truth["white_balance"])
    pairs = [(torch.from_numpy(im.image / g), torch.from_numpy(im.image / g)) for im, g in zip(target.images, gains)]
    references = [torch.from_numpy(im.image) for im in target.images]
    masks = [None if im.mask is None else torch.from_numpy(im.mask) for im in target.images]
    both = camera.gains_for(target, pairs, references, masks, "l2", 4, scales)
    np.testing.assert_allclose(both.per_channel, gains, rtol=1e-6)


def test_card_pixels_count_as_hair_blocks():
    """A card block weighs what a hair block of the same value does: ω²/(N_k n), N_k the image's hair blocks."""
    from types import SimpleNamespace

    mask = np.ones((8, 8), bool)
    card_mask = np.zeros((8, 8), bool)
    card_mask[:4, :4] = True
    mask &= ~card_mask
    image = np.full((8, 8, 3), 0.5, np.float32)
    card = card_region.CardRegion(card_mask, card_mask, np.full(3, 0.18), np.array([0, 0, 1.0]), np.full(3, 0.25))
    view = SimpleNamespace(image=image, mask=mask, card=card)
    target = SimpleNamespace(images=[view], gains="per-image", white_balance="fit")
    a, b = card_region.sums(target, "l2", 2, [0.25])
    # pool 2: 4 card blocks, 12 hair blocks; ω² = 1/0.25.
    np.testing.assert_allclose(a[0], 4 * (1 / 0.25) * 0.25 * 0.5 / 12)
    np.testing.assert_allclose(b[0], 4 * (1 / 0.25) * 0.25**2 / 12)


def test_linearisation_with_a_card_pins_the_gains(tmp_path):
    """A photo-like target with a card pasted into its front view: the card's rows join the linearisation (no
    hair Jacobian before the projection), the gains' columns are projected out of all rows, and the solved gains
    lie within their stated σ of the camera's true ones, the front view's σ below what the same target without
    the card (its hair left out where the card is) gives."""
    plain = tmp_path / "plain"
    shutil.copytree(targets.path(SOURCE), plain)
    hole = np.full((64, 64), 255, np.uint8)
    hole[:8, :8] = 0
    Image.fromarray(hole, "L").save(plain / "front_hole.png")
    spec = (
        (plain / "target.toml")
        .read_text()
        .replace('image = "front.png"', 'image = "front.png"\nmask = "front_hole.png"')
    )
    (plain / "target.toml").write_text(spec)
    with_card(targets.path(SOURCE), tmp_path / "card")
    truth = json.loads((plain / "camera_truth.json").read_text())
    sigmas = {}
    for name in ("plain", "card"):
        target = load_target(tmp_path / name)
        hair = target.truth.to_dict()
        values = {"albedo": hair["albedo"], "beta_m": hair["beta_m"], "beta_n": hair["beta_n"]}
        lin = linearize(target, values, FitSettings(), spp=8, seed=3, threads=2)
        projection = lin.camera
        cols = projection.columns
        assert np.abs(cols.T @ (lin.loss_weights * lin.residuals.mean(0))).max() < 1e-9 * np.abs(cols).sum()
        if name == "card":
            rows = lin.card_rows
            assert rows is not None and rows.sum() == 4 * 3  # four 4×4 blocks, three channels
            assert not projection.jacobian[rows].any() and np.abs(lin.jacobians[:, rows]).max() > 0
        shift = None if projection.direct is None else brightness_sensitivity(lin)
        cov = projection.covariance(lin.statistical_covariance, lin.scatter, 0.01, shift)
        sigma = np.sqrt(np.diag(cov))
        sigmas[name] = sigma
        for k, label in enumerate(projection.labels):
            value = camera.label_values(projection, target)[k]
            inside = re.search(r"\[(.*)\]", label).group(1)
            true = truth["gains"][inside] if label.startswith("gain") else truth["white_balance"]["rgb".index(inside)]
            assert abs(math.log(value / true)) < 3 * sigma[k], (name, label, value, true, sigma[k])
    assert sigmas["card"][0] < sigmas["plain"][0]


def test_the_card_weighs_as_its_variance_says_against_the_hairs(tmp_path):
    """Generalised least squares: a card block weighs the hair rows' mean square residual over the card's own
    variance (its blocks' scatter, or the rounding of its 8-bit codes, one error for the whole flat card). Here the
    hair is rendered at another look than the target's (a misfit, as a recipe leaves), so its residuals are large
    against the card's: the card weighs many hair blocks, and the gains it pins lie within 3σ of the camera's true
    ones with a σ well below the card's weighed as one hair block."""
    from optimize.goodness import quantisation_variances

    with_card(targets.path(SOURCE), tmp_path / "card")
    target = load_target(tmp_path / "card")
    truth = json.loads((tmp_path / "card" / "camera_truth.json").read_text())
    hair = target.truth.to_dict()
    values = {"albedo": hair["albedo"], "beta_m": hair["beta_m"] + 0.15, "beta_n": hair["beta_n"] - 0.15}
    settings = FitSettings()
    lin = linearize(target, values, settings, spp=32, seed=3, threads=2)
    quantisation = quantisation_variances(target, settings)
    weights = card_region.gls_weights(target, lin, settings, quantisation)
    assert weights[1] == 1.0  # the back view has no card
    # By hand: the front's hair rows' mean square residual over its card rows' mean variance.
    hair_rows = lin.image_residuals[0] - 4 * 3
    front = lin.mean_residual[: lin.image_residuals[0]]
    values_card = card_region.card_values(target.images[0], settings.pool)
    reference = target.images[0].image
    omega2 = card_region.omega(values_card, card_region._hair_reference(target.images[0], 4)[0], "l2") ** 2
    card_var = np.maximum(values_card.var(axis=0, ddof=1)[None, :], (card_region.CARD_PRECISION * values_card) ** 2)
    # The card's 8-bit rounding is one error for all its 4 blocks (4×4 pixels each): a block's variance 4 × 16 × its
    # own quantisation.
    rounding = quantisation[hair_rows : lin.image_residuals[0]].reshape(-1, 3) * 16 * 4
    card_var = np.maximum(card_var * omega2, rounding)
    scatter = np.mean(front[:hair_rows] ** 2 - lin.mean_variance[:hair_rows])  # our render's noise taken out
    assert weights[0] == pytest.approx(scatter / np.mean(card_var), rel=1e-9)
    assert weights[0] > 100 and reference.shape[:2] == (64, 64)
    sigmas = {}
    for name, weighed in (("one", target), ("gls", card_region.with_weights(target, weights))):
        lin = linearize(weighed, values, settings, spp=32, seed=5, threads=2)
        projection = lin.camera
        cov = projection.covariance(lin.statistical_covariance, lin.scatter, 0.01, brightness_sensitivity(lin))
        sigmas[name] = np.sqrt(np.diag(cov))
        if name == "gls":  # what the card sees: the front's gain and the white balance (the back's follows the hair)
            for k, label in enumerate(projection.labels):
                value, inside = camera.label_values(projection, weighed)[k], re.search(r"\[(.*)\]", label).group(1)
                if label == "gain[front]":
                    assert abs(math.log(value / truth["gains"]["front"])) < 3 * sigmas[name][k], (label, value)
                elif label.startswith("white_balance"):
                    true = truth["white_balance"]["rgb".index(inside)]
                    assert abs(math.log(value / true)) < 3 * sigmas[name][k], (label, value, true)
    assert sigmas["gls"][0] < 0.5 * sigmas["one"][0]


def test_a_fit_weighs_its_card_before_refining_and_reports_it(tmp_path):
    """The fit measures the card's weight once, after its descent, refines and reports with it: the weight in
    params.json's camera record is `gls_weights`' at least 1, and the printed camera table names it."""
    from optimize.fit import fit
    from optimize.report import camera_table

    with_card(targets.path(SOURCE), tmp_path / "card")
    target = load_target(tmp_path / "card")
    result = fit(target, iters=4, spp=4, refine=2, threads=2, progress=False)
    weights = result.camera["card_weights"]
    assert list(weights) == ["front"] and weights["front"] >= 1.0
    assert f"grey card in front: a block of it weighs {weights['front']:.3g}x" in camera_table(result)
    assert target.images[0].card.weight == 1.0  # the caller's target is left as it was


def _write_spec(directory, edit):
    spec = (directory / "target.toml").read_text()
    (directory / "target.toml").write_text(edit(spec))


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: s.replace("[card]\nreflectance = 0.18\n", "[card]\n"), "needs reflectance"),
        (
            lambda s: s.replace("reflectance = 0.18", "reflectance = 0"),
            r"reflectance = 0; each value must lie in \(0, 1\]",
        ),
        (lambda s: s.replace("reflectance = 0.18", "reflectance = 1.2"), r"must lie in \(0, 1\]"),
        (lambda s: s.replace("reflectance = 0.18", "reflectance = [0.2, 0.2]"), "a number or \\[r, g, b\\]"),
        (lambda s: s.replace("reflectance = 0.18", 'reflectance = "grey"'), "a number or \\[r, g, b\\]"),
        (lambda s: s.replace('normal = "camera"', 'normal = "up"'), 'allowed: "camera" or'),
        (lambda s: s.replace('normal = "camera"', "normal = [1, 0, 0]"), "edge-on"),
        (lambda s: s.replace("reflectance = 0.18", "reflectance = 0.18\nshade = 1"), r"unknown key\(s\) \['shade'\]"),
        (lambda s: re.sub(r"\[card\][^\[]*", "", s), "nothing says what the card is"),
        (lambda s: s.replace('card_mask = "front_card.png"\n', ""), "no \\[\\[images\\]\\] table names its pixels"),
        (lambda s: s.replace('card_mask = "front_card.png"', 'card_mask = "nope.png"'), "mask not found"),
        (lambda s: 'gains = "none"\nwhite_balance = "none"\n' + s, 'gains = "none" and white_balance = "none"'),
        (
            lambda s: s.replace('image = "back.png"', 'image = "back.png"\ncard_mask = "front_card.png"'),
            "no light in R, G, B",
        ),
    ],
)
def test_bad_card_input_is_an_error_naming_the_file(tmp_path, edit, message):
    directory = tmp_path / "t"
    with_card(targets.path(SOURCE), directory)
    _write_spec(directory, edit)
    with pytest.raises((ValueError, FileNotFoundError), match=message) as error:
        load_target(directory)
    assert "target.toml" in str(error.value) or "nope.png" in str(error.value)


def test_bad_card_masks(tmp_path):
    directory = tmp_path / "t"
    with_card(targets.path(SOURCE), directory)
    Image.fromarray(np.zeros((64, 64), np.uint8), "L").save(directory / "front_card.png")
    with pytest.raises(ValueError, match=r"front_card\.png: the mask selects no pixel"):
        load_target(directory)
    Image.fromarray(np.full((32, 64), 255, np.uint8), "L").save(directory / "front_card.png")
    with pytest.raises(ValueError, match=r"front_card\.png: the mask is 64x32 but its image is 64x64"):
        load_target(directory)


def test_clipped_card_pixels_are_left_out_and_counted(tmp_path):
    """Card pixels the camera clipped say nothing of its level: left out with a note; all of them, an error."""
    directory = tmp_path / "t"
    with_card(targets.path(SOURCE), directory)
    codes = np.asarray(Image.open(directory / "front.png").convert("RGB")).copy()
    codes[0:2, 0:8] = 255
    Image.fromarray(codes, "RGB").save(directory / "front.png")
    card = load_target(directory).images[0].card
    assert card.note == "card: 16 clipped and 0 crushed of its 64 pixels left out"
    assert card.marked.sum() == 64 and card.mask.sum() == 48 and not card.mask[0:2].any()
    codes[0:8, 0:8] = 255
    Image.fromarray(codes, "RGB").save(directory / "front.png")
    with pytest.raises(ValueError, match="every one of the card's 64 pixels is clipped \\(64\\)"):
        load_target(directory)


def test_target_from_photos_with_a_marked_card(tmp_path):
    """`warp-hair targets photo --card-mask --card-reflectance`: a 128 px photo of the Cycles brown swatch, taken
    at a gain of 2.2 with an 18% card in a 16×16 corner, becomes a 64 px target whose card (the 8×8 blocks wholly
    on it) alone solves to that gain and a neutral white balance, within the 8-bit codes' rounding."""
    from optimize.photo_target import make_photo_target
    from warp_hair.io import read_exr, srgb_encode
    from warp_hair.photo import srgb_decode, write_photo

    image, _ = read_exr(targets.path("cycles_brown_straight") / "front.exr")
    photo = np.repeat(np.repeat(image, 2, 0), 2, 1) * 2.2
    light = (0.2, -0.3, -1.0)
    value = 2.2 * 0.18 / math.pi * 3.0 * (-np.array(light) @ [0, 0, 1]) / np.linalg.norm(light)
    photo[:16, :16] = value
    rounding = srgb_decode(srgb_encode(value) + 0.5 / 255) / value - 1  # half a code, relative
    write_photo(tmp_path / "front.png", photo)
    mask = np.zeros((128, 128), np.uint8)
    mask[:17, :17] = 255  # one photo pixel past the card: the blocks it reaches only partly are neither
    Image.fromarray(mask, "L").save(tmp_path / "card.png")
    args = photo_args(
        "--image", str(tmp_path / "front.png"), "--light", ",".join(map(str, light)), "--ortho-width", "0.36",
        "--card-mask", str(tmp_path / "card.png"), "--card-reflectance", "0.18", "--card-normal", "camera",
    )  # fmt: skip
    make_photo_target(tmp_path / "made", args)
    target = load_target(tmp_path / "made")
    card = target.images[0].card
    assert card.mask.sum() == 64 and card.mask[:8, :8].all()
    assert not target.images[0].mask[:9, :9].any() and target.images[0].mask[9:].any()
    a, b = card_region.sums(target, "l2", 1, [1.0])
    solved = camera.solve(a, b, target)
    assert solved.g[0] == pytest.approx(2.2, rel=rounding) and np.allclose(solved.w, 1.0, rtol=1e-9)
    args.card_reflectance = None
    with pytest.raises(ValueError, match="--card-mask needs --card-reflectance"):
        make_photo_target(tmp_path / "other", args)
    args.card_reflectance, args.card_mask = 0.18, ["none", "none"]
    with pytest.raises(ValueError, match="1 photo\\(s\\) but 2 --card-mask"):
        make_photo_target(tmp_path / "other", args)


def test_an_image_overrides_the_targets_card(tmp_path):
    """card = {...} in an image's table overrides [card]'s keys for it: twice the reflectance, twice the radiance;
    a per-channel reflectance scales each channel."""
    directory = tmp_path / "t"
    with_card(targets.path(SOURCE), directory)
    grey = load_target(directory).images[0].card.radiance
    _write_spec(
        directory,
        lambda s: s.replace(
            'card_mask = "front_card.png"', 'card_mask = "front_card.png"\ncard = {reflectance = 0.36}'
        ),
    )
    np.testing.assert_allclose(load_target(directory).images[0].card.radiance, 2 * grey, rtol=1e-12)
    _write_spec(
        directory, lambda s: s.replace("card = {reflectance = 0.36}", "card = {reflectance = [0.09, 0.18, 0.36]}")
    )
    np.testing.assert_allclose(load_target(directory).images[0].card.radiance, [0.5, 1, 2] * grey, rtol=1e-12)


def test_targets_check_counts_the_card(tmp_path):
    """`targets check` on the photo-like target with a 16×16 card in the front view against the same target with
    those pixels left out and no card (the same hair rows, the same renders): the card adds information on the
    gains, so the front gain's σ and the red albedo's σ from the target's noise fall (a short check: 4 spp, 2
    linearisations, no model error; benchmarks/card_region.py runs the full one)."""
    from optimize.identify import check_target

    plain = tmp_path / "plain"
    shutil.copytree(targets.path(SOURCE), plain)
    hole = np.full((64, 64), 255, np.uint8)
    hole[:16, :16] = 0
    Image.fromarray(hole, "L").save(plain / "front_hole.png")
    _write_spec(plain, lambda s: s.replace('image = "front.png"', 'image = "front.png"\nmask = "front_hole.png"'))
    with_card(targets.path(SOURCE), tmp_path / "card", box=(0, 16, 0, 16))
    results = {
        name: check_target(load_target(tmp_path / name), render_spp=4, linearisations=2, threads=2, model_error=0.0)
        for name in ("plain", "card")
    }
    front = {name: {label: s for label, _, s in r.camera}["gain[front]"] for name, r in results.items()}
    red = {name: r.noise[r.labels.index("albedo[r]")] for name, r in results.items()}
    assert front["card"] < front["plain"] and red["card"] < red["plain"], (front, red)
