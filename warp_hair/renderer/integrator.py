"""Unidirectional path tracing of fiber assemblies, with next-event estimation and multiple importance sampling.

At every fiber vertex the near-field BSDF is evaluated at the true offset h of the hit: the integral over h is
left to the path tracer rather than folded into a far-field lobe. Lights: directional lights (deltas, reached by
light sampling only), one environment (constant or an importance-sampled lat-long map; light and BSDF sampling
combined by the power heuristic) and an optional diffuse backing card. Russian roulette after `rr_depth`
bounces keeps long paths in light hair unbiased without paying for all of them.

The tracer is built as pbrt-v4 factors its path integrator: `trace_path` (pbrt's `Li`) walks the path, and
`sample_ld` does next-event estimation over every kind of light; `make_trace_path(True)` compiles the gradient
of the same walk in under `wp.static` branches (docs/gradients.md).
"""

import warp as wp

from ..geometry.card import CardData, card_distance
from ..geometry.intersect import FiberGeometry, FiberHit, fibers_occluded, intersect_fibers, shading_frame
from ..model.hair_bsdf import HairCoefficients, LobeSetup, hair_sample, hair_value_pdf, lobe_setup
from ..model.jacobian import (
    CoefficientDerivatives,
    LobeEvaluation,
    LobeSetupGrad,
    hair_value_jacobian,
    hair_value_pdf_lobes,
    lobe_setup_grad,
    value_jacobian_mat,
)
from ..numerics import (
    FLOAT32_MIN_NORMAL,
    INV_PI,
    NO_HIT,
    TWO_PI,
    perpendicular,
    power_heuristic,
    rand2,
    to_local,
    to_world,
)
from .camera import CameraData
from .envmap import EnvironmentData, env_pdf, env_radiance, env_sample

# Forward only (the gradient tracer carries its derivatives forward itself, see `make_trace_path`); -O3 for the
# renderer's hot loop.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})


@wp.struct
class DirectionalLightData:
    to_light: wp.vec3  # unit, opposite to the direction the light travels
    irradiance: wp.vec3  # on a surface facing the light


@wp.struct
class SceneData:
    camera: CameraData
    fibers: FiberGeometry
    hair: HairCoefficients
    lights: wp.array(dtype=DirectionalLightData)
    num_lights: int
    env: EnvironmentData
    has_env: int
    card: CardData
    max_depth: int
    rr_depth: int


@wp.func
def occluded(scene: SceneData, origin: wp.vec3, direction: wp.vec3):
    """Whether a shadow ray toward a light at infinity is blocked (by a fiber or by the card)."""
    if card_distance(scene.card, origin, direction) < NO_HIT:
        return True
    return fibers_occluded(scene.fibers, origin, direction, NO_HIT)


@wp.func
def light_visible(scene: SceneData, on_card: bool, position: wp.vec3, to_light: wp.vec3, w_light: wp.vec3):
    """Whether a light sample (world direction to_light, local w_light) is unoccluded. Below the card's surface
    its S is 0: no shadow ray is traced for those."""
    if on_card and w_light[2] <= 0.0:
        return False
    return not occluded(scene, position, to_light)


@wp.func
def cosine_hemisphere(u: wp.vec2):
    """A cosine-distributed direction about +z (Malley: project a uniform disk sample up)."""
    r = wp.sqrt(u[0])
    phi = TWO_PI * u[1]
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u[0])))


@wp.func
def scatter_value_pdf(scene: SceneData, on_card: bool, setup: LobeSetup, wi: wp.vec3):
    """(cosine-weighted value, solid-angle pdf) of the vertex's BSDF toward local direction wi."""
    if on_card:
        if wi[2] <= 0.0:
            return wp.vec3(0.0), 0.0
        return wi[2] * INV_PI * scene.card.albedo, wi[2] * INV_PI
    return hair_value_pdf(setup, wi)


@wp.func
def scaled_rows(w: wp.vec3, G: value_jacobian_mat):
    """G with row c multiplied by w_c."""
    R = value_jacobian_mat()
    for c in range(3):
        R[c] = G[c] * w[c]
    return R


