"""Tests of warp_hair.geometry.intersect: exact entering hits on mitred, open-ended fiber tubes.

The reference is a float64 NumPy brute force of the same definition, written independently of the module:
for every tube the ray–cylinder quadratic, its entering root, and the two clip planes (mitre planes at
interior joints, perpendicular planes at strand ends).
"""

from pathlib import Path

import numpy as np
import pytest

from warp_hair.geometry import bvh as bvh_module
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.formats import load_fibers
from warp_hair.geometry.generators import wavy
from warp_hair.geometry.intersect import BVH_WIDTH, STACK_SIZE, stack_slots
from warp_hair.geometry.rays import distance, intersect, occluded
from warp_hair.geometry.tubes import FiberBVH, segment_boxes, segment_frames, segment_pieces

BENCH_FIBERS = Path(__file__).parents[1] / "benchmarks" / "standard_swatch_fibers.txt"
T_MIN_RADII = 1e-3


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_directions(rng, n):
    return unit(rng.normal(size=(n, 3)))


def perpendicular_basis(a):
    """Two unit vectors completing the unit vector a to a right-handed frame."""
    u = unit(np.cross(a, [0.3, 0.5, 0.8]))
    return u, np.cross(a, u)


# --- the float64 reference ---------------------------------------------------------------------------------------


def reference_tubes(assembly):
    """Per-segment p0, p1, unit axis a, radius and clip normals m0, m1 (pointing into the tube), in float64."""
    rows = {key: [] for key in ("p0", "p1", "a", "r", "m0", "m1")}
    for k in range(assembly.num_strands):
        points, radii = assembly.strand(k)
        points = points.astype(np.float64)
        axes = unit(np.diff(points, axis=0))
        last = len(axes) - 1
        for i, a in enumerate(axes):
            rows["p0"].append(points[i])
            rows["p1"].append(points[i + 1])
            rows["a"].append(a)
            rows["r"].append((float(radii[i]) + float(radii[i + 1])) / 2)
            rows["m0"].append(a if i == 0 else unit(axes[i - 1] + a))
            rows["m1"].append(-a if i == last else -unit(a + axes[i + 1]))
    return {key: np.array(value) for key, value in rows.items()}


