"""Check `render_grad` against finite differences of `render` on a scene (behind `warp-hair gradcheck`).

The loss is L(θ) = mean over the image's pixels and channels of 0.5 (image(θ) − target)², where the target is
a render of the same scene with the checked controls moved by a fixed amount (`TARGET_PERTURBATION`: albedo
×0.9, σ_a and melanins ×1.1, β_m and β_n +0.05 and α +3° (5% of their ranges), η +0.05, r_roughness_scale +0.1;
a step that would leave a control's range is taken downward instead), rendered once at `target_spp`
(default 16 × spp) with the scene's seed.

For each of K seed pairs (a, b), with a, b different from each other and from the target's seed:

- gradient: the primal image I_a = render(θ, seed a) gives the adjoint (I_a − target) / n, and
  render_grad(θ, adjoint, seed b) the gradient. The two seeds differ, so the noise of the adjoint and of the
  gradient pass are independent and the product is unbiased for ∂L/∂θ of the expected image.
- finite difference: L is estimated without the Var(image) bias of a squared noisy image by the product of two
  independent renders, L̂ = mean 0.5 (I_a − target)(I_b − target), and differentiated centrally with common
  random numbers (the same seeds a, b at θ + ε and θ − ε): D(ε) = (L̂(θ+ε) − L̂(θ−ε)) / 2ε. The value reported
  is the Richardson extrapolation (4 D(ε/2) − D(ε)) / 3, whose error is O(ε⁴) (plain D is visibly biased for
  the roughnesses, see tests/test_render_grad.py).

Both are averaged over the K seed pairs, with standard errors from their spread; a row is OK when
|gradient − fd| ≤ max(3% of |fd|, 3 standard errors of the difference).

Cost: 1 target render at target_spp, then per seed pair 1 render, 2 gradient passes (each a few renders' cost)
and, per checked component (albedo and σ_a count 3), 8 renders (θ ± ε and θ ± ε/2, seeds a and b), all at spp:
`render_count` = 1 + K (3 + 8 × components) calls. With the defaults (spp 16, K 4, a colour triple + 5 scalar
controls = 8 components) that is 269 calls, about 4,300 spp of rendering per pixel: seconds on a 12×12 scene,
over an hour on a 256×256 swatch. For quick checks lower the scene's resolution and check fewer controls
(--params).

At low spp the differences are much noisier than the gradient (a change of θ flips discrete choices of the paths,
lobe and fiber, with a variance ∝ 1/ε), so "OK" there may only mean "within a wide 3 SE": read the ± columns. More
samples and seeds (--spp 128 --seeds 8 on a small scene) resolve the gradient to about 10%.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .controls import CONTROLS
from .renderer.gradients import render_grad
from .renderer.prepare import prepare
from .renderer.render import render
from .scene import Scene
from .validate import SEED_LIMIT

# The target's controls: (kind, amount) per control; "scale" multiplies, "add" adds (the table's gradcheck_move).
TARGET_PERTURBATION = {name: control.gradcheck_move for name, control in CONTROLS.items()}

# Central-difference steps ε (the difference is extrapolated from ε and ε/2; the table's gradcheck_step): large
# enough that the 1/ε variance of the discrete choices a change of θ flips (which lobe, which fiber) stays small;
# as tests/test_render_grad.py.
DEFAULT_STEPS = {name: control.gradcheck_step for name, control in CONTROLS.items()}

CHANNELS = "rgb"
RELATIVE_TOLERANCE = 0.03
SE_TOLERANCE = 3.0
# Seeds of the (a, b) pairs start here, above the scene's seed, so that none is the target's.
SEED_OFFSET = 1000


@dataclass(frozen=True)
class GradcheckRow:
    """One control component: `control` is its label ("albedo[r]", "eta")."""

    control: str
    name: str
    component: int | None
    step: float
    grad: float
    grad_se: float
    fd: float
    fd_se: float
    se: float  # standard error of grad − fd, from the spread of its per-seed-pair values (paired)

    @property
    def difference(self) -> float:
        return self.grad - self.fd

    @property
    def relative_difference(self) -> float:
        return abs(self.difference) / abs(self.fd) if self.fd != 0.0 else math.inf

    @property
    def z(self) -> float:
        """|grad − fd| in standard errors of the difference."""
        return abs(self.difference) / self.se if self.se > 0.0 else math.inf

    @property
    def ok(self) -> bool:
        return abs(self.difference) <= max(RELATIVE_TOLERANCE * abs(self.fd), SE_TOLERANCE * self.se)


def scene_controls(scene: Scene) -> list[str]:
    """The names of the controls this scene's hair has (colour under its input's name), in order."""
    return list(scene.hair.to_dict())


def parse_controls(scene: Scene, names) -> list[str]:
    """Validate a list of control names against the scene; None means all of them."""
    available = scene_controls(scene)
    if names is None:
        return available
    names = [n.strip() for n in names if n.strip()]
    unknown = [n for n in names if n not in available]
    if unknown:
        raise ValueError(f"unknown control(s) {unknown} for --params; this scene's controls are {available}")
    if not names:
        raise ValueError(f"--params names no control; this scene's controls are {available}")
    return list(dict.fromkeys(names))


def target_hair(hair, names):
    """The target's controls: each of `names` moved by TARGET_PERTURBATION (downward where upward leaves its
    range)."""
    changes = {}
    values = hair.to_dict()
    for name in names:
        kind, amount = TARGET_PERTURBATION[name]
        value = np.asarray(values[name], dtype=np.float64)
        if kind == "scale":
            moved = value * amount
        else:
            moved = value + amount
            if not _valid(hair, name, moved):
                moved = value - amount
        changes[name] = moved.tolist() if moved.ndim else float(moved)
    return hair.replace(**changes)


def _valid(hair, name, value) -> bool:
    try:
        hair.replace(**{name: value.tolist() if np.ndim(value) else float(value)})
    except ValueError:
        return False
    return True


def _components(hair, names):
    """(label, name, component) per scalar to check."""
    values = hair.to_dict()
    out = []
    for name in names:
        if np.ndim(values[name]) == 0:
            out.append((name, name, None))
        else:
            out.extend((f"{name}[{CHANNELS[c]}]", name, c) for c in range(len(values[name])))
    return out


def _shifted(hair, name, component, delta, step):
    value = np.array(hair.to_dict()[name], dtype=np.float64)
    if component is None:
        value = float(value + delta)
    else:
        value[component] += delta
        value = value.tolist()
    try:
        return hair.replace(**{name: value})
    except ValueError as error:
        raise ValueError(
            f"the finite-difference step {step:g} for {name} leaves its range at this scene's value ({error}); "
            "use a smaller --eps"
        ) from None


def _mean_and_se(samples):
    samples = np.asarray(samples, dtype=np.float64)
    se = samples.std(ddof=1) / math.sqrt(len(samples)) if len(samples) > 1 else math.nan
    return float(samples.mean()), float(se)


def render_count(n_components: int, seeds: int) -> int:
    """Render calls gradcheck makes (gradient passes counted as one each): target + per seed pair (primal +
    2 gradient passes + 8 per component)."""
    return 1 + seeds * (3 + 8 * n_components)


def gradcheck(
    scene: Scene,
    names=None,
    spp: int = 16,
    seeds: int = 4,
    eps: float | None = None,
    target_spp: int | None = None,
    threads: int | None = None,
    progress=None,
) -> list[GradcheckRow]:
    """Compare render_grad with Richardson-extrapolated central differences of the loss (module docstring).

    names: controls to check (default: all of the scene's); eps: one finite-difference step for all of them
    (default: DEFAULT_STEPS per control); progress(done, total) is called after each render.
    """
    spp, seeds = int(spp), int(seeds)
    if spp < 1:
        raise ValueError(f"spp must be at least 1, got {spp}")
    if seeds < 2:
        raise ValueError(f"seeds must be at least 2 (standard errors come from their spread), got {seeds}")
    if eps is not None and not (math.isfinite(eps) and eps > 0.0):
        raise ValueError(f"eps must be a positive number, got {eps}")
    target_spp = 16 * spp if target_spp is None else int(target_spp)
    if target_spp < 1:
        raise ValueError(f"target_spp must be at least 1, got {target_spp}")
    names = parse_controls(scene, names)
    hair = scene.hair
    # Every render of the check shows the same fibers: one BVH, each render with its own hair.
    prepared = prepare(scene)
    components = _components(hair, names)
    steps = {name: (DEFAULT_STEPS[name] if eps is None else float(eps)) for name in names}
    # Scenes for θ ± ε and θ ± ε/2, built (and range-checked) before any rendering.
    shifted = {
        (label, sign, scale): prepared.with_hair(_shifted(hair, name, c, sign * scale * steps[name], steps[name]))
        for label, name, c in components
        for sign in (1.0, -1.0)
        for scale in (1.0, 0.5)
    }

    total = render_count(len(components), seeds)
    done = 0

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    target = render(
        prepared.with_hair(target_hair(hair, names)), spp=target_spp, seed=scene.render.seed, threads=threads
    ).astype(np.float64)
    tick()
    n = target.size

    def loss(s, seed_a, seed_b):
        residual_a = render(s, spp=spp, seed=seed_a, threads=threads).astype(np.float64) - target
        tick()
        residual_b = render(s, spp=spp, seed=seed_b, threads=threads).astype(np.float64) - target
        tick()
        return 0.5 * float((residual_a * residual_b).sum()) / n

    grads = {label: [] for label, _, _ in components}
    fds = {label: [] for label, _, _ in components}
    base = scene.render.seed + SEED_OFFSET
    for k in range(seeds):
        # Wrapped into the uint32 the random streams are seeded with (a scene seed near 2**32 would pass it).
        seed_a, seed_b = (base + 2 * k) % SEED_LIMIT, (base + 2 * k + 1) % SEED_LIMIT
        # Symmetrized like the product L̂: 0.5 (grad with adjoint from I_a over paths b + the same with a, b
        # swapped). Then gradient and difference estimate the same quantity path by path, and their paired
        # difference per seed pair has a far smaller spread than either.
        image_a = render(prepared, spp=spp, seed=seed_a, threads=threads).astype(np.float64)
        tick()
        g_ab, image_b = render_grad(
            prepared, (image_a - target) / n, spp=spp, seed=seed_b, threads=threads, return_image=True
        )
        tick()
        g_ba = render_grad(prepared, (image_b.astype(np.float64) - target) / n, spp=spp, seed=seed_a, threads=threads)
        tick()
        for label, name, c in components:
            pick = (
                (lambda g, name=name: float(g[name]))
                if c is None
                else (lambda g, name=name, c=c: float(np.asarray(g[name])[c]))
            )
            grads[label].append(0.5 * (pick(g_ab) + pick(g_ba)))
            d = {}
            for scale in (1.0, 0.5):
                up = loss(shifted[(label, 1.0, scale)], seed_a, seed_b)
                down = loss(shifted[(label, -1.0, scale)], seed_a, seed_b)
                d[scale] = (up - down) / (2.0 * scale * steps[name])
            fds[label].append((4.0 * d[0.5] - d[1.0]) / 3.0)

    rows = []
    for label, name, c in components:
        g_mean, g_se = _mean_and_se(grads[label])
        fd_mean, fd_se = _mean_and_se(fds[label])
        _, diff_se = _mean_and_se(np.subtract(grads[label], fds[label]))
        rows.append(GradcheckRow(label, name, c, steps[name], g_mean, g_se, fd_mean, fd_se, diff_se))
    return rows


def format_table(rows: list[GradcheckRow]) -> str:
    """The rows as a fixed-width text table."""
    header = ("control", "step", "render_grad", "finite diff", "rel diff", "diff/SE", "verdict")
    lines = [header]
    for r in rows:
        lines.append(
            (
                r.control,
                f"{r.step:g}",
                f"{r.grad:+.4e} ± {r.grad_se:.1e}",
                f"{r.fd:+.4e} ± {r.fd_se:.1e}",
                f"{100 * r.relative_difference:.1f}%",
                f"{r.z:.2f}",
                "OK" if r.ok else "MISMATCH",
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    out = []
    for i, line in enumerate(lines):
        out.append(
            "  ".join(
                cell.ljust(w) if j == 0 else cell.rjust(w) for j, (cell, w) in enumerate(zip(line, widths))
            ).rstrip()
        )
        if i == 0:
            out.append("  ".join("-" * w for w in widths))
    return "\n".join(out)