@wp.func
def add_log_derivative(G: value_jacobian_mat, J: value_jacobian_mat, value: wp.vec3):
    """G with J[c] / S_c added to each row c: ∂ log S_c/∂θ. Nothing where S_c = 0: every later contribution of the
    path is 0 in channel c. One reciprocal per row, but a subnormal S_c, whose reciprocal overflows (and would
    turn J's zeros into NaN), is divided into J directly."""
    for c in range(3):
        if value[c] >= FLOAT32_MIN_NORMAL:
            G[c] = G[c] + J[c] * (1.0 / value[c])
        elif value[c] > 0.0:
            G[c] = G[c] + J[c] / value[c]
    return G


@wp.func
def log_weights(contribution: wp.vec3, value: wp.vec3):
    """C_c / S_c (0 where S_c = 0): times row c of ∂S/∂θ, C_c ∂ log S_c/∂θ."""
    w = wp.vec3(0.0)
    for c in range(3):
        if value[c] > 0.0:
            w[c] = contribution[c] / value[c]
    return w


def _named(f, name: str):
    """f as a `wp.func` under its own name: the forward and gradient variants of one factory are two functions
    with one signature, which Warp would otherwise take for overloads of one."""
    f.__name__ = f.__qualname__ = name
    return wp.func(f)


@wp.func
def shading_point(scene: SceneData, hit: FiberHit, t_card: float, o: wp.vec3, d: wp.vec3):
    """(on_card, position, x, y, z, h): where the ray o + t d scatters, and the shading frame there. At a fiber,
    x along it (turning smoothly along the strand), z its normal and h the offset across it (docs/MODEL.md,
    "Shading frame"); at the card, z its normal turned toward the incoming ray, the position lifted off it."""
    on_card = t_card < hit.t
    x = hit.tangent
    z = hit.normal
    h = hit.h
    if not on_card:
        x, z, h = shading_frame(scene.fibers, hit, d)
    position = hit.position
    if on_card:
        z = scene.card.normal
        if wp.dot(z, d) > 0.0:
            z = -z
        x = perpendicular(z)
        position = o + t_card * d + 1.0e-5 * z
    y = wp.cross(z, x)
    return on_card, position, x, y, z, h


@wp.func
def escaped(scene: SceneData, throughput: wp.vec3, d: wp.vec3, prev_pdf: float, select_pdf: float):
    """The environment's contribution to a ray that leaves the scene, MIS-weighted against light sampling (a
    camera ray, prev_pdf = 0, takes it whole)."""
    mis = float(1.0)
    if prev_pdf > 0.0:
        mis = power_heuristic(prev_pdf, select_pdf * env_pdf(scene.env, d))
    return mis * wp.cw_mul(throughput, env_radiance(scene.env, d))


@wp.func
def sample_light(scene: SceneData, k: int, rng: wp.uint32):
    """(direction toward emitter k, its solid-angle pdf, rng); the directional lights come first, then the
    environment. A directional light is a delta: its pdf is 1, a probability, not a density (as in pbrt)."""
    direction = wp.vec3(0.0)
    pdf = float(1.0)
    if k < scene.num_lights:
        direction = scene.lights[k].to_light
    else:
        u, rng = rand2(rng)
        direction, pdf = env_sample(scene.env, u)
    return direction, pdf, rng


@wp.func
def light_radiance(scene: SceneData, k: int, direction: wp.vec3):
    """What emitter k sends along `direction`: a directional light's irradiance, the environment's radiance."""
    if k < scene.num_lights:
        return scene.lights[k].irradiance
    return env_radiance(scene.env, direction)


@wp.func
def sample_continuation(on_card: bool, setup: LobeSetup, rng: wp.uint32):
    """(local direction, rng): the next direction of the path, drawn from the vertex's BSDF."""
    wi = wp.vec3(0.0)
    if on_card:
        u2, rng = rand2(rng)
        wi = cosine_hemisphere(u2)
    else:
        wi = hair_sample(setup, wp.vec3(wp.randf(rng), wp.randf(rng), wp.randf(rng)))
    return wi, rng