def reference_crossings(tubes, origins, directions):
    """(N, M) arrays for each ray and tube: the entering and exiting roots of the cylinder (nan when the ray
    line misses it), the interval [lo, hi] of t inside the clipped solid tube (empty when lo > hi), whether
    the entering root lies between the clip planes, its distance to the nearer plane over r, and h there."""
    o = origins[:, None, :]
    d = directions[:, None, :]
    a = tubes["a"][None]
    r = tubes["r"][None]
    w = o - tubes["p0"][None]
    w_perp = w - np.sum(w * a, axis=-1, keepdims=True) * a
    d_perp = d - np.sum(d * a, axis=-1, keepdims=True) * a
    qa = np.sum(d_perp * d_perp, axis=-1)
    qb = np.sum(w_perp * d_perp, axis=-1)
    qc = np.sum(w_perp * w_perp, axis=-1) - r**2
    disc = qb**2 - qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(np.where(disc > 0, disc, np.nan))
        t_in = (-qb - root) / qa
        t_out = (-qb + root) / qa
    lo, hi = t_in.copy(), t_out.copy()
    margins = []
    for end, normal in (("p0", "m0"), ("p1", "m1")):
        m = tubes[normal][None]
        s0 = np.sum((o - tubes[end][None]) * m, axis=-1)
        rate = np.sum(d * m, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            bound = -s0 / rate
        lo = np.where(rate > 0, np.maximum(lo, bound), lo)
        hi = np.where(rate < 0, np.minimum(hi, bound), hi)
        hi = np.where((rate == 0) & (s0 < 0), -np.inf, hi)
        margins.append((s0 + t_in * rate) / r)
    margin = np.fmin(*margins)
    entering = (margin >= 0) & (t_in > T_MIN_RADII * r)

    position = o + t_in[..., None] * d
    normal = (w_perp + t_in[..., None] * d_perp) / r[..., None]
    y = np.cross(normal, np.broadcast_to(a, normal.shape))
    wo_y, wo_z = np.sum(-d * y, axis=-1), np.sum(-d * normal, axis=-1)
    with np.errstate(invalid="ignore"):
        h = -wo_y / np.hypot(wo_y, wo_z)
    return {
        "t_in": t_in,
        "lo": lo,
        "hi": hi,
        "entering": entering,
        "margin": margin,
        "h": h,
        "position": position,
        "normal": normal,
    }


def reference_closest(tubes, origins, directions, t_max=np.inf):
    """Closest entering hit per ray: t (inf on a miss), segment (−1), and whether the answer is robust,
    i.e. no tube of the ray is within rounding of a silhouette, a clip plane or t_max. The clip-plane margin
    (5e-3·r) is wider than the 1e-3·r by which the module lets mitred tubes overlap, where either may win."""
    c = reference_crossings(tubes, origins, directions)
    t_hits = np.where(c["entering"] & (c["t_in"] < t_max), c["t_in"], np.inf)
    segment = np.where(np.isfinite(t_hits.min(axis=1)), t_hits.argmin(axis=1), -1)
    with np.errstate(invalid="ignore"):
        near_edge = (
            (np.abs(np.abs(c["h"]) - 1) < 1e-4) | (np.abs(c["margin"]) < 5e-3) | (np.abs(c["t_in"] - t_max) < 1e-4)
        )
    return t_hits.min(axis=1), segment, ~near_edge.any(axis=1)


def union_entries(tubes, origins, directions, gap=1e-9):
    """Where each ray enters the union of the clipped solid tubes through a tube's side, in float64: the
    starts (t > 0) of the merged inside-intervals that are entering roots of a cylinder (not an open end)."""
    c = reference_crossings(tubes, origins, directions)
    result = []
    for lo, hi, t_in in zip(c["lo"], c["hi"], c["t_in"]):
        inside = np.flatnonzero(lo < hi)
        entries = []
        end = -np.inf
        for k in inside[np.argsort(lo[inside])]:
            if lo[k] > end + gap:
                entries.append((lo[k], lo[k] == t_in[k]))
            end = max(end, hi[k])
        result.append([t for t, lateral in entries if lateral and t > 0])
    return result


# --- scenes ------------------------------------------------------------------------------------------------------


def straight_fiber(p0=(0.1, -0.3, 0.2), axis=(0.36, 0.48, 0.8), length=1.2, radius=0.05):
    axis = unit(axis)
    p0 = np.asarray(p0, dtype=np.float64)
    return FiberAssembly.from_strands([(np.stack([p0, p0 + length * axis]), radius)]), axis


def bent_fiber(radius=0.04):
    """One strand bent by 25°, 45°, 70° and 30° at its joints, partly out of plane."""
    turns = np.radians([0.0, 25.0, 70.0, 140.0, 170.0])
    lift = np.array([0.0, 0.1, -0.2, 0.15, 0.0])
    steps = unit(np.column_stack([np.cos(turns), np.sin(turns), lift])) * 0.4
    points = np.concatenate([[[0.0, 0.0, 0.0]], np.cumsum(steps, axis=0)])
    return FiberAssembly.from_strands([(points, radius)])


def tangle():
    """Wavy strands crossing each other, plus a tapered one (stepped radii) through the middle."""
    strands = wavy(count=6, layers=2, length=0.8, radius=0.02, amplitude=0.05, wavelength=0.4, phase_jitter=1.0, seed=3)
    points = np.column_stack([np.linspace(-0.4, 0.4, 6), np.zeros(6), 0.3 * np.sin(np.linspace(0, 3, 6)) - 0.1])
    tapered = FiberAssembly.from_strands([(points, np.linspace(0.03, 0.01, 6))])
    return FiberAssembly.concatenate([strands, tapered])


def rays_toward(rng, targets, distance=2.0):
    """Rays from `distance` away toward each target, rounded to float32 as the kernels receive them."""
    directions = random_directions(rng, len(targets)).astype(np.float32).astype(np.float64)
    directions = unit(directions)
    return (targets - distance * directions).astype(np.float32).astype(np.float64), directions


# --- a straight segment ------------------------------------------------------------------------------------------


def test_perpendicular_rays_hit_the_surface_with_the_signed_offset_as_h():
    fibers, axis = straight_fiber()
    r = 0.05
    bvh = FiberBVH(fibers)
    u, v = perpendicular_basis(axis)
    offsets = np.linspace(-0.99, 0.99, 41) * r
    foot = np.asarray([0.1, -0.3, 0.2]) + 0.5 * axis  # on the axis, mid-segment
    origins = foot + 1.5 * v + offsets[:, None] * u
    directions = np.broadcast_to(-v, origins.shape)
    hit = intersect(bvh, origins, directions)

    np.testing.assert_allclose(hit["t"], 1.5 - np.sqrt(r**2 - offsets**2), atol=1e-6)
    radial = hit["position"] - foot
    radial -= np.sum(radial * axis, axis=1, keepdims=True) * axis
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), r, atol=1e-5 * r)
    np.testing.assert_allclose(hit["tangent"], np.broadcast_to(axis, origins.shape), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(hit["normal"], axis=1), 1, atol=1e-6)
    np.testing.assert_allclose(np.sum(hit["normal"] * axis, axis=1), 0, atol=1e-6)
    np.testing.assert_allclose(hit["normal"], radial / r, atol=1e-5)
    # The signed offset is measured along a × d.
    side = np.cross(axis, -v)
    np.testing.assert_allclose(hit["h"], offsets * np.dot(u, side) / r, atol=1e-5)
    # ... which is the h of docs/MODEL.md in the frame the hit returns.
    wo = -np.asarray(directions)
    y = np.cross(hit["normal"], hit["tangent"])
    wo_y, wo_z = np.sum(wo * y, axis=1), np.sum(wo * hit["normal"], axis=1)
    np.testing.assert_allclose(hit["h"], -wo_y / np.hypot(wo_y, wo_z), atol=1e-6)
    assert np.all(wo_z > 0)
    assert np.all(hit["segment"] == 0) and np.all(hit["strand"] == 0)


@pytest.mark.parametrize("scene", ["straight", "bent", "tangle"])
def test_random_rays_agree_with_the_float64_brute_force(scene):
    fibers = {"straight": lambda: straight_fiber()[0], "bent": bent_fiber, "tangle": tangle}[scene]()
    tubes = reference_tubes(fibers)
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(11)
    n = 3000
    lo, hi = bvh.bounds
    origins, directions = rays_toward(rng, rng.uniform(lo, hi, (n, 3)))
    hit = intersect(bvh, origins, directions)
    t_ref, segment_ref, robust = reference_closest(tubes, origins, directions)

    assert robust.mean() > 0.95
    assert 0.1 < np.isfinite(t_ref).mean() < 0.9
    np.testing.assert_array_equal(np.isfinite(hit["t"])[robust], np.isfinite(t_ref)[robust])
    both = robust & np.isfinite(t_ref)
    np.testing.assert_array_equal(hit["segment"][both], segment_ref[both])
    c = reference_crossings(tubes, origins[both], directions[both])
    rows = np.arange(both.sum())
    seg = segment_ref[both]
    h_ref = c["h"][rows, seg]
    # float32 places a ray 2 units away to within about eps ≈ 1e-6; the offset from the axis inherits that
    # error, and t, the position and the normal amplify it near the silhouette (1/sqrt(1 − h²)) and, for t and
    # the position, on rays oblique to the fiber (1/sin of the angle to the axis).
    eps = 1e-6
    r = tubes["r"][seg]
    silhouette = 1 / np.sqrt(1 - h_ref**2)
    oblique = 1 / np.linalg.norm(np.cross(tubes["a"][seg], directions[both]), axis=1)
    np.testing.assert_array_less(np.abs(hit["h"][both] - h_ref), eps / r)
    np.testing.assert_array_less(np.abs(hit["t"][both] - t_ref[both]), eps * (1 + silhouette) * oblique)
    position_error = np.linalg.norm(hit["position"][both] - c["position"][rows, seg], axis=1)
    np.testing.assert_array_less(position_error, eps * (1 + silhouette) * oblique)
    normal_error = np.linalg.norm(hit["normal"][both] - c["normal"][rows, seg], axis=1)
    np.testing.assert_array_less(normal_error, eps * silhouette / r)
    strand_of_segment = fibers.segments()[4]
    np.testing.assert_array_equal(hit["strand"][both], strand_of_segment[segment_ref[both]])


