"""Environment lights: the lat-long mapping, and that sampling, density and radiance agree with each other."""

import math

import numpy as np
import pytest
import warp as wp
from scipy.stats import chi2, kstest

from warp_hair.renderer.envmap import (
    EnvironmentData,
    direction_to_uv,
    env_pdf,
    env_radiance,
    env_sample,
    environment_data,
    from_blender,
    uv_to_direction,
)

wp.set_module_options({"enable_backward": False})

SIGNIFICANCE = 0.01
N_SAMPLES = 1_000_000
LARGEST_BELOW_ONE = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


@wp.kernel
def _uv_to_direction_kernel(uv: wp.array(dtype=wp.vec2), d: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    d[i] = uv_to_direction(uv[i])


@wp.kernel
def _direction_to_uv_kernel(d: wp.array(dtype=wp.vec3), uv: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    uv[i] = direction_to_uv(d[i])


@wp.kernel
def _pdf_kernel(env: EnvironmentData, d: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=float)):
    i = wp.tid()
    pdf[i] = env_pdf(env, d[i])


@wp.kernel
def _radiance_kernel(env: EnvironmentData, d: wp.array(dtype=wp.vec3), radiance: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    radiance[i] = env_radiance(env, d[i])


@wp.kernel
def _sample_kernel(
    env: EnvironmentData,
    u: wp.array(dtype=wp.vec2),
    d: wp.array(dtype=wp.vec3),
    pdf: wp.array(dtype=float),
    radiance: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    direction, density = env_sample(env, u[i])
    d[i] = direction
    pdf[i] = density
    radiance[i] = env_radiance(env, direction)


def _run(kernel, inputs, out_dtypes):
    """Launch kernel over the points in the last input, an (N, 2) or (N, 3) array; outputs as NumPy arrays."""
    points = np.asarray(inputs[-1], dtype=np.float32)
    points = wp.array(points, dtype={2: wp.vec2, 3: wp.vec3}[points.shape[1]])
    outputs = [wp.zeros(len(points), dtype=dtype) for dtype in out_dtypes]
    wp.launch(kernel, dim=len(points), inputs=[*inputs[:-1], points, *outputs])
    return [o.numpy() for o in outputs]


def to_directions(uv):
    return _run(_uv_to_direction_kernel, [uv], [wp.vec3])[0]


def to_uv(d):
    return _run(_direction_to_uv_kernel, [d], [wp.vec2])[0]


def pdf(env, d):
    return _run(_pdf_kernel, [env, d], [float])[0].astype(np.float64)


def radiance(env, d):
    return _run(_radiance_kernel, [env, d], [wp.vec3])[0].astype(np.float64)


def sample(env, u):
    d, density, value = _run(_sample_kernel, [env, u], [wp.vec3, float, wp.vec3])
    return d, density.astype(np.float64), value.astype(np.float64)


def pixel_solid_angles(height, width):
    """Exact solid angle of each pixel row (all pixels of a row are equal): 2π/W (cos θ_top − cos θ_bottom)."""
    cos_edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (cos_edges[:-1] - cos_edges[1:]) * 2.0 * np.pi / width


def random_map(rng, height=16, width=32):
    """High dynamic range, different in each channel, like a real sky."""
    return np.exp(rng.normal(0.0, 1.5, (height, width, 3))).astype(np.float32)


def bright_pixel_map(height=16, width=32, row=5, column=11, background=0.0):
    image = np.full((height, width, 3), background, dtype=np.float32)
    image[row, column] = (400.0, 300.0, 200.0)
    return image


MAPS = {
    "random": lambda: random_map(np.random.default_rng(7)),
    "random_odd_size": lambda: random_map(np.random.default_rng(8), 7, 13),
    "bright_pixel": lambda: bright_pixel_map(),
    "bright_pixel_dim_sky": lambda: bright_pixel_map(background=0.01),
    "bright_pole_pixel": lambda: bright_pixel_map(row=0, column=3, background=0.01),
    "constant_image": lambda: np.full((16, 32, 3), 0.7, dtype=np.float32),
}


def test_mitsuba_convention():
    """u = 0 looks along −z, u = 1/4 along +x; v = 0 is +y (row 0, the top), v → 1 is −y."""
    d = np.array([[0, 0, -1], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=np.float32)
    uv = to_uv(d)
    np.testing.assert_allclose(uv[:4, 0], [0.0, 0.25, 0.5, 0.75], atol=1e-6)
    np.testing.assert_allclose(uv[:4, 1], 0.5, atol=1e-6)
    np.testing.assert_allclose(uv[4:, 1], [0.0, 1.0], atol=1e-6)
    assert np.all((uv >= 0.0) & (uv < 1.0))


def test_uv_direction_round_trip():
    rng = np.random.default_rng(1)
    uv = rng.random((100_000, 2)).astype(np.float32)
    uv[:, 1] = 0.001 + 0.998 * uv[:, 1]  # u is undefined at the poles themselves
    d = to_directions(uv)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    back = to_uv(d)
    du = np.abs(back[:, 0] - uv[:, 0])
    assert np.max(np.minimum(du, 1.0 - du)) < 2e-5  # u wraps around at 1
    np.testing.assert_allclose(back[:, 1], uv[:, 1], atol=2e-5)

    d = rng.normal(size=(100_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(to_directions(to_uv(d)), d, atol=2e-5)


def test_radiance_is_nearest_pixel_times_scale():
    rng = np.random.default_rng(2)
    image = random_map(rng, 8, 12)
    env, _keep = environment_data(image=image, scale=2.5)
    rows, columns = np.meshgrid(np.arange(8), np.arange(12), indexing="ij")
    jitter = rng.uniform(-0.45, 0.45, (2, rows.size))
    uv = np.stack([(columns.ravel() + 0.5 + jitter[0]) / 12, (rows.ravel() + 0.5 + jitter[1]) / 8], axis=1)
    expected = 2.5 * image.reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(radiance(env, to_directions(uv)), expected, rtol=1e-6)


def test_constant_radiance_everywhere():
    env, _keep = environment_data(radiance=(0.2, 0.5, 1.0), scale=3.0)
    d = to_directions(np.random.default_rng(3).random((1000, 2)))
    np.testing.assert_allclose(radiance(env, d), np.broadcast_to([0.6, 1.5, 3.0], (1000, 3)), rtol=1e-6)
    np.testing.assert_allclose(pdf(env, d), 1.0 / (4.0 * np.pi), rtol=1e-6)


@pytest.mark.parametrize("name", MAPS)
def test_pdf_integrates_to_one(name):
    """Midpoint rule in (θ, φ) with dω = sin θ dθ dφ, on sub-cells nested in the pixels.

    Within a pixel the density times sin θ is constant, so the rule is exact there and the sum must be 1
    to float32 accuracy: a wrong Jacobian (e.g. sin θ of the pixel centre), normalisation or pixel lookup
    would show. Many θ sub-rows per pixel reach close to the poles, where the density grows as 1/sin θ.
    """
    image = MAPS[name]()
    height, width = image.shape[:2]
    n_theta, n_phi = 64 * height, 4 * width
    theta = (np.arange(n_theta) + 0.5) * np.pi / n_theta
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(pp) * np.sin(tt), np.cos(tt), -np.cos(pp) * np.sin(tt)], axis=-1).reshape(-1, 3)
    env, _keep = environment_data(image=image)
    d_omega = np.sin(tt).ravel() * (np.pi / n_theta) * (2.0 * np.pi / n_phi)
    assert np.sum(pdf(env, d) * d_omega) == pytest.approx(1.0, abs=1e-5)


def latlong_histogram_test(env, d, n_v, n_u, sub_v, sub_u):
    """Pearson's χ² of sampled directions on an n_v × n_u lat-long grid against N ∫_bin env_pdf dω.

    The expected counts come from env_pdf by the midpoint rule on sub_v × sub_u sub-cells per bin, in
    (u, v) with dω = 2π² sin θ du dv; with sub-cells nested in the pixels too the rule is exact. The bins
    themselves are chosen not to line up with the pixels, so they also see where inside a pixel samples go.
    Bins expecting fewer than 5 samples are pooled; a sample in a bin of zero probability fails outright.
    """
    nv, nu = n_v * sub_v, n_u * sub_u
    u, v = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv)
    centres = to_directions(np.stack([u.ravel(), v.ravel()], axis=1))
    jacobian = 2.0 * np.pi**2 * np.sin(np.pi * v.ravel()) / (nu * nv)
    mass = (pdf(env, centres) * jacobian).reshape(n_v, sub_v, n_u, sub_u).sum(axis=(1, 3))
    expected = len(d) * mass.ravel() / mass.sum()

    uv = to_uv(d).astype(np.float64)
    bin_u = np.minimum((uv[:, 0] * n_u).astype(int), n_u - 1)
    bin_v = np.minimum((uv[:, 1] * n_v).astype(int), n_v - 1)
    observed = np.bincount(bin_v * n_u + bin_u, minlength=n_v * n_u).astype(np.float64)

    assert observed[expected == 0.0].sum() == 0
    keep = expected >= 5.0
    obs = np.append(observed[keep], observed[~keep].sum())
    exp = np.append(expected[keep], expected[~keep].sum())
    if exp[-1] < 5.0:
        obs, exp = obs[:-1], exp[:-1]
    statistic = np.sum((obs - exp) ** 2 / exp)
    return chi2.sf(statistic, len(exp) - 1), mass.sum()


@pytest.mark.parametrize("name", MAPS)
def test_samples_follow_pdf(name):
    image = MAPS[name]()
    height, width = image.shape[:2]
    env, _keep = environment_data(image=image)
    d, _, _ = sample(env, np.random.default_rng(4).random((N_SAMPLES, 2)))
    # 1.5 bins per pixel row and column: every second bin edge cuts a pixel in half.
    n_v, n_u = 3 * height // 2 + 1, 3 * width // 2 + 1
    p_value, total = latlong_histogram_test(env, d, n_v, n_u, 2 * height, 2 * width)
    assert total == pytest.approx(1.0, abs=1e-5)
    assert p_value > SIGNIFICANCE


@pytest.mark.parametrize("name", MAPS)
@pytest.mark.parametrize("seed", [4, 5])
def test_sample_pdf_equals_env_pdf(name, seed):
    """Equal but where float32 rounding carries a sample drawn next to a pixel edge across it (about one in
    a million): the sample keeps the density of the pixel it was drawn in, env_pdf gives the other's.
    """
    image = MAPS[name]()
    env, _keep = environment_data(image=image)
    d, density, _ = sample(env, np.random.default_rng(seed).random((N_SAMPLES, 2)))
    assert np.all(np.isfinite(density)) and np.all(density > 0.0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)

    differs = ~np.isclose(density, pdf(env, d), rtol=1e-5, atol=0.0)
    assert np.count_nonzero(differs) <= 3
    pixel_coordinates = to_uv(d[differs]) * [image.shape[1], image.shape[0]]
    distance_to_edge = np.abs(pixel_coordinates - np.round(pixel_coordinates)).min(axis=1)
    assert np.all(distance_to_edge < 1e-3)


@pytest.mark.parametrize("name", MAPS)
def test_importance_sampled_integral_matches_pixel_sum(name):
    """(1/N) Σ L(d)/p(d) over samples of env_sample against Σ_pixels L × Ω_pixel, per channel, within 1%."""
    image = MAPS[name]()
    env, _keep = environment_data(image=image, scale=0.5)
    exact = 0.5 * np.einsum("hwc,h->c", image.astype(np.float64), pixel_solid_angles(*image.shape[:2]))
    _, density, value = sample(env, np.random.default_rng(6).random((N_SAMPLES, 2)))
    np.testing.assert_allclose((value / density[:, None]).mean(axis=0), exact, rtol=0.01)


def test_constant_map_behaves_like_constant_light():
    colour = np.array([0.3, 0.6, 0.9])
    light, _ = environment_data(radiance=colour)
    image_light, _keep = environment_data(image=np.broadcast_to(colour, (16, 32, 3)).astype(np.float32))
    u = np.random.default_rng(7).random((N_SAMPLES, 2))

    d, density, value = sample(light, u)
    np.testing.assert_allclose(density, 1.0 / (4.0 * np.pi), rtol=1e-6)
    np.testing.assert_allclose(value / density[:, None], np.broadcast_to(4.0 * np.pi * colour, value.shape), rtol=1e-5)
    # Uniform on the sphere: height uniform on [−1, 1] (Archimedes) and azimuth uniform.
    assert kstest(d[:, 1], "uniform", args=(-1.0, 2.0)).pvalue > SIGNIFICANCE
    assert kstest(np.arctan2(d[:, 0], -d[:, 2]), "uniform", args=(-np.pi, 2.0 * np.pi)).pvalue > SIGNIFICANCE

    np.testing.assert_allclose(radiance(image_light, d), radiance(light, d), rtol=1e-6)
    _, density, value = sample(image_light, u)
    np.testing.assert_allclose((value / density[:, None]).mean(axis=0), 4.0 * np.pi * colour, rtol=0.01)


def edge_uniforms():
    """Uniforms at and next to 0 and 1 in both components: the poles, the seam at u = 0, the last pixel."""
    edges = [0.0, 1e-7, 0.5, 1.0 - 1e-6, LARGEST_BELOW_ONE]
    return np.array([(a, b) for a in edges for b in edges])


@pytest.mark.parametrize("image", [np.zeros((16, 32, 3), np.float32), bright_pixel_map(row=0, column=0)])
def test_black_map_and_poles_stay_finite(image):
    """An all-black map falls back to uniform sampling; a map lit only at a pole keeps a finite density."""
    env, _keep = environment_data(image=image)
    u = np.concatenate([edge_uniforms(), np.random.default_rng(8).random((10_000, 2))])
    d, density, value = sample(env, u)
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(density)) and np.all(density > 0.0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    assert np.all(np.isfinite(value / density[:, None]))

    poles = np.array([[0, 1, 0], [0, -1, 0], [0, 1, 1e-7], [1e-7, -1, 0]], dtype=np.float32)
    queries = np.concatenate([poles, d.astype(np.float32)])
    assert np.all(np.isfinite(pdf(env, queries))) and np.all(np.isfinite(radiance(env, queries)))
    if not image.any():
        np.testing.assert_allclose(density, 1.0 / (4.0 * np.pi), rtol=1e-6)
        np.testing.assert_allclose(pdf(env, queries), 1.0 / (4.0 * np.pi), rtol=1e-6)
        assert not value.any()


@pytest.mark.parametrize("kwargs", [{"radiance": 0.0}, {}])
def test_black_constant_light(kwargs):
    env, _ = environment_data(**kwargs)
    _, density, value = sample(env, edge_uniforms())
    np.testing.assert_allclose(density, 1.0 / (4.0 * math.pi), rtol=1e-6)
    assert not value.any()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"radiance": 1.0, "image": np.ones((2, 4, 3), np.float32)},
        {"image": np.ones((4, 3), np.float32)},
        {"image": np.ones((2, 4, 4), np.float32)},
        {"image": np.full((2, 4, 3), -1.0, np.float32)},
        {"image": np.full((2, 4, 3), np.nan, np.float32)},
        {"radiance": (1.0, -1.0, 0.0)},
        {"radiance": 1.0, "scale": -1.0},
    ],
)
def test_invalid_input_is_rejected(kwargs):
    with pytest.raises(ValueError):
        environment_data(**kwargs)