@wp.func
def roulette(throughput: wp.vec3, rng: wp.uint32):
    """(alive, throughput, rng): the path survives with probability q = min(1, max_c throughput_c), and its
    throughput is divided by q if it does, which keeps the estimate unbiased."""
    survive = wp.min(1.0, wp.max(throughput[0], wp.max(throughput[1], throughput[2])))
    alive = True
    if wp.randf(rng) >= survive:
        alive = False
    else:
        throughput = throughput / survive
    return alive, throughput, rng


def make_scatter(differentiable: bool):
    """`scatter(scene, on_card, setup, wi) -> (value, pdf, lobes)`: the vertex's cosine-weighted BSDF value and
    solid-angle pdf toward local wi; with `differentiable`, at a fiber also the evaluation of its lobes that
    `hair_value_jacobian` differentiates (the forward variant returns an empty one)."""

    def scatter(scene: SceneData, on_card: bool, setup: LobeSetup, wi: wp.vec3):
        if wp.static(differentiable):
            if not on_card:
                value, density, lobes = hair_value_pdf_lobes(setup, wi)
                return value, density, lobes
        value, density = scatter_value_pdf(scene, on_card, setup, wi)
        return value, density, LobeEvaluation()

    return _named(scatter, "scatter_grad" if differentiable else "scatter")


def make_sample_ld(differentiable: bool, scatter):
    """Next-event estimation at a vertex, over every kind of light (pbrt's SampleLd):

    sample_ld(scene, on_card, position, x, y, z, setup, throughput, num_emitters, select_pdf, rng)
        -> (lit, contribution, S toward the light, lobes toward the light, rng)

    One emitter is chosen uniformly (one shadow ray per vertex whatever the number of lights, as in Mitsuba),
    then a direction toward it. The sample is tested for occlusion before the BSDF is evaluated toward it: an
    occluded sample, often most of them inside an assembly, then costs no evaluation. A directional light is a
    delta that BSDF sampling cannot hit: its sample is not weighted. The environment's is combined with BSDF
    sampling by the power heuristic (`escaped` takes the other side). `scatter` is `make_scatter(differentiable)`.
    """

    def sample_ld(
        scene: SceneData,
        on_card: bool,
        position: wp.vec3,
        x: wp.vec3,
        y: wp.vec3,
        z: wp.vec3,
        setup: LobeSetup,
        throughput: wp.vec3,
        num_emitters: int,
        select_pdf: float,
        rng: wp.uint32,
    ):
        k = wp.min(int(wp.randf(rng) * float(num_emitters)), num_emitters - 1)
        delta = k < scene.num_lights
        to_light, light_pdf, rng = sample_light(scene, k, rng)
        lit = False
        nee = wp.vec3(0.0)
        value = wp.vec3(0.0)
        lobes = LobeEvaluation()
        if light_pdf > 0.0:
            w_light = to_local(to_light, x, y, z)
            if light_visible(scene, on_card, position, to_light, w_light):
                value, pdf_bsdf, lobes = scatter(scene, on_card, setup, w_light)
                if pdf_bsdf > 0.0:
                    lit = True
                    f = wp.cw_mul(throughput, wp.cw_mul(value, light_radiance(scene, k, to_light)))
                    if delta:
                        nee = f / select_pdf
                    else:
                        p_light = select_pdf * light_pdf
                        nee = (power_heuristic(p_light, pdf_bsdf) / p_light) * f
        return lit, nee, value, lobes, rng

    return _named(sample_ld, "sample_ld_grad" if differentiable else "sample_ld")


