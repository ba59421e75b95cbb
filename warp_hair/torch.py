"""A differentiable render for PyTorch: the hair controls as tensors in, the image as a tensor out.

    from warp_hair.torch import render_torch

    albedo = torch.tensor([0.6, 0.4, 0.3], requires_grad=True)
    beta_m = torch.tensor(0.3, requires_grad=True)
    image = render_torch(scene, {"albedo": albedo, "beta_m": beta_m}, spp=16, seed=it)   # (H, W, 3) float32
    loss = any_torch_loss(image, target)          # e.g. torch.nn.functional.mse_loss(image, target)
    loss.backward()                               # albedo.grad, beta_m.grad

Controls are named as in `HairParams.to_dict()`: the colour under the scene's own colour input ("albedo" or
"sigma_a" as (3,) tensors, or "eumelanin" and "pheomelanin" as 0-d tensors), then the 0-d scalars "beta_m",
"beta_n", "alpha" (degrees), "eta" and "r_roughness_scale". Controls not passed keep the scene's values. A name
that is not a control, a colour control of another colour input than the scene's, or a tensor of the wrong
shape raises ValueError naming the control; values outside a control's range raise HairParams' ValueError.
To optimise a grey albedo through one scalar, pass `scalar.expand(3)`; torch sums the gradient back.

With torch.optim, optimise unconstrained latents and map them into each control's range inside the loop, so
that every step gives valid controls (albedo in (0, 1], roughness in [0, 1], η > 1):

    latent = torch.logit(torch.tensor(0.7)).requires_grad_()
    opt = torch.optim.Adam([latent], lr=0.1)
    for it in range(n):
        opt.zero_grad()
        image = render_torch(scene, {"albedo": torch.sigmoid(latent).expand(3)}, spp=4, seed=it)
        loss = ((image - target) ** 2).mean()
        loss.backward()
        opt.step()

Use a fresh `seed` each iteration (the noise then averages out over the iterations instead of biasing every
step the same way).

How the gradient is computed: the forward pass is `render(scene', spp, seed)` with the controls substituted
(scene' = the scene with its hair replaced). The backward pass receives ∂loss/∂image = grad_output and calls
`render_grad(scene', adjoint=grad_output, spp, grad_seed)`, which returns ∂/∂θ Σ adjoint ⊙ image, i.e. the
chain rule ∂loss/∂θ = Σ (∂loss/∂image)(∂image/∂θ), estimated by Monte Carlo.

Why the gradient pass uses another seed: for a nonlinear loss the adjoint depends on the primal image (for
0.5‖image − target‖² it is image − target). If the primal and the gradient estimate came from the same random
paths their errors would be correlated, and E[adjoint(image) · ∂image] ≠ adjoint(E[image]) · E[∂image]: the
gradient would be biased (for the squared error, by a covariance term that pulls toward making the noise
itself smaller or larger, not the image closer to the target). With independent random streams the two
estimates are independent, and the expected gradient is the gradient of the expected loss to first order.
So `grad_seed` defaults to (seed + 1_000_003) mod 2**32, never equal to `seed`; pass it explicitly to
reproduce a gradient, e.g. to compare with `render_grad(scene', adjoint, spp, seed=grad_seed)` (the numbers
are the same, whatever `threads`).

`render_torch_pair(scene, controls, spp, seed)` returns two independent renders (2, H, W, 3) for losses that
add a term per image: its backward pass meets each image's adjoint with the other's Jacobian, which the same
pass computed, so it needs no second tracing of the paths (what `optimize.fit` uses; see its docstring).

`scene` may be a `warp_hair.prepare(scene)`: a loop that renders the same scene with new controls then
builds its BVH once, not once per render (the images are the same, bit for bit).

Where it renders: on `device` when given ("cpu", "cuda", "cuda:N"), else on a prepared scene's device, else on
the first control tensor's GPU if it is a CUDA tensor, else on the CPU (`render_device`). The image is returned on
the device of the first control tensor (the render device if none), and gradients have each control's dtype and
device. On a GPU the image and the Jacobians are torch views of Warp's arrays, made on torch's current stream,
and the adjoint meets the Jacobian there: only the controls (a few floats, the kernel's launch arguments) go
to the host per render. Double backward is not supported.
"""

