"""Which light a shadow ray goes to (renderer/light_sampler.py): the weights, the choice in a kernel, and renders
that stay unbiased whatever the choice (a scene's image is the sum of its images under each light alone)."""

import numpy as np
import pytest
import warp as wp
from helpers.scenes import swatch_scene

from warp_hair.io import write_exr
from warp_hair.renderer.envmap import peak_irradiance, pixel_directions
from warp_hair.renderer.light_sampler import choose_light, selection_cdf
from warp_hair.renderer.render import render
from warp_hair.scene import DirectionalLight, EnvironmentLight


def sun(irradiance):
    return DirectionalLight(direction=(0.3, -0.4, -1.0), irradiance=irradiance)


def test_each_light_weighs_the_irradiance_it_gives_a_surface_facing_it():
    """A directional light's E, channel means; a constant sky nothing beside other lights (the BSDF's own samples
    find it), so it is never chosen."""
    cdf = selection_cdf([sun((3.0, 3.0, 3.0)), sun((1.0, 2.0, 3.0))], EnvironmentLight(radiance=(0.3, 0.3, 0.3)))
    np.testing.assert_allclose(cdf, [0.6, 1.0, 1.0], rtol=1e-6)


def test_an_environment_weighs_the_most_irradiance_it_gives_a_surface():
    """Against closed forms: a constant sky gives a surface π L whichever way it faces; a sky bright above the
    horizon only, π L to a surface facing up; a disc of angular radius a, π L sin² a to a surface facing it. Above
    the least radiance (what the light sampler weighs): a constant sky gives nothing, and a disc on a constant sky
    what the disc gives alone."""
    np.testing.assert_allclose(peak_irradiance(radiance=(0.2, 0.4, 0.6)), np.pi * 0.4, rtol=1e-12)
    assert peak_irradiance(radiance=(0.2, 0.4, 0.6), above_least=True) == 0.0
    constant = np.full((32, 64, 3), 0.4, np.float32)
    np.testing.assert_allclose(peak_irradiance(image=constant), np.pi * 0.4, rtol=2e-3)
    assert peak_irradiance(image=constant, above_least=True) == 0.0
    upper = np.zeros((64, 128, 3), np.float32)
    upper[:32] = 1.0
    np.testing.assert_allclose(peak_irradiance(image=upper), np.pi, rtol=2e-3)
    height, width, radius = 512, 1024, np.radians(6.0)
    towards = np.array([0.6, 0.48, -0.64])
    inside = pixel_directions(width, height) @ towards > np.cos(radius)
    disc = np.where(inside[..., None], np.float32(50.0), np.float32(0.0)) * np.ones(3, np.float32)
    expected = np.pi * 50.0 * np.sin(radius) ** 2
    np.testing.assert_allclose(peak_irradiance(image=disc), expected, rtol=0.02)
    np.testing.assert_allclose(peak_irradiance(image=disc + np.float32(0.3), above_least=True), expected, rtol=0.02)


def test_black_lights_are_never_chosen_and_a_sky_alone_is():
    black = sun((0.0, 0.0, 0.0))
    sky = EnvironmentLight(radiance=(0.2, 0.2, 0.2))
    cdf = selection_cdf([black, sun((2.0, 2.0, 2.0)), black], EnvironmentLight(radiance=(0.0, 0.0, 0.0)))
    np.testing.assert_array_equal(cdf, [0.0, 1.0, 1.0, 1.0])
    np.testing.assert_array_equal(selection_cdf([], sky), [1.0])
    np.testing.assert_array_equal(selection_cdf([black], sky), [0.0, 1.0])
    np.testing.assert_allclose(selection_cdf([black, black], None), [0.5, 1.0])
    assert selection_cdf([], None).size == 0


@wp.kernel
def _choose(cdf: wp.array(dtype=float), u: wp.array(dtype=float), k: wp.array(dtype=int), p: wp.array(dtype=float)):
    i = wp.tid()
    chosen, probability = choose_light(cdf, u[i])
    k[i] = chosen
    p[i] = probability


def choose(cdf, u):
    n = len(u)
    k, p = wp.zeros(n, dtype=int), wp.zeros(n, dtype=float)
    wp.launch(_choose, dim=n, inputs=[wp.array(cdf, dtype=float), wp.array(u, dtype=float), k, p])
    return k.numpy(), p.numpy()


def test_the_choice_follows_the_probabilities_and_reports_them():
    """Over a fine grid of u (and the largest float32 below 1) each emitter is chosen as often as its probability
    says, which is the probability the kernel reports; a black emitter, inside or at the end, never."""
    cdf = selection_cdf([sun((3.0, 3.0, 3.0)), sun((0.0, 0.0, 0.0)), sun((0.5, 0.5, 0.5)), sun((1.0, 1.0, 1.0))], None)
    probabilities = np.diff(cdf, prepend=0.0)
    u = np.append((np.arange(200_000) + 0.5) / 200_000, np.nextafter(np.float32(1.0), np.float32(0.0)))
    k, p = choose(cdf, u.astype(np.float32))
    np.testing.assert_allclose(np.bincount(k, minlength=4) / len(u), probabilities, atol=2e-5)
    np.testing.assert_allclose(p, probabilities[k], rtol=1e-6)
    assert not np.any(k == 1)
    k, _ = choose(selection_cdf([sun((1.0, 1.0, 1.0)), sun((0.0, 0.0, 0.0))], None), u.astype(np.float32))
    assert np.all(k == 0)


@pytest.mark.parametrize("sky", ["constant", "map"])
def test_a_render_is_the_sum_of_its_renders_under_each_light(sky, tmp_path):
    """Light adds: the swatch under a sun and a sky renders to its render under the sun plus its render under the
    sky, within the standard error of their means. Beside the sun a constant sky is never light-sampled: its light
    comes from the BSDF's samples alone, whole (MIS weight 1). The map has a bright patch, which its light samples
    find: they share the shadow rays with the sun by their weights (not half each), and are combined with the BSDF's
    samples by MIS with the map's own probability. A wrong probability in either would show in the sum."""
    sun_light = {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}
    if sky == "constant":
        sky_light = {"type": "environment", "radiance": [0.3, 0.3, 0.3]}
    else:
        image = np.full((16, 32, 3), 0.05, np.float32)
        image[3:6, 10:14] = (4.0, 3.0, 2.0)
        write_exr(tmp_path / "sky.exr", image)
        sky_light = {"type": "environment", "file": str(tmp_path / "sky.exr")}
    hair = {"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.3}
    table = {"spp": 1024, "max_depth": 32, "seed": 4}
    lights = ([sun_light, sky_light], [sun_light], [sky_light])
    scenes = [swatch_scene(hair, each, resolution=(16, 16), render_table=table) for each in lights]
    means = [image_mean(scene, seed) for scene, seed in zip(scenes, (4, 11, 12))]
    difference = means[0][0] - means[1][0] - means[2][0]
    error = np.sqrt(sum(se**2 for _, se in means))
    assert abs(difference) < 4.0 * error, (difference, error)
    assert error < 0.01 * means[0][0]  # and that noise is small: the test tells a bias of 4%


def image_mean(scene, seed):
    """(the image's mean over pixels and channels, its standard error): pixels are independent, a pixel's channels
    share their paths (so their mean's error is taken as their errors' mean, an upper bound)."""
    image, stderr = render(scene, seed=seed, return_stderr=True)
    pixels = stderr.shape[0] * stderr.shape[1]
    return float(image.mean()), float(np.sqrt((stderr.mean(axis=2) ** 2).sum()) / pixels)
