"""What a path meets at a scattering vertex: a material in its shading frame, behind one interface (pbrt's BSDF).

    v = scattering_vertex(surfaces, hair, variation, met, o, d)   # the surface met, its frame, wo (GetBSDF)
    d = local_incident(v, wi)            # a local direction wi with the angles the hair's lobes read of it
    value, pdf, lobes = bsdf_f(v, d)     # cosine-weighted S and solid-angle pdf toward d (f and PDF);
                                         # bsdf_f_grad also evaluates the lobes for ∂S/∂θ
    d, rng = bsdf_sample(v, rng)         # a direction drawn from the material, d.w (Sample_f), with its angles
    bsdf_can_reach(v, wi)                # False where S is 0 whatever the controls: no shadow ray is traced

Two materials, told apart by `Vertex.kind`: the hair BSDF (model/hair_bsdf.py) at a fiber, and the backing
card's two-sided Lambertian (geometry/card.py), whose frame faces the incoming ray. The integrator calls only
these functions, so `trace_path` does not know which material it has met; a Warp function dispatches on the
kind, which keeps the kernels short and allocation-free.

Derivatives (the gradient tracer, docs/gradients.md): only the hair depends on the controls θ.
`depends_on_controls(v)` says whether a vertex's S does, `bsdf_setup_grad(v)` gives what of ∂S/∂θ depends on wo
and h, and `bsdf_value_jacobian` the (3, 8) ∂S/∂θ toward the direction `bsdf_f_grad(v, d)` was evaluated at.
"""

import warp as wp

from ..geometry.intersect import FiberGeometry, FiberHit, shading_frame
from ..model.hair_bsdf import (
    HairCoefficients,
    Incident,
    LobeSetup,
    hair_sample_incident,
    hair_value_pdf_at,
    incident,
    lobe_setup,
)
from ..model.jacobian import (
    CoefficientDerivatives,
    LobeEvaluation,
    LobeSetupGrad,
    hair_value_jacobian,
    hair_value_pdf_lobes,
    lobe_setup_grad,
)
from ..numerics import INV_PI, TWO_PI, perpendicular, rand2, to_local
from .aggregate import CARD, HAIR, SurfaceHit, Surfaces

# As the integrator: forward only, -O3.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})


@wp.struct
class HairVariation:
    """Each strand's own look and the change from root to tip (model/variation.py); with `strands` and `tip` 0
    every fiber renders with the material's coefficients, exactly as without variation. The derivatives in the
    variation's controls are there at every look, no variation included (a spread's at 0, the tip's at 1)."""

    strands: int  # 1: each strand's coefficients from `hair` (indexed by strand)
    hair: wp.array(dtype=HairCoefficients)
    # Each strand's, for the gradient tracer: its spread columns always, the rest too where `strands` is 1.
    derivs: wp.array(dtype=CoefficientDerivatives)
    tip: int  # 1: the absorption ramps toward the tip
    tip_absorption: float
    tip_length: float
    segment_start: wp.array(dtype=float)  # arc-length fraction of the strand at each segment's start
    segment_span: wp.array(dtype=float)  # ... and the fraction the segment covers


@wp.struct
class Vertex:
    """A scattering vertex: the material there and its local frame (x, y, z)."""

    kind: int  # HAIR or CARD
    position: wp.vec3  # where the rays leaving the vertex start (lifted off the card)
    strand: int  # the fiber's strand, which the rays leaving a vertex skip under the "exit" rule; −1 on the card
    tube: int  # the fiber's tube (`FiberHit.tube`), which the rays leaving a vertex need not test; −1 on the card
    x: wp.vec3  # along the fiber; any tangent of the card
    y: wp.vec3
    z: wp.vec3  # the fiber's normal; the card's normal on the side of the incoming ray
    wo: wp.vec3  # local, toward where the path came from
    h: float  # the offset across the fiber (hair only)
    hair: LobeSetup  # what of the hair BSDF depends on wo and h (hair only)
    albedo: wp.vec3  # the card's (card only)


@wp.func
def cosine_hemisphere(u: wp.vec2):
    """A cosine-distributed direction about +z (Malley: project a uniform disk sample up)."""
    r = wp.sqrt(u[0])
    phi = TWO_PI * u[1]
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u[0])))