from __future__ import annotations

import contextlib
import dataclasses

import torch
import warp as wp

from .controls import COLOUR_CONTROLS, CONTROL_NAMES, RGB_CONTROLS, controls_of, named_theta
from .devices import check_device, is_cpu
from .renderer.gradients import contract
from .renderer.prepare import PreparedScene, sampling, scene_of
from .renderer.render import launch_pixels
from .scene import Scene

GRAD_SEED_OFFSET = 1_000_003
SEED_MODULUS = 2**32


def default_grad_seed(seed: int) -> int:
    """The gradient pass's seed when none is given: another random stream than the primal's."""
    return (int(seed) + GRAD_SEED_OFFSET) % SEED_MODULUS


def allowed_controls(scene: Scene | PreparedScene) -> tuple:
    """The control names `render_torch` accepts for this scene (its colour input's, then the scalars)."""
    return controls_of(scene_of(scene).hair.colour_input)


def _check_controls(scene: Scene | PreparedScene, controls: dict) -> dict:
    """Validate names and shapes; returns {name: tensor} in a fixed order."""
    if not isinstance(controls, dict):
        raise ValueError(f"controls must be a dict of name → tensor, got {type(controls).__name__}")
    allowed = allowed_controls(scene)
    mode = scene_of(scene).hair.colour_input
    checked = {}
    for name, value in controls.items():
        if name not in allowed:
            if name in CONTROL_NAMES:
                raise ValueError(
                    f"control {name!r} does not apply: the scene's hair colour is given as {mode!r}, so the "
                    f"colour control is {' / '.join(repr(n) for n in COLOUR_CONTROLS[mode])}; "
                    f"allowed: {list(allowed)}"
                )
            raise ValueError(f"unknown control {name!r}; allowed for this scene: {list(allowed)}")
        if not isinstance(value, torch.Tensor):
            try:
                value = torch.as_tensor(value, dtype=torch.float32)
            except (TypeError, ValueError, RuntimeError):
                raise ValueError(f"control {name!r} must be a tensor or a number, got {value!r}") from None
        if not (value.is_floating_point()):
            raise ValueError(f"control {name!r} must be a floating-point tensor, got dtype {value.dtype}")
        expected = (3,) if name in RGB_CONTROLS else ()
        if tuple(value.shape) != expected:
            hint = " (for a grey value use t.expand(3))" if expected else " (use a 0-d tensor, e.g. t.squeeze())"
            raise ValueError(f"control {name!r} must have shape {expected}, got {tuple(value.shape)}{hint}")
        if not torch.isfinite(value.detach()).all():
            raise ValueError(f"control {name!r} has NaN or infinite entries: {value.detach().tolist()}")
        checked[name] = value
    return {name: checked[name] for name in allowed if name in checked}


def scene_with_controls(scene: Scene | PreparedScene, values: dict) -> Scene | PreparedScene:
    """A copy of the scene with the named controls (floats, or lists of three for RGB) replacing its own; of a
    prepared scene, the prepared scene with the new hair (its BVH shared, not rebuilt)."""
    if not values:
        return scene
    hair = scene_of(scene).hair.replace(**values)
    if isinstance(scene, PreparedScene):
        return scene.with_hair(hair)
    return dataclasses.replace(scene, hair=hair)


def _to_python(name, tensor):
    t = tensor.detach().to("cpu", torch.float64)
    return [float(v) for v in t.tolist()] if name in RGB_CONTROLS else float(t.item())


def _scene_for(scene, names, tensors):
    return scene_with_controls(scene, {name: _to_python(name, t) for name, t in zip(names, tensors)})


def render_device(scene: Scene | PreparedScene, tensors, device=None) -> str:
    """The Warp device a render of `scene` with these control tensors runs on: `device` when given, else a
    prepared scene's own, else the first control tensor's when it is a GPU's (CUDA tensors render on their GPU),
    else "cpu"."""
    if device is not None:
        return check_device(device)
    if isinstance(scene, PreparedScene):
        return scene.device
    if tensors and tensors[0].device.type == "cuda":
        return check_device(tensors[0].device, "the controls' device")
    return "cpu"