# --- grazing rays ------------------------------------------------------------------------------------------------


def test_grazing_offsets():
    fibers, axis = straight_fiber()
    r = 0.05
    bvh = FiberBVH(fibers)
    u, v = perpendicular_basis(axis)
    foot = np.asarray([0.1, -0.3, 0.2]) + 0.5 * axis
    inside = np.array([1 - 1e-3, 1 - 1e-4, -(1 - 1e-4)]) * r
    outside = np.array([1 + 1e-4, -(1 + 1e-4), 1 + 1e-3]) * r
    offsets = np.concatenate([inside, outside])
    origins = foot + 1.5 * v + offsets[:, None] * u
    hit = intersect(bvh, origins, np.broadcast_to(-v, origins.shape))
    assert np.all(np.isfinite(hit["t"][:3])) and np.all(np.isinf(hit["t"][3:]))
    assert np.all(np.abs(hit["h"][:3]) > 0.99) and np.all(np.abs(hit["h"][:3]) <= 1)
    assert np.all(np.isfinite(hit["normal"][:3]))


def test_rays_almost_parallel_to_the_axis():
    fibers, axis = straight_fiber()
    tubes = reference_tubes(fibers)
    bvh = FiberBVH(fibers)
    u, v = perpendicular_basis(axis)
    rng = np.random.default_rng(5)
    n = 400
    tilt = rng.uniform(1e-3, 3e-2, n)
    spin = rng.uniform(0, 2 * np.pi, n)
    side = np.cos(spin)[:, None] * u + np.sin(spin)[:, None] * v
    directions = unit(unit(axis + tilt[:, None] * side).astype(np.float32))
    # Start outside the tube, beside its root, heading up along it and slowly inward.
    origins = (np.asarray([0.1, -0.3, 0.2]) + 0.3 * axis - 0.06 * side - 1.0 * directions).astype(np.float32)
    hit = intersect(bvh, origins, directions)
    t_ref, _, robust = reference_closest(tubes, origins, directions)
    assert robust.mean() > 0.95 and np.isfinite(t_ref).mean() > 0.2
    np.testing.assert_array_equal(np.isfinite(hit["t"])[robust], np.isfinite(t_ref)[robust])
    both = robust & np.isfinite(t_ref)
    # The axis is stored in float32: its rounding shifts sin(tilt), and with it t, by ~1e-7/sin²(tilt).
    sin_tilt = np.linalg.norm(np.cross(axis, directions[both]), axis=1)
    np.testing.assert_array_less(np.abs(hit["t"][both] - t_ref[both]), 1e-6 / sin_tilt**2)

    # Exactly parallel and outside: never enters the side.
    parallel = intersect(bvh, np.asarray([0.1, -0.3, 0.2]) + 0.06 * u - axis, axis[None])
    assert np.isinf(parallel["t"][0])


# --- rays starting on a fiber ------------------------------------------------------------------------------------


def test_rays_from_the_surface_never_see_their_own_tube():
    fibers, axis = straight_fiber()
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(2)
    n = 2000
    origins, directions = rays_toward(rng, np.asarray([0.1, -0.3, 0.2]) + rng.uniform(0.1, 1.1, (n, 1)) * axis)
    first = intersect(bvh, origins, directions)
    on = np.isfinite(first["t"])
    assert on.mean() > 0.5
    start, normal = first["position"][on], first["normal"][on]
    new = random_directions(rng, len(start))
    again = intersect(bvh, start, new)
    assert np.all(np.isinf(again["t"])), "both outward and inward rays must leave their own tube"
    # Rays through the fiber (the TT direction) included.
    through = intersect(bvh, start, directions[on])
    assert np.all(np.isinf(through["t"]))
    assert np.any(np.sum(new * normal, axis=1) < -0.9) and np.any(np.sum(new * normal, axis=1) > 0.9)


def test_grazing_rays_from_just_outside_the_surface_do_not_re_enter():
    # float32 puts a hit up to ~1e-7·|position| off the surface, outside as often as inside. A ray leaving
    # from there nearly tangentially and slightly inward would re-enter the tube at t ≈ gap / cos, well past
    # any fixed t_min of 1e-3·r; the tube must still be invisible to it.
    r = 0.004
    fibers, axis = straight_fiber(p0=(0.3, -0.5, 0.2), radius=r)
    bvh = FiberBVH(fibers)
    u, v = perpendicular_basis(axis)
    rng = np.random.default_rng(9)
    n = 500
    angle = rng.uniform(0, 2 * np.pi, n)
    normal = np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v
    across = np.cross(axis, normal)
    starts = np.asarray([0.3, -0.5, 0.2]) + rng.uniform(0.2, 1.0, (n, 1)) * axis + r * (1 + 2e-4) * normal
    directions = unit(across + rng.uniform(-0.5, 0.5, (n, 1)) * axis - rng.uniform(0.005, 0.05, (n, 1)) * normal)
    assert np.all(np.isinf(intersect(bvh, starts, directions)["t"]))


