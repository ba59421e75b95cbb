"""Fitting a target whose fibers are known by their recipe only: random realisations of the strands.

A target's scenes describe its fibers. Where they are the very strands the target's images show (our own
renders, the shipped Cycles targets), the fit renders them (`realisations = "fixed"`, the default). A
photographed swatch's strands were never modelled: its scenes can only give the recipe (a generator and its
parameters), and the scene's seed picks one set of strands that is not the photographed one. target.toml's

    realisations = "random"

then fits the look averaged over the recipe's realisations (`warp_hair.realisation`: other seeds, and the
swatch's lattice shifted across it), and the uncertainty counts the photographed strands' being one draw.

Why fitting one wrong realisation biases β_n. With the fit's fibers f and the target's t independent draws, the
L2 loss ‖I_f(x) − T_t‖² averages over them to ‖Ī(x) − T̄‖² + Σ Var_f[I_f(x)] + const, Ī the image averaged over
realisations: the fit also minimises how much its own strands' image varies between realisations, per pooled
block, which is the contrast between fiber and gap, highlight and shadow. A rougher azimuthal lobe (β_n) smooths
that contrast, so the estimate is pulled up in β_n (issue 23 measured +0.02 to +0.06 on Cycles swatches).

The estimator. Each gradient of the fit comes from two renders whose losses are crossed (`render_torch_pair`:
each render's adjoint meets the other's Jacobian). Here the two renders also use two different realisations
a ≠ b, drawn afresh for every iteration and every Gauss–Newton linearisation from a pool of POOL realisations
(1…POOL; 0, the scene's own, is left out). With a, b independent,

    E[(I_a(x) − T) · ∂I_b(x)] = (Ī(x) − T) · ∂Ī(x),

the gradient of ½‖Ī(x) − T‖², with no variance term: the fit minimises the distance of the realisation-averaged
image to the target. (Over a finite pool, the mean over its pairs a ≠ b is the U-statistic
‖Ī_P − T‖² − Σ_a ‖I_a − Ī_P‖² / (P(P − 1)), whose expectation over pools is ‖Ī − T‖² exactly.) The target is
one realisation t: T = Ī(x*) + e_t, E[e_t] = 0, so to first order the estimate is x* + H⁻¹ Āᵀ W e_t,
unbiased, with spread H⁻¹ Āᵀ W Cov(e_t) W Ā H⁻¹: the realisation term of the uncertainty. What is left of a
bias is second order, of the size of that spread squared times the model's curvature in x, and the pool's
own draw adds a spread of about 1/√POOL of the realisation term's, both in the benchmark's figures
(benchmarks/realisation_acceptance.py, docs/acceptance.md).

The realisation term of σ (`realisation_term`). At the fitted controls x̂, K further realisations
(POOL + 1 … POOL + K) are each linearised with both passes on the same strands. Were the target realisation k,
the estimate would move by u_k = H⁻¹ Aᵀ W r_k, r_k that realisation's weighted residuals (A and H the fit's,
with these K linearisations' Jacobians pooled in: `pooled_jacobians` says why; restricted to the directions they
determine, uncertainty.py `pinned`); their covariance over k is the
realisation term. Each u_k is formed
from both passes, and the covariance is taken across passes (Σ (u_k¹ − ū¹)(u_k² − ū²)ᵀ / (K − 1)), so that
our render noise, independent between the passes, drops out of it in expectation. The same cross-pass
covariance per residual, v, is how much a realisation's image varies: the target differs from any realisation
we render by about 2v, which the noise term's scatter s² would otherwise count as the target's noise
(uncertainty.py), so it is taken out of s² there.

With a prior over how the strands lie (target.toml [arrangement], arrangement.py), every realisation here also
draws those recipe parameters from it: Ī above is then the image averaged over the prior too, and the realisation
term counts the arrangement's spread with the seed's.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from warp_hair.geometry.interpenetration import InterpenetrationWarning
from warp_hair.realisation import check_realisable, realisation_views
from warp_hair.renderer.prepare import prepare_views

from .arrangement import fiber_seed
from .linearize import inverse_curvature
from .uncertainty import pinned

REALISATION_MODES = ("fixed", "random")
# Realisations the fit draws its pairs from. Each costs a generator run, the strands' check and a BVH, once for all
# the target's views (`realisation_views`): 40–90 ms for the Cycles swatches' 152 strands (docs/benchmarks.md,
# issue 45); the pool's own draw adds ~1/√POOL of the realisation term.
POOL = 16
DEFAULT_SAMPLES = 8  # K: realisations rendered at the fitted look for the realisation term


def check_mode(mode, where: str = "realisations") -> str:
    if mode not in REALISATION_MODES:
        raise ValueError(f"{where} = {mode!r}; allowed: {list(REALISATION_MODES)}")
    return mode


class Realisations:
    """Prepared scenes of the target's other realisations, built when first drawn and kept."""

    def __init__(self, target, pool: int = POOL, device: str = "cpu"):
        for image in target.images:
            check_realisable(image.scene, f'{target.name}: realisations = "random", {image.scene.path or image.name}')
        self.target, self.pool, self.device = target, pool, device
        self._prepared = {}
        self._warned = False

    def scenes(self, index: int) -> list:
        """Realisation `index` of every image's scene, prepared (the images show the same strands)."""
        if index not in self._prepared:
            self._prepared[index] = prepare_views(self.views(index, self.drawn(index)), self.device)
        return self._prepared[index]

    def views(self, index: int, recipe: dict | None) -> list:
        """`realisation_views` of the target's scenes, whose strands' passing through each other is said once for
        all of the fit's realisations (the first that does; it is the recipe's, not one set of strands', and a
        fit draws dozens), where each new assembly would say it again."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            views = realisation_views([image.scene for image in self.target.images], index, recipe)
        for warning in caught:
            if issubclass(warning.category, InterpenetrationWarning):
                if self._warned:
                    continue
                self._warned = True
                message = f"{warning.message} (in realisation {index} of the recipe; later ones are not reported)"
                warnings.warn(message, InterpenetrationWarning, stacklevel=2)
            else:
                warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
        return views

    def drawn(self, index: int) -> dict | None:
        """How realisation `index`'s strands lie, drawn from the target's [arrangement] prior (arrangement.py); None
        without one. One draw for all images: they show the same strands (their scenes' [fibers] agree: target.py)."""
        prior = getattr(self.target, "arrangement", None)
        return None if prior is None else prior.draw(fiber_seed(self.target.images[0].scene), index)

    def term_drawn(self, k: int) -> dict | None:
        """`drawn` for the k-th realisation of the realisation term (`term_scenes`)."""
        return self.drawn(self.pool + 1 + k)

    def term_scenes(self, k: int) -> list:
        """The k-th realisation (k = 0, 1, …) the realisation term renders: after the pool's, so never one the fit
        drew its pairs from."""
        return self.scenes(self.pool + 1 + k)

    def pair(self, seed: int) -> list:
        """Per image, a pair of scenes of two different realisations drawn from the pool with `seed`."""
        a, b = np.random.default_rng(seed).choice(np.arange(1, self.pool + 1), 2, replace=False)
        return list(zip(self.scenes(int(a)), self.scenes(int(b))))


@dataclasses.dataclass(frozen=True)
class RealisationTerm:
    covariance: np.ndarray  # (p, p): the estimate's spread over the target's possible realisations
    scatter: float  # s² of a same-realisation linearisation with the realisations' own variance taken out
    linearization: object  # that linearisation (both passes on one realisation): for the noise term
    samples: int
    pooled: object  # the fit's linearisation with the K linearisations' Jacobians pooled in (`pooled_jacobians`)
    variance: np.ndarray | None = None  # (N,) one realisation's variance per residual (goodness.py's σ²_draw)
    arrangement: np.ndarray | None = None  # (p, p) the part of `covariance` how the strands lie makes (M Σ Mᵀ)
    unpinned: object = None  # the directions the pooled Jacobians do not determine (uncertainty.py `pinned`), or None
    camera: np.ndarray | None = None  # (q, q) a photo's log-gains' spread over the realisations (`camera_spread`)


def pooled_jacobians(lin, linearizations):
    """`lin` (the fit's linearisation at its estimate) with the Jacobians of `linearizations` (made at the same
    controls, each on a realisation of its own) pooled into its Jacobian and curvature.

    Why: a light hair's albedo changes its image little, and its column of the curvature comes from Jacobians
    whose noise is of the size of their mean. From the refinement's last eight linearisations alone it varied
    40-fold between fits of one target at nearly the same estimate (red albedo of cycles_blonde_straight, 4.7e-4
    to 2.0e-2), and every term of σ scales with its inverse. The realisation term's K linearisations at the
    estimate bring 2K more Jacobians for nothing (`targets check`, identify.py, pools them as well). Their
    residuals also make the realisation term, which is then no longer independent of its gain; that bias is of
    order 2/(number of Jacobians), a few percent."""
    earlier = [] if lin.earlier_jacobians is None else [lin.earlier_jacobians]
    jacobians = np.concatenate(earlier + [other.jacobians for other in linearizations])
    return dataclasses.replace(lin, earlier_jacobians=jacobians, curvature=None)


def estimate_gain(lin) -> np.ndarray:
    """H⁻¹ Aᵀ W (p, N): how far the estimate moves per unit of each weighted residual, linearised at `lin`."""
    return inverse_curvature(lin.curvature) @ (lin.mean_jacobian * lin.loss_weights[:, None]).T


def realisation_term(lin, linearizations, arrangement=None) -> RealisationTerm:
    """The realisation covariance from K ≥ 2 linearisations at the fitted controls, each with both passes on one
    further realisation (see the module docstring); `lin` gives the Jacobian and curvature, with the K
    linearisations' Jacobians pooled in. `arrangement`: where the realisations also draw how the strands lie,
    (their draws (K, q), the arrangement's columns (N, q), the prior's covariance (q, q)) for
    `realisation_spread`'s control variate."""
    pooled, unpinned = pinned(pooled_jacobians(lin, linearizations))
    w = pooled.loss_weights
    gain = estimate_gain(pooled)
    covariance, variance, part = realisation_spread(gain, linearizations, arrangement)
    first = linearizations[0]
    hair = first.hair_rows  # as scatter_estimate counts them (a grey card's rows left out)
    n, p = len(w[hair]), first.jacobians.shape[2]
    scatter = first.scatter_estimate - 2.0 * float(w[hair] @ variance[hair]) / max(n - p, 1)
    return RealisationTerm(
        covariance,
        scatter,
        dataclasses.replace(first, scatter=scatter),
        len(linearizations),
        pooled,
        variance,
        part,
        unpinned,
        camera_spread(lin.camera, gain, linearizations),
    )


def camera_spread(projection, gain: np.ndarray, linearizations) -> np.ndarray | None:
    """(q, q): the cross-pass covariance over the K realisations of how far a photo's log-gains would move on each,
    or None without gains. On realisation k a pass's residuals r move the gains directly by their part along the
    gains' columns, c = (CᵀWC)⁻¹CᵀW r (`Linearization.camera_moves`: a realisation that renders brighter moves the
    gains, not the hair), and through the hair's move u = gain · P⊥r (as `realisation_spread`) by `follow` · u; the
    gains take −(c + follow · u). The hair's covariance carried into the gains (camera.Projection.covariance) leaves
    this out, and a grey card outweighed by hair rows that a realisation moves together does not hold it."""
    if projection is None or any(other.camera_moves is None for other in linearizations):
        return None
    _, u = _estimate_moves(gain, linearizations)
    moves = np.stack([other.camera_moves for other in linearizations])  # (K, 2, q)
    return _crossed_covariance(moves - moves.mean(axis=0) + np.einsum("qp,khp->khq", projection.follow, u))


def realisation_spread(gain: np.ndarray, linearizations, arrangement=None) -> tuple:
    """(the cross-pass covariance (p, p) of u_k = gain · r_k over K ≥ 2 linearisations, each with both passes on
    one realisation k (positive semi-definite); the cross-pass variance (N,) of each residual over them; the
    arrangement's part of the covariance, or None). `gain` (p, N) maps weighted residuals to the estimate's
    move, H⁻¹ Aᵀ W (the fit's, or `targets check`'s).

    `arrangement` = (draws (K, q), columns (N, q), prior covariance Σ (q, q)): each realisation k also drew how
    the strands lie, ψ_k, from a stated prior (arrangement.py), and `columns` are ∂r/∂ψ. From K = 8 draws the
    part of the spread that ψ makes is as noisy as any 8-sample variance (its relative error about √(2/7), half),
    yet that part is known to first order: M (ψ_k − ψ̄), M = gain · columns, whose covariance over the prior is
    M Σ Mᵀ exactly. So it is taken out of each u_k and counted exactly instead (a control variate): the
    covariance is that of the rest (the seed's part, and what is not linear in ψ) plus M Σ Mᵀ, which is the
    third value."""
    k = len(linearizations)
    if k < 2:
        raise ValueError(f"the realisation term needs at least 2 realisations, got {k}")
    deviations, u = _estimate_moves(gain, linearizations)
    part = None
    if arrangement is not None:
        draws, columns, prior = arrangement
        moved = gain @ columns  # (p, q): the estimate's move per unit of each key
        u = u - ((draws - draws.mean(axis=0)) @ moved.T)[:, None, :]
        part = moved @ prior @ moved.T
    variance = (deviations[:, 0] * deviations[:, 1]).sum(axis=0) / (k - 1)
    covariance = _crossed_covariance(u)
    return (covariance if part is None else covariance + part), variance, part


def _estimate_moves(gain: np.ndarray, linearizations) -> tuple:
    """(each realisation's pass's residuals less their mean over the realisations (K, 2, N), and the estimate's move
    they make, gain · that (K, 2, p))."""
    residuals = np.stack([other.residuals for other in linearizations])
    deviations = residuals - residuals.mean(axis=0)
    return deviations, np.einsum("pn,khn->khp", gain, deviations)


def _crossed_covariance(moves: np.ndarray) -> np.ndarray:
    """The covariance over K realisations of a move seen in both of each one's passes (K, 2, ·), crossed between the
    passes so that their independent render noise drops out: symmetric, positive semi-definite."""
    crossed = np.einsum("ki,kj->ij", moves[:, 0], moves[:, 1]) / (len(moves) - 1)
    return _nearest_psd(0.5 * (crossed + crossed.T))


def _nearest_psd(matrix: np.ndarray) -> np.ndarray:
    """The cross-pass covariance is unbiased but not always positive semi-definite when the realisations hardly
    change the estimate; its negative directions are noise, and are dropped."""
    values, vectors = np.linalg.eigh(matrix)
    return (vectors * np.maximum(values, 0.0)) @ vectors.T
