"""The path tracer: energy conservation of the whole loop, direct lighting against quadrature over the
fiber's width, Monte Carlo convergence, and images that do not depend on the number of threads."""

import numpy as np
import pytest
from helpers import reference_model as ref
from helpers.scenes import front_camera, swatch_scene

from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.render import render
from warp_hair.scene import EnvironmentLight, scene_from_dict


def test_white_furnace():
    """Fibers with albedo 1 under a constant environment L and nothing else: every pixel equals L.

    Whatever the depth of the assembly, energy that enters leaves; so this checks the whole estimator (MIS
    weights, Russian roulette, h and the frame at real hits, sampling) and not only the BSDF.
    """
    radiance = 0.5
    scene = swatch_scene(
        {"albedo": 1.0, "beta_m": 0.3, "beta_n": 0.3},
        [{"type": "environment", "radiance": [radiance] * 3}],
        resolution=(16, 16),
        render_table={"spp": 1024, "max_depth": 1000, "rr_depth": 8, "seed": 2},
    )
    image, stderr = render(scene, return_stderr=True)
    assert np.isfinite(image).all()
    np.testing.assert_allclose(image.mean(), radiance, rtol=2e-3)
    # Every pixel within 5 standard errors of its own mean, and that noise is about 1%.
    assert np.all(np.abs(image - radiance) <= 5.0 * stderr + 1e-6)
    assert np.median(stderr) / radiance < 0.012


def test_environment_is_complete_at_the_depth_limit():
    """A lone white fiber under a constant sky with max_depth = 1 scatters once and everything escapes, so
    every pixel equals L. Light sampling at that vertex is MIS-weighted against BSDF sampling, so this fails
    if the ray sampled at the last vertex is not traced to the sky (it lost 43% of the light once)."""
    radiance = 0.7
    scene = single_fiber_scene(0.05, (0.0, 0.0, -1.0), (16, 4), {"albedo": 1.0})
    scene.lights = [EnvironmentLight(radiance=(radiance,) * 3)]
    image, stderr = render(scene, spp=256, return_stderr=True)
    assert np.all(np.abs(image - radiance) <= 5.0 * stderr + 1e-6)
    np.testing.assert_allclose(image.mean(), radiance, rtol=3e-3)


def single_fiber_scene(radius, light_direction, resolution, hair):
    points = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    fiber = FiberAssembly(points, np.full(2, radius), np.array([0, 2]))
    data = {
        "camera": front_camera(2.0 * radius, resolution),
        "lights": [{"type": "directional", "direction": list(light_direction), "irradiance": [2.0, 2.0, 2.0]}],
        "fibers": {"generator": "swatch", "count": 1, "layers": 1},
        "hair": hair,
        "render": {"spp": 512, "max_depth": 1, "seed": 5},
    }
    scene = scene_from_dict(data)
    scene.fibers = fiber
    return scene