def _on_torch_stream(device: str):
    """On a GPU, Warp's launches go on torch's current stream of that GPU, so that torch's operations on the
    image and the Jacobian are ordered after them without a synchronisation (Warp has streams of its own
    otherwise); nothing to do on the CPU."""
    if is_cpu(device):
        return contextlib.nullcontext()
    return wp.ScopedStream(wp.stream_from_torch(wp.device_to_torch(device)))


def _as_tensor(array, resolution, *shape) -> torch.Tensor:
    """A flat Warp array of a render, as a torch tensor (H, W, *shape) on its device, sharing its memory."""
    width, height = resolution
    return wp.to_torch(array, requires_grad=False).reshape(height, width, *shape)


def _contract(adjoint: torch.Tensor, jacobian: torch.Tensor) -> torch.Tensor:
    """(8,) float64 on the Jacobian's device: Σ adjoint ⊙ jacobian over pixels and channels. On the CPU by
    `gradients.contract`, render_grad's own sum (so the two agree bit for bit); on a GPU the same sum in torch,
    where the Jacobian is: nothing of the image size goes to the host."""
    adjoint = adjoint.detach().to(jacobian.device, torch.float64)
    if jacobian.device.type == "cpu":
        return torch.from_numpy(contract(adjoint.numpy(), jacobian.numpy()))
    return torch.einsum("hwc,hwck->k", adjoint, jacobian.to(torch.float64))


def _control_gradients(ctx, theta_gradient: torch.Tensor):
    """Per-control torch gradients from the 8 θ components, in each input's dtype and device."""
    named = named_theta(scene_of(ctx.scene).hair.colour_input, theta_gradient)
    out = []
    for name, need, (dtype, device) in zip(ctx.names, ctx.needs_input_grad[2:], ctx.meta):
        shape = (3,) if name in RGB_CONTROLS else ()
        out.append(named[name].to(device=device, dtype=dtype).reshape(shape) if need else None)
    return (None, None, *tuple(out))


def _begin(ctx, scene, names, tensors, device):
    """Keep what backward needs of the inputs; the scene with the controls substituted."""
    ctx.scene = _scene_for(scene, names, tensors)
    ctx.names = names
    ctx.meta = [(t.dtype, t.device) for t in tensors]
    ctx.device = device
    # The image goes back where the controls are (torch's rule for a function of them), else where it was made.
    ctx.out_device = tensors[0].device if tensors else torch.device(wp.device_to_torch(device))
    return ctx.scene


def _no_gradients(ctx):
    """backward's answer when no control needs a gradient: None for config, names and each tensor."""
    return (None, None) + (None,) * len(ctx.meta)


class _RenderFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, config, names, *tensors):
        scene, spp, seed, grad_seed, threads, device = config
        scene = _begin(ctx, scene, names, tensors, device)
        ctx.spp, ctx.grad_seed, ctx.threads = spp, grad_seed, threads
        with _on_torch_stream(device):
            prepared, image, _, _ = launch_pixels(scene, spp, seed, threads, device, False)
            return _as_tensor(image, prepared.resolution, 3).to(ctx.out_device)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_output):
        if not any(ctx.needs_input_grad[2:]):
            return _no_gradients(ctx)
        with _on_torch_stream(ctx.device):
            prepared, _, _, jacobian = launch_pixels(ctx.scene, ctx.spp, ctx.grad_seed, ctx.threads, ctx.device, True)
            theta = _contract(grad_output, _as_tensor(jacobian, prepared.resolution, 3, -1))
        return _control_gradients(ctx, theta)


class _PairFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, config, names, *tensors):
        scenes, spp, seeds, threads, pixels, device = config
        first = _begin(ctx, scenes[0], names, tensors, device)
        images, ctx.jacobians = [], []
        with _on_torch_stream(device):
            for scene, seed in zip((first, _scene_for(scenes[1], names, tensors)), seeds):
                prepared, image, _, jacobian = launch_pixels(scene, spp, seed, threads, device, True, pixels=pixels)
                images.append(_as_tensor(image, prepared.resolution, 3))
                ctx.jacobians.append(_as_tensor(jacobian, prepared.resolution, 3, -1))
            return torch.stack(images).to(ctx.out_device)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_output):
        if not any(ctx.needs_input_grad[2:]):
            return _no_gradients(ctx)
        # Each image's adjoint meets the other image's Jacobian (independent paths: an unbiased product).
        with _on_torch_stream(ctx.device):
            theta = _contract(grad_output[0], ctx.jacobians[1]) + _contract(grad_output[1], ctx.jacobians[0])
        return _control_gradients(ctx, theta)


