"""Rendering on a GPU: the device option's plumbing and its error on every machine, the kernels compiled for a
CUDA architecture wherever Warp has NVRTC, and on a machine with a CUDA device the render, its Jacobian, the
torch front and a fit there agreeing with the CPU's."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import warp as wp
from helpers.scenes import swatch_scene

from optimize.cli import main as fit_main
from optimize.fit import FitRun, FitSettings, fit
from optimize.target import load_target
from warp_hair.cli import main
from warp_hair.devices import check_device
from warp_hair.renderer.gradients import contract, named_gradients, render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import pixel_jacobian_kernel, pixel_kernel, render
from warp_hair.torch import default_grad_seed, render_device, render_torch, render_torch_pair

HAS_CUDA = wp.get_cuda_device_count() > 0
needs_cuda = pytest.mark.skipif(not HAS_CUDA, reason="no CUDA device on this machine (Warp finds none)")
without_cuda = pytest.mark.skipif(HAS_CUDA, reason="tests the error on a machine without a CUDA device")
TARGET = Path(__file__).parents[1] / "targets" / "blonde_straight"
LIGHTS = [
    {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
    {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
]
HAIR = {"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.35}

# How far a GPU render may be from the CPU's. The kernel and the random streams are the same, so each path is
# the CPU's path up to rounding: NVRTC may contract a·b + c into one FMA where the CPU compiler does not, and
# CUDA's sqrt, exp, log and trigonometric functions (no fast math: within 2 ulp) are not libm's. A path of at
# most 8 bounces here takes of the order of 10³ float32 operations; errors of up to 2 ulp (1.2e-7) each that
# add up in the worst case reach about 1e-4 relative, RTOL. A rounding difference that decides a branch (a
# roulette or lobe choice, a ray grazing a tube's edge) sends a path elsewhere; that needs a random number
# within about 1e-6 of its threshold, of the order of 1e-6 × 50 decisions per path, so of the 2048 paths of a
# 16×16 render at 8 spp fewer than one is expected to: at most 1% of the values may differ by more.
RTOL = 1e-4
DIVERGED = 0.01


def small_scene():
    return swatch_scene(HAIR, LIGHTS, resolution=(16, 16), render_table={"spp": 8, "max_depth": 8, "seed": 1})


# -- Every machine: the option, its checks and errors. ---------------------------------------------------------


def test_check_device_names_the_option_and_the_devices():
    assert check_device(None) == "cpu"
    assert check_device("cpu") == check_device(torch.device("cpu")) == check_device(wp.get_device("cpu")) == "cpu"
    with pytest.raises(ValueError, match=r"--device = 'tpu' is not a device of this machine; available: cpu"):
        check_device("tpu", "--device")
    with pytest.raises(ValueError, match="must be a device name"):
        check_device(0)


@without_cuda
@pytest.mark.parametrize("name", ["cuda", "cuda:0", "cuda:1"])
def test_cuda_without_a_gpu_is_a_clear_error(name):
    with pytest.raises(ValueError, match=rf"device = '{name}', but .*; available: cpu$"):
        prepare(small_scene(), name)
    with pytest.raises(ValueError, match=rf"device = '{name}', but"):
        render(small_scene(), device=name)
    with pytest.raises(ValueError, match=rf"device = '{name}', but"):
        render_torch(small_scene(), {}, device=name)


def test_the_render_device_follows_the_prepared_scene_and_the_option():
    scene = small_scene()
    prepared = prepare(scene, "cpu")
    assert prepare(prepared, "cpu") is prepared
    with pytest.raises(ValueError, match="not a device of this machine"):
        prepare(prepared, "tpu")
    assert render_device(prepared, ()) == render_device(scene, (torch.tensor(0.3),)) == "cpu"
    assert render_device(scene, (), "cpu") == "cpu"


def test_device_cpu_is_the_default_render_bit_for_bit():
    scene = small_scene()
    beta_m = torch.tensor(0.25, requires_grad=True)
    image = render_torch(scene, {"beta_m": beta_m}, spp=2, seed=3, device="cpu")
    assert image.device == torch.device("cpu")
    default = render_torch(scene, {"beta_m": beta_m}, spp=2, seed=3)
    np.testing.assert_array_equal(image.detach().numpy(), default.detach().numpy())
    np.testing.assert_array_equal(render(scene, spp=2, seed=3, device="cpu"), render(scene, spp=2, seed=3))


def test_cli_refuses_an_unknown_device_before_any_work(tiny_scene, tmp_path, capsys):
    out = tmp_path / "x.exr"
    assert main(["render", str(tiny_scene), "-o", str(out), "--device", "tpu"]) == 2
    assert "warp-hair: error: --device = 'tpu' is not a device of this machine; available:" in capsys.readouterr().err
    assert not out.exists()
    assert fit_main(["fit", str(TARGET), "-o", str(tmp_path / "fit"), "--device", "tpu"]) == 2
    assert "--device = 'tpu'" in capsys.readouterr().err
    assert not (tmp_path / "fit").exists()


@without_cuda
def test_cli_names_the_missing_gpu(tiny_scene, tmp_path, capsys):
    assert main(["render", str(tiny_scene), "-o", str(tmp_path / "x.exr"), "--device", "cuda"]) == 2
    err = capsys.readouterr().err
    assert "warp-hair: error: --device = 'cuda', but" in err and "available: cpu" in err
    assert "Traceback" not in err


def test_fit_checks_its_device_setting():
    with pytest.raises(ValueError, match="device = 'tpu' is not a device"):
        fit(load_target(TARGET), iters=1, device="tpu", progress=False)


# -- Wherever Warp has NVRTC (its wheels link it; no driver needed): the kernels compile for a GPU. -----------

AOT_ARCH = 90  # sm_90 (Hopper); any architecture NVRTC supports would show a CPU-only construct as well


@pytest.mark.skipif(
    AOT_ARCH not in wp.get_cuda_supported_archs(),
    reason=f"Warp has no NVRTC here that compiles for sm_{AOT_ARCH} (a build without CUDA)",
)
@pytest.mark.parametrize("kernel", [pixel_kernel, pixel_jacobian_kernel], ids=["forward", "gradient"])
def test_render_kernels_compile_for_cuda(kernel, tmp_path):
    """The forward and gradient pixel kernels (which inline the integrator, the traversal, the BSDF and the
    lights) compiled to a cubin through NVRTC and ptxas, as a GPU render would load them (8 and 16 s on the
    shared 2-core machine: NVRTC compiles on one core, and nothing is cached between runs)."""
    paths = wp.compile_aot_module(kernel.module, arch=AOT_ARCH, module_dir=tmp_path, use_ptx=False)
    assert [p.suffix for p in paths] == [".cubin"]
    assert paths[0].stat().st_size > 10_000


# -- On a machine with a CUDA device: the same renders and gradients, and nothing read back per iteration. ----


def assert_same_render(gpu, cpu, what):
    """Within RTOL of the largest value (sums of signed Jacobian terms cancel), but for at most DIVERGED of
    the values (paths that a rounding difference sent elsewhere)."""
    assert np.isfinite(gpu).all(), what
    close = np.isclose(gpu, cpu, rtol=RTOL, atol=RTOL * np.abs(cpu).max())
    assert close.mean() >= 1 - DIVERGED, f"{what}: {np.count_nonzero(~close)} of {close.size} values differ"


@needs_cuda
def test_render_on_cuda_is_the_cpu_render():
    scene = small_scene()
    cpu, cpu_err = render(scene, device="cpu", return_stderr=True)
    gpu, gpu_err = render(prepare(scene, "cuda"), return_stderr=True)
    assert gpu.dtype == np.float32 and gpu.shape == cpu.shape
    assert_same_render(gpu, cpu, "image")
    assert_same_render(gpu_err, cpu_err, "standard error")
    assert np.abs(cpu).max() > 0
    # A subset of pixels renders as they come out in the whole image there too.
    pixels = np.array([0, 17, 100, 255])
    part = render(scene, device="cuda", pixels=pixels).reshape(-1, 3)
    np.testing.assert_array_equal(part[pixels], gpu.reshape(-1, 3)[pixels])


@needs_cuda
def test_jacobian_on_cuda_is_the_cpu_jacobian():
    scene = small_scene()
    cpu, cpu_image, _ = render_jacobian(scene, spp=4, seed=2, device="cpu")
    gpu, gpu_image, _ = render_jacobian(scene, spp=4, seed=2, device="cuda")
    assert_same_render(gpu_image, cpu_image, "image")
    for k in range(cpu.shape[-1]):
        assert_same_render(gpu[..., k], cpu[..., k], f"Jacobian column {k}")


@needs_cuda
def test_torch_front_keeps_cuda_tensors_on_the_gpu():
    scene = small_scene()
    albedo = torch.tensor([0.6, 0.5, 0.4], device="cuda", requires_grad=True)
    beta_m = torch.tensor(0.25, device="cuda", dtype=torch.float64, requires_grad=True)
    pair = render_torch_pair(scene, {"albedo": albedo, "beta_m": beta_m}, spp=4, seed=5)
    assert pair.device.type == "cuda" and pair.dtype == torch.float32 and pair.shape == (2, 16, 16, 3)
    targets = torch.tensor([0.2, 0.05], device="cuda").reshape(2, 1, 1, 1)
    (0.5 * ((pair - targets) ** 2).sum()).backward()
    assert albedo.grad.device.type == beta_m.grad.device.type == "cuda"
    assert beta_m.grad.dtype == torch.float64 and beta_m.grad.shape == ()

    # The gradient is the crossed contraction of the GPU's own Jacobians (the same seeds), summed on the host.
    hair = scene.hair.replace(albedo=albedo.detach().cpu().tolist(), beta_m=beta_m.item())  # float32's values
    substituted = dataclasses.replace(scene, hair=hair)
    seeds = (5, default_grad_seed(5))
    jacobians = [render_jacobian(substituted, spp=4, seed=s, device="cuda")[0] for s in seeds]
    adjoints = (pair - targets).detach().cpu().numpy().astype(np.float64)
    expected = named_gradients(
        substituted.hair, contract(adjoints[0], jacobians[1]) + contract(adjoints[1], jacobians[0])
    )
    np.testing.assert_allclose(albedo.grad.cpu().numpy(), expected["albedo"], rtol=1e-5)
    np.testing.assert_allclose(beta_m.grad.item(), expected["beta_m"], rtol=1e-5)

    # A prepared scene renders on its own device; the image goes back where the controls are.
    on_gpu = prepare(scene, "cuda")
    on_cpu = render_torch(on_gpu, {"beta_m": torch.tensor(0.25)}, spp=2, seed=1)
    assert on_cpu.device == torch.device("cpu")
    with pytest.raises(ValueError, match=r"prepared on device 'cuda:0', not 'cpu'"):
        render_torch(on_gpu, {}, device="cpu")


@needs_cuda
def test_fit_on_cuda_reads_nothing_back_per_iteration_and_agrees_with_the_cpu(monkeypatch):
    target = load_target(TARGET)
    settings = FitSettings(iters=4, spp=4, refine=0, uncertainty=False, device="cuda")
    run = FitRun(target, settings, progress=False)
    reads = []
    original = wp.array.numpy

    def numpy(self):
        reads.append(self.device)
        return original(self)

    monkeypatch.setattr(wp.array, "numpy", numpy)
    run.step()
    monkeypatch.undo()
    assert not [d for d in reads if d.is_cuda], "an iteration copied a GPU array to the host"
    assert all(t.device.type == "cuda" for t in run.latents.tensors.values())

    # Gradients within RTOL of the CPU's move Adam's normalised steps (lr 0.1 in latent space) by as little:
    # after 4 steps the controls agree to far better than 1e-3.
    gpu = fit(target, settings, progress=False)
    cpu = fit(target, FitSettings(**{**settings.__dict__, "device": "cpu"}), progress=False)
    for name, value in cpu.values.items():
        np.testing.assert_allclose(gpu.values[name], value, rtol=1e-3, err_msg=name)