@pytest.mark.parametrize("light_direction", [(0.3, -0.4, -1.0), (-0.8, 0.2, 0.5)])
def test_single_fiber_direct_lighting_matches_quadrature(light_direction):
    """One fiber along +y, camera looking down −z at it, one bounce: each pixel column is the average over its
    footprint of S(wo, wi, h(x))·E, integrated here with the float64 reference BSDF at 64 points a column."""
    radius, columns = 0.05, 32
    hair = {"albedo": [0.8, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.4}
    scene = single_fiber_scene(radius, light_direction, (columns, 4), hair)
    image = render(scene).mean(axis=0)  # the rows see the same straight fiber

    to_light = -np.asarray(light_direction, dtype=np.float64)
    to_light /= np.linalg.norm(to_light)
    # Sub-pixel positions across each column (the camera spans [−r, r] in x).
    k = 64
    x = -radius + (np.arange(columns * k) + 0.5) * 2.0 * radius / (columns * k)
    h_geom = x / radius
    tangent = np.array([0.0, 1.0, 0.0])
    normal = np.stack([h_geom, np.zeros_like(x), np.sqrt(1.0 - h_geom**2)], axis=1)
    y = np.cross(normal, tangent)
    wo_world = np.array([0.0, 0.0, 1.0])

    def local(w):
        return np.stack([np.full(len(x), w @ tangent), y @ w, normal @ w], axis=1)

    wo, wi = local(wo_world), local(to_light)
    h = -wo[:, 1] / np.hypot(wo[:, 1], wo[:, 2])
    expected = (ref.eval(hair, wo, wi, h) * 2.0).reshape(columns, k, 3).mean(axis=1)
    # The pixel jitter is the only randomness (a delta light, one bounce): 512 samples a pixel and 4 rows.
    np.testing.assert_allclose(image, expected, rtol=0.02, atol=2e-3 * expected.max())


def test_noise_falls_as_one_over_sqrt_spp():
    """Two independent renders differ by noise of variance 2σ²/spp: 16× the samples, 4× less RMS difference."""
    scene = swatch_scene(
        {"eumelanin": 0.5, "beta_m": 0.3, "beta_n": 0.3},
        [
            {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
            {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
        ],
        resolution=(24, 24),
    )

    def rms_difference(spp):
        return np.sqrt(np.mean((render(scene, spp=spp, seed=10) - render(scene, spp=spp, seed=20)) ** 2))

    ratio = rms_difference(16) / rms_difference(256)
    assert 3.3 < ratio < 4.7, ratio


def test_threads_do_not_change_the_image():
    scene = swatch_scene(
        {"albedo": [0.6, 0.4, 0.2]},
        [
            {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
            {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
        ],
        resolution=(40, 30),
        render_table={"spp": 4, "max_depth": 16, "seed": 9},
        card={"albedo": [0.5, 0.5, 0.5]},
    )
    one = render(scene, threads=1)
    np.testing.assert_array_equal(one, render(scene, threads=2))
    np.testing.assert_array_equal(one, render(scene, threads=3))
    assert not np.array_equal(one, render(scene, seed=10))


def test_a_small_image_gives_each_thread_several_ranges():
    """A fit's 48×48 image on two threads: in ranges of 256 pixels it was 9, which two threads split 5 to 4 (one
    idle for a ninth of the render); now at least 8 a thread, and the image is the one thread's."""
    scene = swatch_scene(
        {"albedo": [0.6, 0.4, 0.2]},
        [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
        resolution=(48, 48),
        render_table={"spp": 1, "max_depth": 4, "seed": 9},
    )
    calls = []
    two = render(scene, threads=2, progress=lambda done, total: calls.append((done, total)))
    assert len(calls) >= 16 and calls[-1] == (48 * 48, 48 * 48), calls
    np.testing.assert_array_equal(two, render(scene, threads=1))


def test_a_subset_of_pixels_renders_as_in_the_whole_image():
    """A fit's mini-batch renders some pixels only: each must come out as in the whole image (its own random
    stream), image, standard error and Jacobian alike, and the others 0."""
    scene = swatch_scene(
        {"albedo": [0.6, 0.4, 0.2]},
        [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
        resolution=(20, 16),
        render_table={"spp": 4, "max_depth": 16, "seed": 9},
    )
    pixels = np.random.default_rng(0).choice(20 * 16, 37, replace=False)
    chosen = np.zeros(20 * 16, bool)
    chosen[pixels] = True
    chosen = chosen.reshape(16, 20)
    whole, whole_err = render(scene, threads=2, return_stderr=True)
    part, part_err = render(scene, threads=2, return_stderr=True, pixels=pixels)
    assert whole[chosen].max() > 0
    np.testing.assert_array_equal(part[chosen], whole[chosen])
    np.testing.assert_array_equal(part_err[chosen], whole_err[chosen])
    assert not part[~chosen].any()
    jacobian, image, _ = render_jacobian(scene, threads=2, pixels=pixels)
    whole_jacobian, _, _ = render_jacobian(scene, threads=2)
    np.testing.assert_array_equal(jacobian[chosen], whole_jacobian[chosen])
    np.testing.assert_allclose(image[chosen], whole[chosen], rtol=1e-6, atol=1e-7)
    assert not jacobian[~chosen].any()
    for bad, message in (([-1], "must lie in"), ([320], "must lie in"), ([[1, 2]], "1-D array"), ([0.5], "integer")):
        with pytest.raises(ValueError, match=message):
            render(scene, pixels=np.array(bad))


def test_image_orientation():
    """Row 0 is the top: a swatch that covers only the upper half of the view lights only the upper rows,
    and one shifted to +x (forward × up) only the right columns."""
    scene = swatch_scene(
        {"albedo": 0.8},
        [{"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": [1.0, 1.0, 1.0]}],
        resolution=(20, 20),
        render_table={"spp": 4, "max_depth": 2, "seed": 0},
    )
    points = np.array(scene.fibers.points, dtype=np.float64)
    points[:, 1] = np.clip(points[:, 1], 0.02, None)  # only y > 0: the upper half of the image
    points[:, 0] = np.abs(points[:, 0]) + 0.02  # only x > 0: the right half
    scene.fibers = FiberAssembly(points, scene.fibers.radii, scene.fibers.strand_offsets)
    image = render(scene).sum(axis=2)
    assert image[:9].sum() > 0 and image[11:].sum() == 0
    assert image[:, 11:].sum() > 0 and image[:, :9].sum() == 0


def test_cuticle_tilt_puts_a_black_fibers_highlight_toward_the_root():
    """A black fiber (σ_a = 50: only R is left) listed root first along +y, seen head-on. The scales' normals
    lean toward the root by α, so the mirror direction of the view leans toward the root by 2α: a light there
    lights the fiber brightly, and the same light mirrored toward the tip barely at all."""
    alpha = 4.0
    hair = {"sigma_a": 50.0, "beta_m": 0.1, "beta_n": 0.3, "alpha": alpha}
    lean = np.radians(2.0 * alpha)

    def brightness(toward):  # toward = −1: the light sits toward the root (−y); +1: toward the tip
        to_light = np.array([0.0, toward * np.sin(lean), np.cos(lean)])
        return render(single_fiber_scene(0.05, tuple(-to_light), (16, 4), hair), spp=64).mean()

    root_side, tip_side = brightness(-1.0), brightness(+1.0)
    assert root_side > 20.0 * tip_side, (root_side, tip_side)