def test_rays_through_a_fiber_hit_the_one_behind():
    front, _ = straight_fiber(p0=(-0.5, 0.0, 0.0), axis=(1, 0, 0), length=1.0, radius=0.05)
    back, _ = straight_fiber(p0=(-0.5, 0.0, -0.3), axis=(1, 0, 0), length=1.0, radius=0.05)
    bvh = FiberBVH(FiberAssembly.concatenate([front, back]))
    y = np.linspace(-0.045, 0.045, 31)
    origins = np.column_stack([np.zeros_like(y), y, np.full_like(y, 2.0)])
    down = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)
    first = intersect(bvh, origins, down)
    assert np.all(first["strand"] == 0)
    second = intersect(bvh, first["position"], down)
    assert np.all(second["strand"] == 1)
    np.testing.assert_allclose(second["position"][:, 2], np.sqrt(0.05**2 - y**2) - 0.3, atol=1e-6)
    # From inside the front fiber, the back one is the next hit too.
    inside = intersect(bvh, first["position"] + [0.0, 0.0, -0.01], down)
    assert np.all(inside["strand"] == 1)


# --- joints ------------------------------------------------------------------------------------------------------


def successive_entries(bvh, origins, directions, limit=16):
    """t of every entering hit along each ray, found by restarting each ray at its previous hit."""
    entries = [[] for _ in origins]
    positions = np.array(origins, dtype=np.float64)
    travelled = np.zeros(len(origins))
    active = np.arange(len(origins))
    for _ in range(limit):
        hit = intersect(bvh, positions[active], directions[active])
        active = active[np.isfinite(hit["t"])]
        if not len(active):
            return entries
        step = np.isfinite(hit["t"])
        travelled[active] += hit["t"][step]
        positions[active] = hit["position"][step]
        for k in active:
            entries[k].append(travelled[k])
    raise AssertionError("too many entries")


def test_joints_are_closed_and_counted_once():
    fibers = bent_fiber()
    tubes = reference_tubes(fibers)
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(17)
    joints = fibers.points[1:-1].astype(np.float64)
    per_joint = 150
    targets = np.repeat(joints, per_joint, axis=0) + rng.normal(scale=0.03, size=(len(joints) * per_joint, 3))
    origins, directions = rays_toward(rng, targets)
    hits = intersect(bvh, origins, directions)
    t_ref, _, robust = reference_closest(tubes, origins, directions)

    origins, directions, hits, t_ref = origins[robust], directions[robust], hits["t"][robust], t_ref[robust]
    expected = union_entries(tubes, origins, directions)
    found = successive_entries(bvh, origins, directions)
    entered = 0
    for k, entries in enumerate(expected):
        if not entries:
            assert np.isinf(hits[k])
            continue
        entered += 1
        # Never a gap: a ray that enters the union of the mitred tubes hits it where it enters (the accuracy
        # of t is tested against the brute force above; here, that there is a hit and which one).
        assert t_ref[k] == pytest.approx(entries[0], abs=1e-9)
        assert hits[k] == pytest.approx(entries[0], abs=1e-4)
        # No double counting: each entry into the union is one hit, found again from the previous hit.
        np.testing.assert_allclose(found[k], entries, atol=1e-4)
    assert entered > per_joint


def test_a_ray_across_a_joint_perpendicular_to_the_bend_enters_once():
    points = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4 + 0.4 * np.cos(0.8), 0.4 * np.sin(0.8), 0.0]])
    fibers = FiberAssembly.from_strands([(points, 0.04)])
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(4)
    # Across the whole joint region, the outer corner of the mitre included.
    xy = points[1, :2] + rng.uniform(-0.06, 0.06, (2000, 2))
    origins = np.column_stack([xy, np.full(len(xy), 1.0)])
    down = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)
    expected = union_entries(reference_tubes(fibers), origins, down)
    found = successive_entries(bvh, origins, down)
    assert 0.3 < np.mean([len(e) for e in expected]) < 0.9
    for entries, hits in zip(expected, found):
        assert len(entries) <= 1
        np.testing.assert_allclose(hits, entries, atol=1e-4)


# --- open ends ---------------------------------------------------------------------------------------------------


def test_open_ends():
    fibers, _axis = straight_fiber(p0=(0.0, 0.0, 0.0), axis=(1, 0, 0), length=1.0, radius=0.05)
    bvh = FiberBVH(fibers)
    r = 0.05
    # Along the axis into the open end, on the axis and off it: the ray is inside the tube, no hit.
    origins = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.02, -0.03], [2.0, 0.0, 0.01]])
    directions = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    assert np.all(np.isinf(intersect(bvh, origins, directions)["t"]))
    # Into the open end at an angle, out through the side: an exit, not a hit.
    slanted = intersect(bvh, [[-1.0, 0.0, -0.1]], unit([[1.0, 0.0, 0.1]]))
    assert np.isinf(slanted["t"][0])
    # Across the tube just inside and just beyond each end plane.
    x = np.array([1e-3 * r, -1e-3 * r, 1 - 1e-3 * r, 1 + 1e-3 * r])
    origins = np.column_stack([x, np.zeros(4), np.full(4, 1.0)])
    hit = intersect(bvh, origins, np.broadcast_to([0.0, 0.0, -1.0], origins.shape))
    assert np.isfinite(hit["t"]).tolist() == [True, False, True, False]