def _checked_seed(name, seed):
    seed = int(seed)
    if not 0 <= seed < SEED_MODULUS:
        raise ValueError(f"{name} must be in [0, 2**32), got {seed}")
    return seed


def render_torch(
    scene: Scene | PreparedScene, controls: dict, spp=None, seed=0, grad_seed=None, threads=None, device=None
) -> torch.Tensor:
    """The image (H, W, 3) float32 of `scene` with `controls` substituted, differentiable in the controls.

    controls: {name: tensor}, "albedo"/"sigma_a" (3,) or the 0-d scalars (see the module docstring); not
    passed ⇒ the scene's value. spp defaults to the scene's [render] spp. The forward pass renders with `seed`;
    the backward pass estimates the gradient with `grad_seed`, by default (seed + 1_000_003) mod 2**32, an
    independent random stream (see the module docstring for why). `device`: where to render (`render_device`).
    """
    checked = _check_controls(scene, controls)
    spp, _ = sampling(scene, spp)
    seed = _checked_seed("seed", seed)
    grad_seed = default_grad_seed(seed) if grad_seed is None else _checked_seed("grad_seed", grad_seed)
    config = (scene, spp, seed, grad_seed, threads, render_device(scene, tuple(checked.values()), device))
    return _RenderFunction.apply(config, tuple(checked), *checked.values())


def render_torch_pair(
    scene: Scene | PreparedScene, controls: dict, spp=None, seed=0, threads=None, pixels=None, device=None
) -> torch.Tensor:
    """Two independent renders (2, H, W, 3) of `scene` with `controls`, each at `spp`, in one pass each.

    For losses that add a term per image, ℓ(pair[0]) + ℓ(pair[1]): the backward pass contracts each image's
    adjoint with the *other* image's Jacobian, which its gradient pass computed along with the image
    (`render_jacobian`). The adjoint and the Jacobian it meets then come from independent paths, as
    `render_torch`'s separate gradient pass ensures, but nothing is traced twice: the pair costs two gradient
    passes at spp and gives the gradient and the loss of 2·spp samples, where `render_torch` costs a forward
    render and a gradient pass at spp for those of spp. (A loss that couples the two images, such as
    (pair[0] − T)·(pair[1] − T), would pair each adjoint with its own paths: use `render_torch` for those.)
    The seeds are `seed` and (seed + 1_000_003) mod 2**32. `pixels`: render only these flat pixel indices
    (`render`); the others are 0 in both images, and so is their gradient.

    `scene` may be a pair of scenes, one per render: two realisations of the same fibers' recipe
    (`warp_hair.realisation`), with the same camera, lights and resolution. The gradient is then unbiased for
    the loss of the image averaged over realisations, since each adjoint meets a Jacobian of independent
    strands as well as independent paths (optimize/realisations.py derives it). `device`: where to render
    (`render_device`; a pair of prepared scenes must share one).
    """
    scenes = tuple(scene) if isinstance(scene, (tuple, list)) else (scene, scene)
    if len(scenes) != 2:
        raise ValueError(f"render_torch_pair takes one scene or a pair of scenes, got {len(scenes)}")
    checked = _check_controls(scenes[0], controls)
    spp, _ = sampling(scenes[0], spp)
    if scene_of(scenes[1]).camera.resolution != scene_of(scenes[0]).camera.resolution:
        raise ValueError("render_torch_pair's two scenes must have the same camera resolution")
    seed = _checked_seed("seed", seed)
    device = render_device(scenes[0], tuple(checked.values()), device)
    config = (scenes, spp, (seed, default_grad_seed(seed)), threads, pixels, device)
    return _PairFunction.apply(config, tuple(checked), *checked.values())
