"""Unidirectional path tracing of fiber assemblies, with next-event estimation and multiple importance sampling.

At every fiber vertex the near-field BSDF is evaluated at the true offset h of the hit: the integral over h is
left to the path tracer rather than folded into a far-field lobe. Lights: directional lights (deltas, reached by
light sampling only) and one environment (constant or an importance-sampled lat-long map; light and BSDF
sampling combined by the power heuristic). Surfaces: the fibers and an optional diffuse backing card. Russian
roulette after `rr_depth` bounces keeps long paths in light hair unbiased without paying for all of them.

The tracer is built as pbrt-v4 factors its path integrator: `trace_path` (pbrt's `Li`) walks the path, and
`sample_ld` does next-event estimation over every kind of light. What the path meets at a vertex is a
`material.Vertex`, used only through its interface (`bsdf_f`, `bsdf_sample`; pbrt's f, PDF and Sample_f): the
tracer does not know whether it is on a fiber or on the card. `make_trace_path(True)` compiles the gradient of
the same walk in under `wp.static` branches (docs/gradients.md).
"""

import warp as wp

from ..model.hair_bsdf import HairCoefficients
from ..model.jacobian import CoefficientDerivatives, LobeEvaluation, value_jacobian_mat
from ..numerics import FLOAT32_MIN_NORMAL, power_heuristic, rand2, to_local, to_world
from .aggregate import MISS, Surfaces, intersect_scene, occluded_scene
from .camera import CameraData
from .envmap import EnvironmentData, env_pdf, env_radiance, env_sample
from .light_sampler import choose_light, light_probability
from .material import (
    HairVariation,
    Vertex,
    bsdf_can_reach,
    bsdf_f,
    bsdf_f_grad,
    bsdf_sample,
    bsdf_setup_grad,
    bsdf_value_jacobian,
    depends_on_controls,
    local_incident,
    scattering_vertex,
    vertex_derivatives,
)

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
    surfaces: Surfaces  # the fibers and the card, asked through aggregate.py
    hair: HairCoefficients
    variation: HairVariation  # each strand's look and the root-to-tip ramp (none: the material's everywhere)
    lights: wp.array(dtype=DirectionalLightData)
    num_lights: int
    env: EnvironmentData
    has_env: int
    light_cdf: wp.array(dtype=float)  # the emitters' cumulative selection probabilities (light_sampler.py)
    max_depth: int
    rr_depth: int


@wp.func
def occluded(scene: SceneData, origin: wp.vec3, direction: wp.vec3, strand: int, tube: int):
    """Whether a shadow ray toward a light at infinity is blocked; `strand` and `tube` are those the ray leaves."""
    return occluded_scene(scene.surfaces, origin, direction, strand, tube)


@wp.func
def light_visible(scene: SceneData, v: Vertex, to_light: wp.vec3, w_light: wp.vec3):
    """Whether a light sample (world direction to_light, local w_light) is unoccluded. Where the material's S
    toward it is 0 anyway (below the card), no shadow ray is traced."""
    if not bsdf_can_reach(v, w_light):
        return False
    return not occluded(scene, v.position, to_light, v.strand, v.tube)


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
def escaped(scene: SceneData, throughput: wp.vec3, d: wp.vec3, prev_pdf: float):
    """The environment's contribution to a ray that leaves the scene, MIS-weighted against light sampling, which
    chooses the environment with its own probability (a camera ray, prev_pdf = 0, takes it whole)."""
    mis = float(1.0)
    if prev_pdf > 0.0:
        select_pdf = light_probability(scene.light_cdf, scene.num_lights)
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