def test_a_tilted_end_is_cut_perpendicular_to_its_segment():
    points = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5 + 0.5 * np.cos(0.5), 0.5 * np.sin(0.5), 0.0]])
    bvh = FiberBVH(FiberAssembly.from_strands([(points, 0.04)]))
    a = unit(points[2] - points[1])
    side = np.array([-a[1], a[0], 0.0])
    # Beside the tip, on both sides of the axis, just inside and just beyond the plane through it ⊥ a.
    offsets = np.array([0.03, -0.03, 0.03, -0.03])
    along = np.array([-1e-4, -1e-4, 1e-4, 1e-4])
    feet = points[2] + along[:, None] * a + offsets[:, None] * side
    hit = intersect(bvh, feet + [0.0, 0.0, 1.0], np.broadcast_to([0.0, 0.0, -1.0], feet.shape))
    assert np.isfinite(hit["t"]).tolist() == [True, True, False, False]


# --- t_max, occlusion, misses ------------------------------------------------------------------------------------


def test_t_max_and_occlusion_agree_with_the_closest_hit():
    fibers = tangle()
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(23)
    n = 3000
    lo, hi = bvh.bounds
    origins, directions = rays_toward(rng, rng.uniform(lo, hi, (n, 3)))
    closest = intersect(bvh, origins, directions)["t"]
    hit = np.isfinite(closest)
    assert 0.1 < hit.mean() < 0.9

    t_max = rng.uniform(1.0, 3.5, n)
    limited = intersect(bvh, origins, directions, t_max=t_max)["t"]
    away = np.abs(closest - t_max) > 1e-5
    np.testing.assert_array_equal(np.isfinite(limited)[away], (closest < t_max)[away])
    np.testing.assert_array_equal(limited[away & (closest < t_max)], closest[away & (closest < t_max)])

    np.testing.assert_array_equal(occluded(bvh, origins, directions), hit)
    np.testing.assert_array_equal(occluded(bvh, origins, directions, t_max=t_max)[away], (closest < t_max)[away])

    # Just short of and just past the closest hit.
    t = closest[hit]
    assert np.all(intersect(bvh, origins[hit], directions[hit], t_max=t * (1 - 1e-5))["segment"] == -1)
    np.testing.assert_array_equal(intersect(bvh, origins[hit], directions[hit], t_max=t * (1 + 1e-5))["t"], t)


@pytest.mark.parametrize("rule", ["enter", "exit"])
def test_the_preliminary_query_is_the_closest_hits_distance_and_segment(rule):
    """`distance` (the traversal alone, as Embree's closest-hit query) finds what `intersect` does, to the bit,
    with and without t_max, in a tangle whose rays start inside other strands' tubes."""
    bvh = FiberBVH(tangle())
    rng = np.random.default_rng(5)
    lo, hi = bvh.bounds
    origins, directions = rays_toward(rng, rng.uniform(lo, hi, (2000, 3)))
    for t_max in (np.inf, rng.uniform(0.5, 3.0, len(origins))):
        full = intersect(bvh, origins, directions, t_max=t_max, rule=rule, skip_strand=2)
        t, segment = distance(bvh, origins, directions, t_max=t_max, rule=rule, skip_strand=2)
        assert 0.1 < np.isfinite(t).mean() < 0.95
        np.testing.assert_array_equal(t, full["t"])
        np.testing.assert_array_equal(segment, full["segment"])


def test_misses():
    fibers, _ = straight_fiber()
    hit = intersect(FiberBVH(fibers), [[5.0, 5.0, 5.0], [0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    assert np.all(np.isinf(hit["t"]))
    assert hit["segment"].tolist() == [-1, -1] and hit["strand"].tolist() == [-1, -1]
    empty = FiberBVH(FiberAssembly.from_strands([]))
    assert np.isinf(intersect(empty, [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]])["t"][0])
    t, segment = distance(empty, [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]])
    assert np.isinf(t[0]) and segment[0] == -1
    assert not occluded(empty, [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]])[0]


# --- odd geometry ------------------------------------------------------------------------------------------------


def test_tapered_strands_are_stepped_tubes_of_the_mean_radius():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    bvh = FiberBVH(FiberAssembly.from_strands([(points, [0.06, 0.04, 0.02])]))
    origins = np.array([[0.5, 0.0, 1.0], [1.5, 0.0, 1.0]])
    hit = intersect(bvh, origins, [[0.0, 0.0, -1.0]] * 2)
    np.testing.assert_allclose(hit["position"][:, 2], [0.05, 0.03], atol=1e-6)


def test_zero_length_segments_and_hairpins_do_not_break_the_strand():
    # A repeated vertex, then a joint folded back by ~179°: both are cut like strand ends.
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.02, 0.0]])
    bvh = FiberBVH(FiberAssembly.from_strands([(points, 0.01)]))
    x = np.linspace(0.05, 1.95, 38)
    origins = np.column_stack([x, np.full_like(x, -0.003), np.ones_like(x)])
    hit = intersect(bvh, origins, np.broadcast_to([0.0, 0.0, -1.0], origins.shape))
    assert np.all(np.isfinite(hit["t"]))
    assert 1 not in hit["segment"]
    assert np.all(np.isfinite(bvh.bounds[0])) and np.all(np.isfinite(bvh.bounds[1]))


# --- the benchmark swatch ----------------------------------------------------------------------------------------