@wp.func
def diffuse_value_pdf(albedo: wp.vec3, wi: wp.vec3):
    """(cosine-weighted value, solid-angle pdf) of a Lambertian reflector about +z: both cos θ_i / π, times the
    albedo for the value; 0 below the surface."""
    if wi[2] <= 0.0:
        return wp.vec3(0.0), 0.0
    return wi[2] * INV_PI * albedo, wi[2] * INV_PI


@wp.func
def tip_ramp(t: float, tip_length: float):
    """clamp((t − (1 − L)) / L, 0, 1): 0 up to 1 − L from the root, 1 at the tip."""
    return wp.clamp((t - (1.0 - tip_length)) / tip_length, 0.0, 1.0)


@wp.func
def strand_intercept(fibers: FiberGeometry, variation: HairVariation, hit: FiberHit):
    """The hit's arc-length fraction along its strand, from the root (linear within its segment)."""
    along = wp.clamp(wp.dot(hit.position - fibers.start[hit.segment], fibers.step[hit.segment]), 0.0, 1.0)
    return variation.segment_start[hit.segment] + variation.segment_span[hit.segment] * along


@wp.func
def fiber_coefficients(fibers: FiberGeometry, hair: HairCoefficients, variation: HairVariation, hit: FiberHit):
    """The coefficients at a fiber hit: the material's, or its strand's, with the tip's absorption."""
    c = hair
    if variation.strands != 0:
        c = variation.hair[hit.strand]
    if variation.tip != 0:
        t = strand_intercept(fibers, variation, hit)
        c.sigma_a = c.sigma_a * (1.0 + (variation.tip_absorption - 1.0) * tip_ramp(t, variation.tip_length))
    return c


@wp.func
def scattering_vertex(
    surfaces: Surfaces, hair: HairCoefficients, variation: HairVariation, met: SurfaceHit, o: wp.vec3, d: wp.vec3
):
    """The vertex where the ray o + t d meets the surface `met` (`aggregate.intersect_scene`, not a miss). At a
    fiber, x along it (turning smoothly along the strand), z its normal and h the offset across it (docs/MODEL.md,
    "Shading frame"); at the card, z its normal turned toward the incoming ray, the position lifted off it."""
    v = Vertex()
    v.kind = met.kind
    hit = met.fiber
    x = hit.tangent
    z = hit.normal
    h = hit.h
    if v.kind == HAIR:
        x, z, h = shading_frame(surfaces.fibers, hit, d)
    position = hit.position
    if v.kind == CARD:
        z = surfaces.card.normal
        if wp.dot(z, d) > 0.0:
            z = -z
        x = perpendicular(z)
        position = o + met.t * d + 1.0e-5 * z
    y = wp.cross(z, x)
    v.position = position
    v.strand = wp.where(v.kind == HAIR, hit.strand, -1)
    v.tube = wp.where(v.kind == HAIR, hit.tube, -1)
    v.x = x
    v.y = y
    v.z = z
    v.wo = to_local(-d, x, y, z)
    v.h = h
    if v.kind == HAIR:
        v.hair = lobe_setup(fiber_coefficients(surfaces.fibers, hair, variation, hit), v.wo, h)
    else:
        v.albedo = surfaces.card.albedo
    return v


@wp.func
def local_incident(v: Vertex, wi: wp.vec3):
    """The local direction wi as the vertex's material reads it (at the card, the direction alone)."""
    if v.kind == HAIR:
        return incident(v.hair, wi)
    d = Incident()
    d.w = wi
    return d


@wp.func
def bsdf_value_pdf(v: Vertex, wi: Incident):
    """(cosine-weighted value, solid-angle pdf) of the vertex's material toward a local direction."""
    if v.kind == CARD:
        return diffuse_value_pdf(v.albedo, wi.w)
    return hair_value_pdf_at(v.hair, wi)


@wp.func
def bsdf_can_reach(v: Vertex, wi: wp.vec3):
    """False where S toward local wi is 0 whatever the controls (below the card's surface): a light sample there
    needs no shadow ray."""
    if v.kind == CARD:
        return wi[2] > 0.0
    return True