def _cycles_pixel(direction, width, height):
    """(row from the top, column) Cycles' Environment Texture with Closest interpolation reads for a lookup
    direction: its u = (π − atan2(y, x)) / 2π, v = 1 − acos(z) / π with v = 0 at the bottom row
    (kernel/geom, `direction_to_equirectangular`, range (−2π, π, −π, π))."""
    x, y, z = direction.T
    u = ((np.pi - np.arctan2(y, x)) / (2 * np.pi)) % 1.0
    v = 1.0 - np.arccos(np.clip(z, -1, 1)) / np.pi
    return height - 1 - np.minimum((v * height).astype(int), height - 1), np.minimum((u * width).astype(int), width - 1)


@pytest.mark.parametrize("rotation_z", [0.0, 45.0, -90.0, 202.5])
def test_from_blender_reads_what_cycles_reads_in_the_converted_scene(rotation_z):
    """For a direction d in the Y-up scene, warp-hair's lookup of the converted map finds the pixel that Cycles
    finds for the same direction in the Z-up Blender scene (b = (d.x, −d.z, d.y)) turned by the Mapping node's
    Z rotation. Rotations here are whole columns (W = 64: 5.625° a column), where the conversion is exact."""
    height, width = 32, 64
    image = np.random.default_rng(3).uniform(0.0, 1.0, (height, width, 3)).astype(np.float32)
    converted = from_blender(image, rotation_z)
    d = np.random.default_rng(4).normal(size=(20_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    uv = wp.zeros(len(d), dtype=wp.vec2)
    wp.launch(_direction_to_uv_kernel, dim=len(d), inputs=[wp.array(d, dtype=wp.vec3)], outputs=[uv])
    uv = uv.numpy().astype(np.float64)
    ours = converted[(uv[:, 1] * height).astype(int), (uv[:, 0] * width).astype(int)]
    b = np.stack([d[:, 0], -d[:, 2], d[:, 1]], axis=1)
    c, s = math.cos(math.radians(rotation_z)), math.sin(math.radians(rotation_z))
    lookup = b @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    row, column = _cycles_pixel(lookup, width, height)
    # Directions within float32 rounding of a pixel edge may land either side in the two computations.
    u_cycles = ((np.pi - np.arctan2(lookup[:, 1], lookup[:, 0])) / (2 * np.pi)) % 1.0 * width
    v_ours = uv[:, 1] * height
    clear = (np.abs(u_cycles - np.round(u_cycles)) > 1e-3) & (np.abs(v_ours - np.round(v_ours)) > 1e-3)
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(ours[clear], image[row, column][clear])


def test_from_blender_rejects_bad_input():
    with pytest.raises(ValueError, match="rotation_z"):
        from_blender(np.ones((4, 8, 3), np.float32), float("nan"))
    with pytest.raises(ValueError, match="shape"):
        from_blender(np.ones((4, 8), np.float32))