def test_benchmark_swatch_orthographic_grid():
    fibers = load_fibers(BENCH_FIBERS)
    bvh = FiberBVH(fibers)
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, 96), np.linspace(-0.5, 0.5, 96))
    origins = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 3.0)])
    down = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)
    hit = intersect(bvh, origins, down)
    hits = np.isfinite(hit["t"])
    # Four staggered layers leave only slivers between fibers uncovered.
    assert 0.95 < hits.mean() < 1.0
    assert np.all(np.abs(hit["h"][hits]) <= 1)
    p0, p1, r0, r1, strand, _ = fibers.segments()
    seg = hit["segment"][hits]
    a = unit(p1[seg].astype(np.float64) - p0[seg])
    rel = hit["position"][hits] - p0[seg]
    along = np.sum(rel * a, axis=1)
    radial = np.linalg.norm(rel - along[:, None] * a, axis=1)
    r = (r0[seg] + r1[seg]) / 2.0
    np.testing.assert_allclose(radial, r, rtol=1e-4)
    length = np.linalg.norm(p1[seg] - p0[seg], axis=1)
    assert np.all((along > -0.01) & (along < length + 0.01))
    np.testing.assert_array_equal(hit["strand"][hits], strand[seg])
    # The front layer (z ≈ 0) is what a camera on +z sees first.
    assert np.median(hit["position"][hits, 2]) > -0.01
    np.testing.assert_allclose(hit["position"][hits], origins[hits] + hit["t"][hits, None] * down[hits], atol=1e-5)


# --- the BVH -----------------------------------------------------------------------------------------------------


