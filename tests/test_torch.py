"""warp_hair.torch: the autograd Function's gradient is render_grad's, a torch.optim loop recovers an albedo,
and bad controls are refused by name."""

import dataclasses

import numpy as np
import pytest
import torch
from helpers.scenes import swatch_scene

from warp_hair.renderer.gradients import render_grad
from warp_hair.renderer.render import render
from warp_hair.torch import default_grad_seed, render_torch, render_torch_pair

LIGHTS = [
    {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
    {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
]


def small_scene(hair, resolution=(12, 12)):
    return swatch_scene(hair, LIGHTS, resolution=resolution, render_table={"spp": 8, "max_depth": 8, "seed": 1})


def test_backward_equals_render_grad():
    scene = small_scene({"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.35})
    albedo = torch.tensor([0.6, 0.5, 0.4], requires_grad=True)
    beta_n = torch.tensor(0.3, requires_grad=True)
    eta = torch.tensor(1.6)  # passed, but no gradient wanted
    image = render_torch(scene, {"albedo": albedo, "beta_n": beta_n, "eta": eta}, spp=8, seed=5)
    assert image.shape == (12, 12, 3) and image.dtype == torch.float32

    # The primal is render's image of the same controls and seed.
    substituted = dataclasses.replace(
        scene, hair=scene.hair.replace(albedo=albedo.detach().tolist(), beta_n=beta_n.item(), eta=eta.item())
    )
    np.testing.assert_array_equal(image.detach().numpy(), render(substituted, spp=8, seed=5))

    target = torch.full_like(image, 0.2)
    loss = 0.5 * ((image - target) ** 2).sum()
    loss.backward()
    assert eta.grad is None

    adjoint = (image - target).detach().numpy()
    expected = render_grad(substituted, adjoint, spp=8, seed=default_grad_seed(5))
    assert default_grad_seed(5) != 5
    np.testing.assert_array_equal(albedo.grad.numpy(), expected["albedo"].astype(np.float32))
    assert beta_n.grad.shape == () and beta_n.grad.item() == np.float32(expected["beta_n"])
    assert np.any(albedo.grad.numpy() != 0)

    # An explicit grad_seed is used as given.
    beta_n.grad = None
    image = render_torch(scene, {"beta_n": beta_n}, spp=8, seed=5, grad_seed=77)
    image.sum().backward()
    scene_b = dataclasses.replace(scene, hair=scene.hair.replace(beta_n=beta_n.item()))
    expected = render_grad(scene_b, np.ones((12, 12, 3)), spp=8, seed=77)
    assert beta_n.grad.item() == np.float32(expected["beta_n"])


def test_pair_meets_each_adjoint_with_the_other_images_jacobian():
    scene = small_scene({"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.35})
    albedo = torch.tensor([0.6, 0.5, 0.4], requires_grad=True)
    beta_m = torch.tensor(0.25, requires_grad=True)
    pair = render_torch_pair(scene, {"albedo": albedo, "beta_m": beta_m}, spp=8, seed=5)
    assert pair.shape == (2, 12, 12, 3)
    substituted = dataclasses.replace(scene, hair=scene.hair.replace(albedo=albedo.detach().tolist(), beta_m=0.25))
    seeds = (5, default_grad_seed(5))
    for image, seed in zip(pair, seeds):
        np.testing.assert_allclose(image.detach().numpy(), render(substituted, spp=8, seed=seed), rtol=1e-5, atol=1e-7)

    # Different targets per image make the two adjoints differ, so a swap that was not done would show.
    loss = 0.5 * ((pair[0] - 0.2) ** 2).sum() + 0.5 * ((pair[1] - 0.05) ** 2).sum()
    loss.backward()
    adjoints = [(pair[0] - 0.2).detach().numpy(), (pair[1] - 0.05).detach().numpy()]
    crossed = [
        render_grad(substituted, adjoints[0], spp=8, seed=seeds[1]),
        render_grad(substituted, adjoints[1], spp=8, seed=seeds[0]),
    ]
    np.testing.assert_allclose(albedo.grad.numpy(), crossed[0]["albedo"] + crossed[1]["albedo"], rtol=1e-5)
    np.testing.assert_allclose(beta_m.grad.item(), crossed[0]["beta_m"] + crossed[1]["beta_m"], rtol=1e-5)
    uncrossed = sum(render_grad(substituted, a, spp=8, seed=seed)["beta_m"] for a, seed in zip(adjoints, seeds))
    assert not np.isclose(beta_m.grad.item(), uncrossed, rtol=1e-3)


def test_adam_recovers_albedo():
    """Target at grey albedo 0.4, start at 0.7, Adam on logit(albedo) with a fresh seed every iteration.

    Lit by a constant sky only: a directional light on the dense swatch gives heavy-tailed pixels (glints), a
    target whose 32-spp mean was 9% under its expectation, and gradients too noisy for a 25-step test."""
    scene = swatch_scene(
        {"albedo": 0.7, "beta_m": 0.3, "beta_n": 0.3},
        [{"type": "environment", "radiance": [1.0, 1.0, 1.0]}],
        resolution=(12, 12),
        render_table={"spp": 8, "max_depth": 8, "seed": 1},
    )
    eval_seed, eval_spp = 3, 256
    target = render_torch(scene, {"albedo": torch.full((3,), 0.4)}, spp=eval_spp, seed=eval_seed)

    def eval_loss(albedo):
        # Common random numbers with the target: exactly 0 at albedo 0.4.
        with torch.no_grad():
            image = render_torch(scene, {"albedo": albedo.expand(3)}, spp=eval_spp, seed=eval_seed)
            return float(((image - target) ** 2).mean())

    latent = torch.logit(torch.tensor(0.7)).requires_grad_()
    initial = eval_loss(torch.sigmoid(latent))
    opt = torch.optim.Adam([latent], lr=0.3, betas=(0.5, 0.9))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=0.88)
    for it in range(25):
        opt.zero_grad()
        image = render_torch(scene, {"albedo": torch.sigmoid(latent).expand(3)}, spp=8, seed=100 + it)
        loss = ((image - target) ** 2).mean()
        loss.backward()
        opt.step()
        sched.step()
    albedo = torch.sigmoid(latent).detach()
    final = eval_loss(albedo)
    assert abs(albedo.item() - 0.4) < 0.03, albedo.item()
    assert final < initial / 50, (initial, final)


@pytest.mark.parametrize(
    "controls, words",
    [
        ({"albedoo": torch.tensor([0.5] * 3)}, ["'albedoo'", "unknown"]),
        ({"sigma_a": torch.tensor([0.5] * 3)}, ["'sigma_a'", "albedo"]),
        ({"eumelanin": torch.tensor(1.0)}, ["'eumelanin'", "albedo"]),
        ({"albedo": torch.tensor(0.5)}, ["'albedo'", "shape"]),
        ({"albedo": torch.tensor([0.5, 0.5])}, ["'albedo'", "shape"]),
        ({"beta_m": torch.tensor([0.3])}, ["'beta_m'", "shape"]),
        ({"beta_m": torch.tensor(float("nan"))}, ["'beta_m'", "NaN"]),
        ({"eta": torch.tensor(2)}, ["'eta'", "floating"]),
        ({"beta_m": torch.tensor(1.5)}, ["beta_m"]),  # HairParams' range check
    ],
)
def test_bad_controls(controls, words):
    scene = small_scene({"albedo": 0.5}, resolution=(4, 4))
    with pytest.raises(ValueError) as info:
        render_torch(scene, controls, spp=1)
    for word in words:
        assert word in str(info.value), str(info.value)


def test_melanin_scene_controls():
    scene = small_scene({"eumelanin": 1.0}, resolution=(4, 4))
    eu = torch.tensor(1.0, requires_grad=True)
    pheo = torch.tensor(0.2, requires_grad=True)
    render_torch(scene, {"eumelanin": eu, "pheomelanin": pheo}, spp=2).sum().backward()
    assert eu.grad.shape == () and pheo.grad.shape == ()
    with pytest.raises(ValueError, match="'albedo'"):
        render_torch(scene, {"albedo": torch.tensor([0.5] * 3)}, spp=1)