@wp.func
def bsdf_sample(v: Vertex, rng: wp.uint32):
    """(Incident, rng): a local direction drawn from the vertex's material (2 uniforms at the card, 3 at a
    fiber), with the angles a fiber's sample was built from, which `bsdf_f` then reads instead of recovering them."""
    d = Incident()
    if v.kind == CARD:
        u2, rng = rand2(rng)
        d.w = cosine_hemisphere(u2)
    else:
        d = hair_sample_incident(v.hair, wp.vec3(wp.randf(rng), wp.randf(rng), wp.randf(rng)))
    return d, rng


@wp.func
def bsdf_f(v: Vertex, wi: Incident):
    """(value, pdf, lobes): `bsdf_value_pdf`, with an empty lobe evaluation (the forward tracer's variant)."""
    value, density = bsdf_value_pdf(v, wi)
    return value, density, LobeEvaluation()


@wp.func
def bsdf_f_grad(v: Vertex, wi: Incident):
    """(value, pdf, lobes): `bsdf_value_pdf` (the same floats), and at a fiber also the evaluation of its lobes
    that `bsdf_value_jacobian` differentiates (the gradient tracer's variant)."""
    if v.kind == HAIR:
        value, density, lobes = hair_value_pdf_lobes(v.hair, wi)
        return value, density, lobes
    value, density = bsdf_value_pdf(v, wi)
    return value, density, LobeEvaluation()


@wp.func
def depends_on_controls(v: Vertex):
    """Whether the vertex's S depends on the hair controls θ (the card's does not)."""
    return v.kind == HAIR


@wp.func
def bsdf_setup_grad(v: Vertex):
    """What of ∂S/∂θ depends on wo and h only, once per vertex (empty where S does not depend on θ)."""
    if v.kind == HAIR:
        return lobe_setup_grad(v.hair, v.wo, v.h)
    return LobeSetupGrad()


@wp.func
def bsdf_value_jacobian(v: Vertex, dv: LobeSetupGrad, derivs: CoefficientDerivatives, lobes: LobeEvaluation):
    """∂S_c/∂θ_k (3, 8) toward the direction `lobes` was evaluated at, at a vertex that `depends_on_controls`."""
    return hair_value_jacobian(v.hair, dv, derivs, lobes)


@wp.func
def vertex_derivatives(
    variation: HairVariation, fibers: FiberGeometry, hit: FiberHit, v: Vertex, derivs: CoefficientDerivatives
):
    """The CoefficientDerivatives at the fiber vertex v of `hit`: the material's `derivs`, or its strand's; its
    strand's spread columns; with a tip ramp every ∂σ_a/∂θ times the vertex's factor g(t) = σ_a(t)/σ_a; the tip's
    own columns (at every look: the gradient at no variation is not 0). The gradient tracer's only: the forward
    one needs no intercept where the tip does not ramp."""
    k = derivs
    if variation.strands != 0:
        k = variation.derivs[hit.strand]
    else:
        # No spread yet: the material's coefficients, and each strand's first-order change with the spreads.
        own = variation.derivs[hit.strand]
        k.d_sigma_d_color_spread = own.d_sigma_d_color_spread
        k.d_sigma_d_roughness_spread = own.d_sigma_d_roughness_spread
        k.d_log_v_d_roughness_spread = own.d_log_v_d_roughness_spread
        k.d_log_s_d_roughness_spread = own.d_log_s_d_roughness_spread
    t = strand_intercept(fibers, variation, hit)
    a = variation.tip_absorption
    length = variation.tip_length
    ramp = tip_ramp(t, length)
    g = 1.0 + (a - 1.0) * ramp
    sigma = v.hair.c.sigma_a
    if variation.tip != 0:
        sigma = sigma / g  # the strand's, before the ramp
        k.d_sigma_d_colour = k.d_sigma_d_colour * g
        k.d_sigma_d_beta_n = k.d_sigma_d_beta_n * g
        k.d_sigma_d_color_spread = k.d_sigma_d_color_spread * g
        k.d_sigma_d_roughness_spread = k.d_sigma_d_roughness_spread * g
    k.d_sigma_d_tip_absorption = sigma * ramp
    d_ramp = float(0.0)  # ∂ramp/∂L = (1 − t)/L² inside the ramp
    if ramp > 0.0 and ramp < 1.0:
        d_ramp = (1.0 - t) / (length * length)
    k.d_sigma_d_tip_length = sigma * ((a - 1.0) * d_ramp)
    return k
