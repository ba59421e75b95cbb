"""Rendering on a GPU: the device option's plumbing and its error on every machine, the kernels compiled for a
CUDA architecture wherever Warp has NVRTC, and on a machine with a CUDA device the render, its Jacobian, the
torch front and a fit there agreeing with the CPU's."""

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch
import warp as wp
from helpers.scenes import swatch_scene

from optimize.cli import main as fit_main
from optimize.fit import FitRun, FitSettings, fit
from optimize.settings import BOUNDS
from optimize.target import load_target
from warp_hair.cli import main
from warp_hair.devices import check_device
from warp_hair.geometry.bvh import MAX_DEPTH, build_bvh, leaf_range
from warp_hair.geometry.intersect import BVH_WIDTH
from warp_hair.geometry.tubes import MAX_LEAF, segment_boxes, segment_frames
from warp_hair.renderer.gradients import contract, named_gradients, render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import pixel_jacobian_kernel, pixel_kernel, render
from warp_hair.scene import scene_from_dict
from warp_hair.torch import default_grad_seed, render_device, render_torch, render_torch_pair

HAS_CUDA = wp.get_cuda_device_count() > 0
needs_cuda = pytest.mark.skipif(not HAS_CUDA, reason="no CUDA device on this machine (Warp finds none)")
without_cuda = pytest.mark.skipif(HAS_CUDA, reason="tests the error on a machine without a CUDA device")
TARGETS = Path(__file__).parents[1] / "targets"
TARGET = TARGETS / "blonde_straight"
APART_TARGET = TARGETS / "cycles_blonde_straight"  # a draped swatch whose strands do not touch
DARK_TARGET = TARGETS / "black_straight"  # the Quick start's
LIGHTS = [
    {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
    {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
]
HAIR = {"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.35}

# How far a GPU render may be from the CPU's. The kernel and the random streams are the same, so each path is
# the CPU's path up to rounding: NVRTC contracts a·b + c into FMAs where clang (-march=native) contracts other
# sums, and CUDA's sqrt, exp, log and trigonometric functions (no fast math: within 2 ulp) are not libm's. A path
# that takes the same branches on both stays within float32's rounding: on an H200, over 2048 one-path pixels,
# the median difference was 4e-9 and the largest 4e-6 of the image's largest value, so RTOL leaves 25 times that.
# A rounding difference that decides a branch (a ray grazing a tube's edge, where the hit is the sign of a
# difference of nearly equal numbers) sends a path elsewhere, as an independent sample of the same pixel; the
# more tubes a path passes, the more such decisions. Measured there: 0 of 2048 paths on one sparse layer, 15 of
# 2048 (0.73%) on the dense 4-layer swatch, about 0.55% on a draped 4-layer one (11 of 256 pixels at 8 spp).
# DIVERGED_PATHS allows 2%, while a fault that changes the path itself (another random stream, a traversal that
# misses) moves nearly all of them.
RTOL = 1e-4
DIVERGED_PATHS = 0.02


def small_scene():
    """The dense swatch: 160 strands in 4 layers (none interpenetrate)."""
    return swatch_scene(HAIR, LIGHTS, resolution=(16, 16), render_table={"spp": 8, "max_depth": 8, "seed": 1})


def apart_scene():
    """APART_TARGET's back-lit scene at 16×16 and 8 spp: 4 layers of strands that do not touch."""
    data = tomllib.loads((APART_TARGET / "scene_back.toml").read_text())
    data["camera"]["resolution"] = [16, 16]
    data["render"] = {"spp": 8, "max_depth": 8, "seed": 1}
    return scene_from_dict(data)


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


def assert_same_render(gpu, cpu, what, spp):
    """Pixels within RTOL of the largest value (sums of signed Jacobian terms cancel), but for those of which one
    of the spp paths went elsewhere (1 - (1 - DIVERGED_PATHS)^spp of them at most); and those pixels' differences
    unbiased: their sum within 4 standard deviations of zero, as independent samples of the same pixel give.
    """
    assert np.isfinite(gpu).all(), what
    close = np.isclose(gpu, cpu, rtol=RTOL, atol=RTOL * np.abs(cpu).max()).all(axis=-1)
    allowed = 1 - (1 - DIVERGED_PATHS) ** spp
    assert close.mean() >= 1 - allowed, f"{what}: {np.count_nonzero(~close)} of {close.size} pixels differ"
    elsewhere = (gpu.astype(np.float64) - cpu)[~close]
    assert abs(elsewhere.sum()) <= 4 * np.sqrt((elsewhere**2).sum()), f"{what}: paths elsewhere biased"


@needs_cuda
def test_bvh_built_on_cuda_is_a_valid_tree():
    """The build's kernels on the GPU (`build_bvh(device="cuda")`, which gpu.py times; scenes build on the host):
    every primitive in exactly one leaf, inside each box on its way from the root, the depth within MAX_DEPTH; for
    a swatch's tubes and for boxes whose centres coincide (split at the median, the NumPy step, on copies of the
    GPU's arrays). Its tree need not be the CPU's: fused multiply-adds may break an SAH near-tie otherwise."""
    p0, p1, r0, r1, strand, _ = small_scene().fibers.segments()
    lowers, uppers = segment_boxes(segment_frames(p0, p1, r0, r1, strand))
    same = np.repeat(np.random.default_rng(3).uniform(-1.0, 1.0, (1, 3)), 64, axis=0)
    for lo, hi in ((lowers, uppers), (np.concatenate([lowers, same]), np.concatenate([uppers, same + 0.01]))):
        tree = build_bvh(lo, hi, max_leaf=MAX_LEAF, width=BVH_WIDTH, device="cuda")
        np.testing.assert_array_equal(np.sort(tree.order), np.arange(len(lo)))
        assert tree.depth <= -(-MAX_DEPTH // 3)
        seen = np.zeros(len(lo), dtype=int)
        stack = [(0, np.full(3, -np.inf), np.full(3, np.inf))]  # a node and the boxes above it, intersected
        while stack:
            node, box_lo, box_hi = stack.pop()
            for c in range(tree.width):
                child_lo = np.maximum(box_lo, tree.lo[node, c])
                child_hi = np.minimum(box_hi, tree.hi[node, c])
                if tree.child[node, c] >= 0:
                    stack.append((tree.child[node, c], child_lo, child_hi))
                    continue
                first, count = leaf_range(tree.child[node, c])
                prims = tree.order[first : first + count]
                seen[prims] += 1
                assert (lo[prims] >= child_lo).all() and (hi[prims] <= child_hi).all()
        np.testing.assert_array_equal(seen, 1)


@needs_cuda
def test_render_on_cuda_is_the_cpu_render():
    scene = apart_scene()
    cpu, cpu_err = render(scene, device="cpu", return_stderr=True)
    gpu, gpu_err = render(prepare(scene, "cuda"), return_stderr=True)
    assert gpu.dtype == np.float32 and gpu.shape == cpu.shape
    assert_same_render(gpu, cpu, "image", spp=8)
    assert_same_render(gpu_err, cpu_err, "standard error", spp=8)
    assert np.abs(cpu).max() > 0
    # A subset of pixels renders as they come out in the whole image there too.
    pixels = np.array([0, 17, 100, 255])
    part = render(scene, device="cuda", pixels=pixels).reshape(-1, 3)
    np.testing.assert_array_equal(part[pixels], gpu.reshape(-1, 3)[pixels])


@needs_cuda
@pytest.mark.parametrize("make_scene", [apart_scene, small_scene], ids=["draped", "dense"])
def test_all_but_a_few_paths_are_the_cpu_s(make_scene):
    """One path a pixel (spp 1, eight seeds: 2048 paths): all but DIVERGED_PATHS of them the CPU's to RTOL."""
    scene = make_scene()
    gpu = np.array([render(scene, spp=1, seed=s, device="cuda") for s in range(1, 9)])
    cpu = np.array([render(scene, spp=1, seed=s, device="cpu") for s in range(1, 9)])
    assert np.abs(cpu).max() > 0
    assert_same_render(gpu, cpu, "one-path images", spp=1)


@needs_cuda
def test_jacobian_on_cuda_is_the_cpu_jacobian():
    scene = apart_scene()
    cpu, cpu_image, _ = render_jacobian(scene, spp=4, seed=2, device="cpu")
    gpu, gpu_image, _ = render_jacobian(scene, spp=4, seed=2, device="cuda")
    assert_same_render(gpu_image, cpu_image, "image", spp=4)
    for k in range(cpu.shape[-1]):
        assert_same_render(gpu[..., k], cpu[..., k], f"Jacobian column {k}", spp=4)


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
def test_fit_on_cuda_reads_nothing_back_per_iteration_and_recovers_the_truth(monkeypatch):
    target = load_target(DARK_TARGET)
    run = FitRun(target, FitSettings(iters=4, spp=4, refine=0, uncertainty=False, device="cuda"), progress=False)
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

    # The whole fit there, with its defaults. Not the CPU's trajectory: Adam's first steps are the signs of the
    # gradients, which the few paths that go elsewhere can flip where a control is weakly constrained.
    result = fit(target, device="cuda", progress=False)
    truth = target.truth.to_dict()
    for name, bound in BOUNDS.items():
        error = np.abs(np.asarray(result.values[name]) - truth[name])
        assert (error <= bound).all(), f"{name}: {result.values[name]} against the truth {truth[name]}"