def check_tree(tree, lowers, uppers, max_leaf):
    """The invariants of warp_hair.geometry.bvh's layout: every primitive in exactly one leaf of at most max_leaf, every
    child box (float32) enclosing what lies below it, children numbered after their parents, the depth."""
    m = len(lowers)
    assert sorted(tree.order.tolist()) == list(range(m))
    covered = np.zeros(m, dtype=int)
    for k, (los, his, children) in enumerate(zip(tree.lo, tree.hi, tree.child)):
        for lo, hi, c in zip(los, his, children):
            if c >= 0:
                assert c > k and tree.level[c] == tree.level[k] + 1
                real = tree.child[c] != bvh_module.leaf_code(0, 0)
                assert np.all(lo <= tree.lo[c][real].min(axis=0)) and np.all(hi >= tree.hi[c][real].max(axis=0))
                continue
            start, count = bvh_module.leaf_range(c)
            if count == 0:  # an unused slot
                assert np.all(lo >= 1e29) and np.all(hi >= 1e29)
                continue
            assert count <= max_leaf
            inside = tree.order[start : start + count]
            covered[inside] += 1
            assert np.all(lo <= lowers[inside]) and np.all(hi >= uppers[inside])
    np.testing.assert_array_equal(covered, 1)
    if m:
        assert tree.depth == tree.level.max() + 1
        assert tree.depth <= -(-bvh_module.MAX_DEPTH // (tree.width.bit_length() - 1))


@pytest.mark.parametrize("width", [2, 4, 8])
@pytest.mark.parametrize("case", ["empty", "one", "two", "three", "random", "coincident", "geometric", "swatch"])
def test_bvh_layout(case, width):
    rng = np.random.default_rng(1)
    if case == "swatch":
        p0, p1, r0, r1, _, _ = load_fibers(BENCH_FIBERS).segments()
        lowers = np.minimum(p0, p1) - np.maximum(r0, r1)[:, None]
        uppers = np.maximum(p0, p1) + np.maximum(r0, r1)[:, None]
    elif case == "geometric":
        # Boxes at exponentially growing spacing and size, which the surface area heuristic splits into a
        # lopsided tree (depth ~30 for 2000 boxes): the depth bound must still hold.
        x = 1.03 ** np.arange(2000)
        lowers = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
        uppers = lowers + np.column_stack([0.2 * x, np.ones_like(x), np.ones_like(x)])
    else:
        m = {"empty": 0, "one": 1, "two": 2, "three": 3, "random": 300, "coincident": 40}[case]
        centres = rng.normal(size=(m, 3)) if case != "coincident" else np.zeros((m, 3))
        lowers, uppers = centres - rng.uniform(0.01, 0.2, (m, 3)), centres + rng.uniform(0.01, 0.2, (m, 3))
    for max_leaf in (1, 2, 4):
        tree = bvh_module.build_bvh(lowers, uppers, max_leaf=max_leaf, width=width)
        check_tree(tree, lowers, uppers, max_leaf)
        if width == BVH_WIDTH:
            assert stack_slots(tree.depth) <= STACK_SIZE


def agrees_with_the_brute_force(fibers, bvh, origins, directions, rng, hits=(0.2, 0.9, 0.2), min_sin=0.0):
    """Rays from outside and rays scattered from their hits: the closest hit and the shadow test agree with the
    float64 brute force. `hits`: the fraction of the rays from outside that hit lies between the first two, and
    that of the scattered rays between the third and the second."""
    tubes = reference_tubes(fibers)
    n = len(origins)
    first = intersect(bvh, origins, directions)
    on = np.isfinite(first["t"])
    scattered = unit(random_directions(rng, int(on.sum())).astype(np.float32))
    origins = np.concatenate([origins, first["position"][on].astype(np.float32)])
    directions = np.concatenate([directions, scattered])

    hit = intersect(bvh, origins, directions)
    blocked = occluded(bvh, origins, directions)
    t_ref, segment_ref, robust = reference_closest(tubes, origins, directions)
    # The module ignores a tube whose cylinder holds the origin within r·(1 + 1e-3) of its axis (the next tube
    # at a joint, or a crossing fiber, for a ray that starts on a surface), which the brute force does not
    # model: leave out rays whose brute-force hit is such a tube.
    seg = np.maximum(segment_ref, 0)
    a = tubes["a"][seg]
    w = origins - tubes["p0"][seg]
    radial = np.linalg.norm(w - np.sum(w * a, axis=1, keepdims=True) * a, axis=1) / tubes["r"][seg]
    robust &= ~((segment_ref >= 0) & (radial < 1 + 2e-3))
    # A ray within asin(min_sin) of its tube's axis enters the side where float32 rounding of its origin moves
    # the root by that rounding over sin θ: leave those out too where asked.
    robust &= np.linalg.norm(np.cross(directions, a), axis=1) > min_sin
    assert robust.mean() > 0.95
    assert hits[0] < np.isfinite(t_ref[:n]).mean() < hits[1]
    assert hits[2] < np.isfinite(t_ref[n:]).mean() < hits[1]
    np.testing.assert_array_equal(blocked, np.isfinite(hit["t"]))
    np.testing.assert_array_equal(np.isfinite(hit["t"])[robust], np.isfinite(t_ref)[robust])
    both = robust & np.isfinite(t_ref)
    np.testing.assert_array_equal(hit["segment"][both], segment_ref[both])
    np.testing.assert_allclose(hit["t"][both], t_ref[both], atol=1e-4)


def test_many_tubes_agree_with_the_float64_brute_force():
    """Rays from outside and rays scattered from the hits, on enough tubes for a BVH several levels deep: the
    closest hit and the shadow test agree with the brute force."""
    fibers = wavy(count=40, layers=2, length=0.4, radius=0.01, amplitude=0.03, wavelength=0.4, phase_jitter=1.0, seed=5)
    bvh = FiberBVH(fibers)
    rng = np.random.default_rng(31)
    lo, hi = bvh.bounds
    origins, directions = rays_toward(rng, rng.uniform(lo, hi, (1500, 3)))
    agrees_with_the_brute_force(fibers, bvh, origins, directions, rng)


def test_an_unbalanced_tree_agrees_with_the_float64_brute_force():
    """Strands at exponentially growing spacing: a lopsided tree, deeper on one side than on the other."""
    x = 0.05 * 1.04 ** np.arange(150)
    strands = [(np.array([[xi, -0.5, 0.0], [xi, 0.0, 0.02], [xi, 0.5, 0.0]]), 0.01) for xi in x]
    fibers = FiberAssembly.from_strands(strands)
    bvh = FiberBVH(fibers)
    tubes = reference_tubes(fibers)
    rng = np.random.default_rng(8)
    n = 2000
    targets = np.column_stack(
        [rng.choice(x, n) + rng.normal(scale=0.01, size=n), rng.uniform(-0.6, 0.6, n), rng.normal(scale=0.01, size=n)]
    )
    origins, directions = rays_toward(rng, targets, distance=1.0)
    hit = intersect(bvh, origins, directions)
    t_ref, segment_ref, robust = reference_closest(tubes, origins, directions)
    assert robust.mean() > 0.95 and np.isfinite(t_ref).mean() > 0.3
    np.testing.assert_array_equal(np.isfinite(hit["t"])[robust], np.isfinite(t_ref)[robust])
    both = robust & np.isfinite(t_ref)
    np.testing.assert_array_equal(hit["segment"][both], segment_ref[both])
    np.testing.assert_array_equal(occluded(bvh, origins, directions), np.isfinite(hit["t"]))


# --- the shading frame ------------------------------------------------------------------------------------------


def arc_fiber(segments=12, bend=np.pi / 2, curve_radius=1.0, radius=0.02):
    """A strand on a circle of curve_radius in the x-y plane (centre at the origin), root at angle 0."""
    angles = np.linspace(0.0, bend, segments + 1)
    points = curve_radius * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    return FiberAssembly.from_strands([(points, radius)]), bend / segments


def rays_down_onto_the_arc(n, first, last, curve_radius=1.0):
    """Rays along −z onto the arc, at angles spread from first to last."""
    angles = np.linspace(first, last, n)
    targets = curve_radius * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    origins = targets + [0.0, 0.0, 1.0]
    return origins, np.tile([0.0, 0.0, -1.0], (n, 1))


def test_shading_tangent_follows_the_curve_and_is_continuous_at_joints():
    """On a polyline through a circle, the shading tangent at a hit is within a small fraction of the
    segments' turn of the circle's own tangent there, where the segment axis is up to half a turn off; along
    the strand it turns smoothly, without a step at the joints. (The end segments, whose outer vertex has
    only the segment's own axis as its tangent, are left out.)"""
    fibers, turn = arc_fiber()
    origins, directions = rays_down_onto_the_arc(2000, turn, np.pi / 2 - turn)
    hit = intersect(FiberBVH(fibers), origins, directions)
    assert np.all(hit["segment"] >= 0)
    angle = np.arctan2(hit["position"][:, 1], hit["position"][:, 0])
    circle_tangent = np.stack([-np.sin(angle), np.cos(angle), np.zeros_like(angle)], axis=1)

    def error(t):
        return np.arccos(np.clip(np.einsum("ij,ij->i", unit(t), circle_tangent), -1.0, 1.0))

    assert error(hit["tangent"]).max() > 0.45 * turn  # the polyline's own axis: half a turn off at the joints
    assert error(hit["shading_tangent"]).max() < 0.02 * turn
    # Neighbouring rays are 1/2000 of the arc apart: the tangent moves by about that, never by a joint's step.
    steps = np.arccos(np.clip(np.einsum("ij,ij->i", hit["shading_tangent"][1:], hit["shading_tangent"][:-1]), -1, 1))
    assert steps.max() < 3.0 * (np.pi / 2 - 2 * turn) / 2000

    flat = intersect(FiberBVH(fibers, smooth_tangents=False), origins, directions)
    np.testing.assert_allclose(flat["shading_tangent"], flat["tangent"], atol=1e-6)


def test_shading_frame_is_orthonormal_and_h_is_its_cos_phi():
    """x ⊥ z, both unit, z the cylinder normal turned only as far as x requires, and h = −cos φ_o in that frame
    (docs/MODEL.md: the BSDF assumes frame and offset agree)."""
    rng = np.random.default_rng(11)
    fibers = wavy(count=12, layers=2, length=0.6, radius=0.01, amplitude=0.03, wavelength=0.15, seed=4)
    lo, hi = fibers.points.min(axis=0), fibers.points.max(axis=0)
    targets = lo + rng.random((4000, 3)) * (hi - lo)
    origins, directions = rays_toward(rng, targets)
    hit = intersect(FiberBVH(fibers), origins, directions)
    got = hit["segment"] >= 0
    assert got.sum() > 500
    x, z, d = hit["shading_tangent"][got], hit["shading_normal"][got], unit(directions[got])
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(z, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.einsum("ij,ij->i", x, z), 0.0, atol=1e-5)
    # z stays in the plane of the cylinder normal and x.
    n = hit["normal"][got]
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(n, x), z), 0.0, atol=1e-5)
    y = np.cross(z, x)
    wo_y, wo_z = -np.einsum("ij,ij->i", d, y), -np.einsum("ij,ij->i", d, z)
    np.testing.assert_allclose(hit["shading_h"][got], -wo_y / np.hypot(wo_y, wo_z), atol=2e-5)


