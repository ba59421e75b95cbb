"""Preparing a scene once (fibers, BVH, camera, lights) for many renders: the renders of a prepared scene, with
its own hair or another, are bit for bit those of the plain scene, and a fit builds each image's BVH once."""

import dataclasses

import numpy as np
import pytest
import torch

from warp_hair.renderer.gradients import render_grad, render_jacobian
from warp_hair.renderer.prepare import PreparedScene, prepare
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict
from warp_hair.torch import render_torch_pair, scene_with_controls


def small_scene():
    return scene_from_dict(
        {
            "camera": {
                "type": "orthographic",
                "origin": [0.0, 0.0, 3.0],
                "target": [0.0, 0.0, 0.0],
                "up": [0.0, 1.0, 0.0],
                "width": 0.3,
                "resolution": [12, 10],
            },
            "lights": [
                {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
                {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
            ],
            "fibers": {"generator": "swatch", "count": 60, "layers": 3, "length": 0.6, "radius": 0.004, "seed": 3},
            "hair": {"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.3},
            "render": {"spp": 4, "max_depth": 16, "seed": 1},
            "card": {"albedo": [0.5, 0.5, 0.5]},
        }
    )


OTHER_HAIR = {"albedo": [0.2, 0.5, 0.7], "beta_m": 0.2, "beta_n": 0.5, "alpha": -1.5, "eta": 1.6}


def test_prepared_render_is_the_plain_render_bit_for_bit():
    scene = small_scene()
    prepared = prepare(scene)
    other = scene_with_controls(scene, OTHER_HAIR)
    for plain, cached in ((scene, prepared), (other, prepared.with_hair(other.hair))):
        image, stderr = render(plain, seed=5, return_stderr=True)
        image_p, stderr_p = render(cached, seed=5, return_stderr=True)
        np.testing.assert_array_equal(image_p, image)
        np.testing.assert_array_equal(stderr_p, stderr)
    # The other hair changes the image (the check above is not comparing two renders of one thing).
    assert not np.array_equal(render(scene, seed=5), render(other, seed=5))


def test_with_hair_shares_the_geometry_and_leaves_the_original_alone():
    scene = small_scene()
    prepared = prepare(scene)
    before = render(prepared, seed=2)
    other = prepared.with_hair(scene_with_controls(scene, OTHER_HAIR).hair)
    assert other.bvh is prepared.bvh and other.lights is prepared.lights
    assert other.scene.hair != prepared.scene.hair and prepared.scene.hair == scene.hair
    np.testing.assert_array_equal(render(prepared, seed=2), before)
    assert prepare(prepared) is prepared


def test_prepared_jacobian_and_gradient_are_the_plain_ones_bit_for_bit():
    scene = scene_with_controls(small_scene(), OTHER_HAIR)
    prepared = prepare(small_scene()).with_hair(scene.hair)
    for a, b in zip(render_jacobian(scene, seed=3), render_jacobian(prepared, seed=3)):
        np.testing.assert_array_equal(b, a)
    adjoint = np.random.default_rng(0).normal(size=(10, 12, 3))
    plain, cached = render_grad(scene, adjoint, seed=4), render_grad(prepared, adjoint, seed=4)
    assert plain.keys() == cached.keys()
    for name in plain:
        np.testing.assert_array_equal(cached[name], plain[name])


def test_prepared_torch_pair_is_the_plain_one_bit_for_bit():
    scene = small_scene()
    prepared = prepare(scene)
    results = []
    for s in (scene, prepared):
        albedo = torch.tensor([0.3, 0.5, 0.6], dtype=torch.float64, requires_grad=True)
        beta_m = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
        pair = render_torch_pair(s, {"albedo": albedo, "beta_m": beta_m}, spp=2, seed=9)
        (pair**2).sum().backward()
        results.append((pair.detach().numpy(), albedo.grad.numpy(), beta_m.grad.numpy()))
    for a, b in zip(*results):
        np.testing.assert_array_equal(b, a)


def test_prepare_rejects_what_it_cannot_use():
    prepared = prepare(small_scene())
    with pytest.raises(TypeError, match="Scene or a PreparedScene"):
        prepare({"camera": {}})
    # A device the machine lacks is named first (no machine has 100 GPUs); another one that exists:
    # tests/test_device.py.
    with pytest.raises(ValueError, match=r"device = 'cuda:99'.*available: cpu"):
        prepare(prepared, device="cuda:99")
    with pytest.raises(TypeError, match="hair must be a HairParams"):
        prepared.with_hair({"albedo": 0.5})


def test_fit_builds_each_images_scene_once(monkeypatch):
    """A fit of a two-image target prepares two scenes, however many renders its iterations and Gauss–Newton
    steps make."""
    from optimize import fit
    from optimize.target import Target, TargetImage

    scene = small_scene()
    back = dataclasses.replace(scene, lights=[scene.lights[1]])
    images = [
        TargetImage(name, s, render(s, spp=8, seed=11), None, None) for name, s in (("front", scene), ("back", back))
    ]
    target = Target("tiny", None, images, None)
    built = []
    original = PreparedScene.__init__

    def counting(self, *args, **kwargs):
        built.append(1)
        original(self, *args, **kwargs)

    monkeypatch.setattr(PreparedScene, "__init__", counting)
    result = fit(target, iters=3, spp=2, refine=2, uncertainty=False, progress=False)
    assert result.iterations == 3 and len(result.history.refine) == 2
    assert len(built) == len(images)