def make_sample_ld(differentiable: bool):
    """Next-event estimation at a vertex, over every kind of light (pbrt's SampleLd):

    sample_ld(scene, v, throughput, rng)
        -> (lit, contribution, S toward the light, lobes toward the light, rng)

    One emitter is chosen, by the irradiance each gives (one shadow ray per vertex whatever the number of lights;
    light_sampler.py), then a direction toward it. The sample is tested for occlusion before the BSDF is evaluated
    toward it: an occluded sample, often most of them inside an assembly, then costs no evaluation. A directional
    light is a delta that BSDF sampling cannot hit: its sample is not weighted. The environment's is combined with
    BSDF sampling by the power heuristic (`escaped` takes the other side). With `differentiable`, `lobes` is the
    evaluation of the material toward the light that `bsdf_value_jacobian` differentiates.
    """

    f_bsdf = bsdf_f_grad if differentiable else bsdf_f

    def sample_ld(
        scene: SceneData,
        v: Vertex,
        throughput: wp.vec3,
        rng: wp.uint32,
    ):
        k, select_pdf = choose_light(scene.light_cdf, wp.randf(rng))
        delta = k < scene.num_lights
        to_light, light_pdf, rng = sample_light(scene, k, rng)
        lit = False
        nee = wp.vec3(0.0)
        value = wp.vec3(0.0)
        lobes = LobeEvaluation()
        if light_pdf > 0.0:
            w_light = to_local(to_light, v.x, v.y, v.z)
            if light_visible(scene, v, to_light, w_light):
                value, pdf_bsdf, lobes = f_bsdf(v, local_incident(v, w_light))
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

    trace_path(scene, origin, direction, rng, derivs) -> (radiance, D, rng), `derivs` the hair's
    `model.jacobian.coefficient_derivatives` and D[c, k] = ∂L_c/∂θ_k, the (3, THETA_SIZE) Jacobian of the path's
    radiance. The forward variant ignores `derivs` and returns D = 0: the branches under wp.static are compiled
    out of it.

    The gradient (detached sampling; docs/gradients.md explains why it is unbiased): every contribution C of a
    path is a product of BSDF values S_c over its vertices divided by θ-independent factors (pdfs, MIS
    weights and roulette probabilities held fixed), so ∂C_c/∂θ_k = C_c Σ_vertices ∂ log S_c/∂θ_k. G[c, k]
    carries that sum over the vertices so far (at the directions the path continued in); each contribution
    adds C_c (G[c, k] + ∂ log S_c(w_light)/∂θ_k at an NEE vertex that depends on θ) to D[c, k]. Keeping the
    channels apart gives the whole per-pixel Jacobian in one pass for what contracting them with an adjoint would
    cost; memory is flat in the depth (no tape over the loop). Vertices whose S does not depend on θ (the card)
    add nothing to G.

    ∂S/∂θ is in closed form (`model.jacobian`, through `material`): `bsdf_setup_grad` once per vertex (what
    depends on wo and h), and `bsdf_value_jacobian` differentiates the very evaluation of the lobes that gave S
    and the pdf (so the path is the forward renderer's): for the continuation, and toward the light only when
    the sample is lit.
    """
    f_bsdf = bsdf_f_grad if differentiable else bsdf_f
    sample_ld = make_sample_ld(differentiable)

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
        prev_pdf = float(0.0)  # solid-angle pdf of the BSDF sample that produced d; 0 for the camera ray
        depth = int(0)  # scattering vertices so far
        strand = int(-1)  # the strand the ray leaves (the "exit" rule skips it); −1 for none
        tube = int(-1)  # the tube the ray leaves, which it need not test (`intersect_fibers`); −1 for none
        while True:
            met = intersect_scene(scene.surfaces, o, d, strand, tube)
            if met.kind == MISS:
                if scene.has_env != 0:
                    contribution = escaped(scene, throughput, d, prev_pdf)
                    radiance += contribution
                    if wp.static(differentiable):
                        D += scaled_rows(contribution, G)
                break
            # The ray sampled at the last allowed vertex is still traced above: light sampling there was
            # MIS-weighted on the understanding that this ray would bring the rest of the environment.
            if depth >= scene.max_depth:
                break

            v = scattering_vertex(scene.surfaces, scene.hair, scene.variation, met, o, d)
            if wp.static(differentiable):
                dv = bsdf_setup_grad(v)
                k = derivs
                if depends_on_controls(v):
                    k = vertex_derivatives(scene.variation, scene.surfaces.fibers, met.fiber, v, derivs)

            if num_emitters > 0:
                lit, nee, nee_value, lobes_light, rng = sample_ld(scene, v, throughput, rng)
                if lit:
                    radiance += nee
                    if wp.static(differentiable):
                        D += scaled_rows(nee, G)
                        if depends_on_controls(v):
                            # C_c ∂ log S_c(w_light)/∂θ, only for lit light samples.
                            J_light = bsdf_value_jacobian(v, dv, k, lobes_light)
                            D += scaled_rows(log_weights(nee, nee_value), J_light)

            wi, rng = bsdf_sample(v, rng)
            value, pdf, lobes = f_bsdf(v, wi)
            if pdf < FLOAT32_MIN_NORMAL:
                break
            throughput = wp.cw_mul(throughput, value / pdf)
            prev_pdf = pdf
            o = v.position
            d = wp.normalize(to_world(wi.w, v.x, v.y, v.z))
            strand = v.strand
            tube = v.tube
            depth += 1

            if depth >= scene.rr_depth:
                alive, throughput, rng = roulette(throughput, rng)
                if not alive:
                    break
            if wp.static(differentiable):
                # After roulette: a path it ends has no later contribution to carry the vertex's derivative to.
                if depends_on_controls(v):
                    G = add_log_derivative(G, bsdf_value_jacobian(v, dv, k, lobes), value)
        return radiance, D, rng

    return _named(trace_path, "trace_path_grad" if differentiable else "trace_path")


trace_path = make_trace_path(False)
trace_path_grad = make_trace_path(True)