def test_straight_strands_shade_with_their_own_axis():
    fibers, _ = straight_fiber()
    rng = np.random.default_rng(3)
    origins, directions = rays_toward(rng, fibers.points.mean(axis=0) + rng.normal(0, 0.02, (500, 3)))
    hit = intersect(FiberBVH(fibers), origins, directions)
    got = hit["segment"] >= 0
    assert got.sum() > 100
    np.testing.assert_allclose(hit["shading_tangent"][got], hit["tangent"][got], atol=1e-6)
    np.testing.assert_allclose(hit["shading_normal"][got], hit["normal"][got], atol=1e-6)
    np.testing.assert_allclose(hit["shading_h"][got], hit["h"][got], atol=1e-5)


def slanted_strands(rng, count=30, segments=4, step=0.3, radius=0.002):
    """Thin strands of few long segments running across the axes, bent 20–40° at each joint: a sparse groom."""
    strands = []
    for _ in range(count):
        direction = random_directions(rng, 1)[0]
        points = [rng.uniform(-0.5, 0.5, 3)]
        for _ in range(segments):
            u, v = perpendicular_basis(direction)
            bend = np.radians(rng.uniform(20.0, 40.0))
            spin = rng.uniform(0.0, 2 * np.pi)
            direction = unit(np.cos(bend) * direction + np.sin(bend) * (np.cos(spin) * u + np.sin(spin) * v))
            points.append(points[-1] + step * direction)
        strands.append((np.array(points), radius))
    return FiberAssembly.from_strands(strands)


def test_pieces_of_long_slanted_segments_hold_their_tube():
    """`segment_pieces` cuts long segments that run across the axes into references with smaller boxes; every
    point of each clipped tube (its surface, sampled in float64) lies in one of its segment's pieces' boxes."""
    fibers = slanted_strands(np.random.default_rng(4))
    p0, p1, r0, r1, strand, _ = fibers.segments()
    seg = segment_frames(p0, p1, r0, r1, strand)
    lowers, uppers = segment_boxes(seg)
    reference, lo, hi = segment_pieces(seg, lowers, uppers)
    assert len(reference) > 2 * len(lowers)  # most of these segments are cut
    assert np.all(np.prod(hi - lo, axis=1) <= np.prod(uppers - lowers, axis=1)[reference] * (1 + 1e-12))
    rng = np.random.default_rng(5)
    for i in range(len(lowers)):
        a, r = seg["axis"][i], seg["radius"][i]
        u, v = perpendicular_basis(a)
        along = rng.uniform(-0.1, 1.1, 4000) * np.linalg.norm(seg["p1"][i] - seg["p0"][i])
        spin = rng.uniform(0.0, 2 * np.pi, 4000)
        points = seg["p0"][i] + along[:, None] * a + r * (np.cos(spin)[:, None] * u + np.sin(spin)[:, None] * v)
        w = points - seg["center"][i]
        inside = (w @ seg["mitre0"][i] >= seg["clip"][i, 0]) & (w @ seg["mitre1"][i] >= seg["clip"][i, 1])
        mine = reference == i
        held = np.any(
            np.all((points[inside, None] >= lo[mine][None]) & (points[inside, None] <= hi[mine][None]), axis=2), axis=1
        )
        assert inside.sum() > 3000 and held.all(), i


def test_long_slanted_segments_agree_with_the_float64_brute_force():
    """The same sparse groom through the traversal, its segments held as pieces: the closest hit and the shadow
    test agree with the brute force, for rays from outside and rays scattered from the hits."""
    fibers = slanted_strands(np.random.default_rng(6))
    tubes = reference_tubes(fibers)
    bvh = FiberBVH(fibers)
    assert bvh.geometry.tubes.shape[0] > 2 * bvh.num_segments
    rng = np.random.default_rng(7)
    n = 1500
    # Rays toward points on the tubes' axes from every direction, so that most of them hit: a few run within 3°
    # of an axis.
    pick = rng.integers(0, len(tubes["p0"]), n)
    targets = tubes["p0"][pick] + rng.uniform(0, 1, (n, 1)) * (tubes["p1"] - tubes["p0"])[pick]
    origins, directions = rays_toward(rng, targets)
    # A sparse groom: most rays from outside hit, few scattered from the hits find another strand.
    agrees_with_the_brute_force(fibers, bvh, origins, directions, rng, hits=(0.5, 1.0, 0.01), min_sin=0.05)