def make_trace_path(differentiable: bool):
    """The path tracer as a `wp.func` (pbrt's Li); with `differentiable` it also returns the path's ∂L/∂θ.

    trace_path(scene, origin, direction, rng, derivs) -> (radiance, D, rng), `derivs` the material's
    `model.jacobian.coefficient_derivatives` and D[c, k] = ∂L_c/∂θ_k, the (3, 8) Jacobian of the path's
    radiance. The forward variant ignores `derivs` and returns D = 0: the branches under wp.static are compiled
    out of it.

    The gradient (detached sampling; docs/gradients.md explains why it is unbiased): every contribution C of a
    path is a product of BSDF values S_c over its fiber vertices divided by θ-independent factors (pdfs, MIS
    weights and roulette probabilities held fixed), so ∂C_c/∂θ_k = C_c Σ_vertices ∂ log S_c/∂θ_k. G[c, k]
    carries that sum over the vertices so far (at the directions the path continued in); each contribution
    adds C_c (G[c, k] + ∂ log S_c(w_light)/∂θ_k at an NEE vertex on a fiber) to D[c, k]. Keeping the channels
    apart gives the whole per-pixel Jacobian in one pass for what contracting them with an adjoint would cost;
    memory is flat in the depth (no tape over the loop). The card does not depend on θ.

    ∂S/∂θ is in closed form (`model.jacobian`): at a fiber vertex `lobe_setup_grad` once (what depends on wo and
    h), and `hair_value_jacobian` differentiates the very evaluation of the lobes that gave S and the pdf (so the
    path is the forward renderer's): for the continuation, and toward the light only when the sample is lit.
    """
    scatter = make_scatter(differentiable)
    sample_ld = make_sample_ld(differentiable, scatter)

    def trace_path(
        scene: SceneData,
        origin: wp.vec3,
        direction: wp.vec3,
        rng: wp.uint32,
        derivs: CoefficientDerivatives,
    ):
        radiance = wp.vec3(0.0)
        D = value_jacobian_mat()
        G = value_jacobian_mat()
        throughput = wp.vec3(1.0)
        o = origin
        d = direction
        num_emitters = scene.num_lights + scene.has_env
        select_pdf = 1.0 / float(wp.max(num_emitters, 1))
        prev_pdf = float(0.0)  # solid-angle pdf of the BSDF sample that produced d; 0 for the camera ray
        depth = int(0)  # scattering vertices so far
        while True:
            hit = intersect_fibers(scene.fibers, o, d, NO_HIT)
            t_card = card_distance(scene.card, o, d)
            if hit.t >= NO_HIT and t_card >= NO_HIT:
                if scene.has_env != 0:
                    contribution = escaped(scene, throughput, d, prev_pdf, select_pdf)
                    radiance += contribution
                    if wp.static(differentiable):
                        D += scaled_rows(contribution, G)
                break
            # The ray sampled at the last allowed vertex is still traced above: light sampling there was
            # MIS-weighted on the understanding that this ray would bring the rest of the environment.
            if depth >= scene.max_depth:
                break

            on_card, position, x, y, z, h = shading_point(scene, hit, t_card, o, d)
            wo = to_local(-d, x, y, z)
            setup = LobeSetup()
            if wp.static(differentiable):
                d_setup = LobeSetupGrad()
            if not on_card:
                setup = lobe_setup(scene.hair, wo, h)
                if wp.static(differentiable):
                    d_setup = lobe_setup_grad(setup, wo, h)

            if num_emitters > 0:
                lit, nee, nee_value, lobes_light, rng = sample_ld(
                    scene, on_card, position, x, y, z, setup, throughput, num_emitters, select_pdf, rng
                )
                if lit:
                    radiance += nee
                    if wp.static(differentiable):
                        D += scaled_rows(nee, G)
                        if not on_card:
                            # C_c ∂ log S_c(w_light)/∂θ, only for lit light samples.
                            J_light = hair_value_jacobian(setup, d_setup, derivs, lobes_light)
                            D += scaled_rows(log_weights(nee, nee_value), J_light)

            wi, rng = sample_continuation(on_card, setup, rng)
            value, pdf, lobes = scatter(scene, on_card, setup, wi)
            if pdf < FLOAT32_MIN_NORMAL:
                break
            throughput = wp.cw_mul(throughput, value / pdf)
            prev_pdf = pdf
            o = position
            d = wp.normalize(to_world(wi, x, y, z))
            depth += 1

            if depth >= scene.rr_depth:
                alive, throughput, rng = roulette(throughput, rng)
                if not alive:
                    break
            if wp.static(differentiable):
                # After roulette: a path it ends has no later contribution to carry the vertex's derivative to.
                if not on_card:
                    G = add_log_derivative(G, hair_value_jacobian(setup, d_setup, derivs, lobes), value)
        return radiance, D, rng

    return _named(trace_path, "trace_path_grad" if differentiable else "trace_path")


trace_path = make_trace_path(False)
trace_path_grad = make_trace_path(True)

