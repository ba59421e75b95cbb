"""Fiber geometry: strands of hair or fur as polylines with a radius per vertex.

`FiberAssembly` is the container the renderer reads. Files load and save with `load_fibers` / `save_fibers`
(Cem Yuksel's binary `.hair`, the plain-text `x y z radius` format of Mitsuba 3's `linearcurve`, and USD
BasisCurves through `warp_hair.usd`), and
`swatch`, `wavy`, `curly` and `fur` build procedural test geometry. Plain NumPy throughout.

Every strand is listed root first, in files (as `.hair`, Mitsuba's curve text and USD BasisCurves list them)
and in the generators: the cuticle tilt α shifts the primary highlight toward a strand's first vertex, so a
strand listed tip first would show it on the wrong side.
"""

from __future__ import annotations

import math
import operator
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import validate
from .usd import SUFFIXES as USD_SUFFIXES


class FiberDataError(ValueError):
    """Invalid fiber data, located by file, line, strand and vertex as far as they are known.

    `strand` and `vertex` are 0-based (`vertex` counts within its strand); `line` is 1-based.
    """

    def __init__(self, problem, *, strand=None, vertex=None, source=None, line=None):
        self.problem = problem
        self.strand = strand
        self.vertex = vertex
        self.source = source
        self.line = line
        super().__init__(self._message())

    def _message(self):
        parts = []
        if self.source is not None:
            parts.append(str(self.source))
        if self.line is not None:
            parts.append(f"line {self.line}")
        if self.strand is not None:
            vertex = "" if self.vertex is None else f", vertex {self.vertex}"
            parts.append(f"strand {self.strand}{vertex}")
        parts.append(self.problem)
        return ": ".join(parts)

    def located(self, *, source=None, line=None):
        """The same error with the file and/or line filled in."""
        return FiberDataError(
            self.problem,
            strand=self.strand,
            vertex=self.vertex,
            source=self.source if source is None else source,
            line=self.line if line is None else line,
        )


class FiberAssembly:
    """A set of strands, each a polyline of at least two vertices with a radius per vertex.

    Stored flat: `points` (V, 3) float32, `radii` (V,) float32 and `strand_offsets` (S+1,) int64, strand k
    owning vertices `strand_offsets[k]:strand_offsets[k+1]`. The arrays are private read-only copies, so an
    assembly stays valid once built; copy them to edit and build a new assembly.

    Construction checks every strand (at least 2 vertices, finite points, finite radii > 0) and raises
    `FiberDataError` (a ValueError) naming the first bad strand; `source` (a file name) prefixes the message.
    """

    def __init__(self, points, radii, strand_offsets, *, source=None):
        # Values beyond float32 range become inf here, which the checks below report by strand.
        with np.errstate(over="ignore"):
            self.points = _frozen(np.array(points, dtype=np.float32))
            self.radii = _frozen(np.array(radii, dtype=np.float32))
        self.strand_offsets = _frozen(_as_offsets(strand_offsets, source))
        _check_shapes(self.points, self.radii, self.strand_offsets, source)
        _check_strands(self.points, self.radii, self.strand_offsets, source)

    @classmethod
    def from_arrays(cls, points, radii, *, source=None):
        """Strands of equal vertex count: `points` (S, N, 3); `radii` a scalar, (S,) per strand or (S, N)."""
        with np.errstate(over="ignore"):  # beyond float32 range: inf, which construction reports by strand
            points = np.asarray(points, dtype=np.float32)
        if points.ndim != 3 or points.shape[2] != 3:
            raise FiberDataError(f"points must have shape (S, N, 3), got {points.shape}", source=source)
        strands, per_strand = points.shape[:2]
        radii = np.asarray(radii, dtype=np.float32)
        if radii.ndim == 1:
            radii = radii[:, None]
        radii = np.broadcast_to(radii, (strands, per_strand))
        offsets = np.arange(strands + 1, dtype=np.int64) * per_strand
        return cls(points.reshape(-1, 3), radii.reshape(-1), offsets, source=source)

    @classmethod
    def from_strands(cls, strands, *, source=None):
        """Strands of any vertex counts, from an iterable of (points (n, 3), radii (n,) or scalar) pairs."""
        points, radii = [], []
        for strand_points, strand_radii in strands:
            strand_points = np.asarray(strand_points, dtype=np.float32).reshape(-1, 3)
            points.append(strand_points)
            radii.append(np.broadcast_to(np.asarray(strand_radii, dtype=np.float32), len(strand_points)))
        counts = [len(p) for p in points]
        offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
        if not points:
            return cls(np.zeros((0, 3)), np.zeros(0), offsets, source=source)
        return cls(np.concatenate(points), np.concatenate(radii), offsets, source=source)

    @classmethod
    def concatenate(cls, assemblies):
        """One assembly holding the strands of all `assemblies`, in order."""
        assemblies = list(assemblies)
        if not assemblies:
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(1, dtype=np.int64))
        starts = np.cumsum([0] + [a.num_vertices for a in assemblies[:-1]])
        offsets = [np.zeros(1, dtype=np.int64)]
        offsets += [a.strand_offsets[1:] + start for a, start in zip(assemblies, starts)]
        return cls(
            np.concatenate([a.points for a in assemblies]),
            np.concatenate([a.radii for a in assemblies]),
            np.concatenate(offsets),
        )

    @property
    def num_strands(self):
        return len(self.strand_offsets) - 1

    @property
    def num_vertices(self):
        return len(self.points)

    @property
    def num_segments(self):
        return self.num_vertices - self.num_strands

    @property
    def vertex_counts(self):
        """(S,) int64: the number of vertices of each strand."""
        return np.diff(self.strand_offsets)

    def strand(self, k):
        """(points (n, 3), radii (n,)) of strand k (negative k counts from the end), as read-only views."""
        k = operator.index(k)
        if k < 0:
            k += self.num_strands
        if not 0 <= k < self.num_strands:
            raise IndexError(f"strand index {k} out of range for {self.num_strands} strands")
        start, stop = self.strand_offsets[k], self.strand_offsets[k + 1]
        return self.points[start:stop], self.radii[start:stop]

    def segments(self):
        """Every segment of every strand, in strand order: (p0, p1, r0, r1, strand_id, index_in_strand).

        p0, p1 are (M, 3) float32 end points, r0, r1 (M,) float32 end radii, strand_id (M,) int32 the strand
        each segment belongs to and index_in_strand (M,) int32 its position along that strand (0 at the root).
        """
        first = self._segment_start_vertices()
        strand_id = np.repeat(np.arange(self.num_strands, dtype=np.int32), self.vertex_counts - 1)
        index_in_strand = (first - self.strand_offsets[strand_id]).astype(np.int32)
        return (
            self.points[first],
            self.points[first + 1],
            self.radii[first],
            self.radii[first + 1],
            strand_id,
            index_in_strand,
        )

    def _segment_start_vertices(self):
        # Every vertex starts a segment except the last vertex of each strand.
        starts = np.ones(self.num_vertices, dtype=bool)
        starts[self.strand_offsets[1:] - 1] = False
        return np.flatnonzero(starts)

    def bounds(self):
        """(lo (3,), hi (3,)) float32: the axis-aligned box holding every vertex sphere (radii included)."""
        if self.num_vertices == 0:
            raise ValueError("an empty fiber assembly has no bounds")
        radii = self.radii[:, None]
        return (self.points - radii).min(axis=0), (self.points + radii).max(axis=0)

    def __len__(self):
        return self.num_strands

    def __repr__(self):
        return (
            f"FiberAssembly({self.num_strands} strands, {self.num_vertices} vertices, "
            f"{self.num_segments} segments)"
        )


def _frozen(array):
    array.flags.writeable = False
    return array


def _as_offsets(strand_offsets, source):
    offsets = np.asarray(strand_offsets)
    if offsets.dtype.kind not in "iu":
        raise FiberDataError(f"strand_offsets must be integers, got dtype {offsets.dtype}", source=source)
    return offsets.astype(np.int64)


def _check_shapes(points, radii, offsets, source):
    if points.ndim != 2 or points.shape[1] != 3:
        raise FiberDataError(f"points must have shape (V, 3), got {points.shape}", source=source)
    if radii.shape != (len(points),):
        raise FiberDataError(f"radii must have shape ({len(points)},), got {radii.shape}", source=source)
    if offsets.ndim != 1 or len(offsets) == 0 or offsets[0] != 0 or offsets[-1] != len(points):
        raise FiberDataError(
            f"strand_offsets must run from 0 to the vertex count {len(points)}, got {offsets[:3]}..{offsets[-3:]}",
            source=source,
        )


def _check_strands(points, radii, offsets, source):
    counts = np.diff(offsets)
    short = np.flatnonzero(counts < 2)
    if short.size:
        k = int(short[0])
        vertices = "vertex" if counts[k] == 1 else "vertices"
        raise FiberDataError(f"has {counts[k]} {vertices}; a strand needs at least 2", strand=k, source=source)
    checks = (
        (~np.isfinite(points).all(axis=1), lambda v: f"position ({', '.join(map(str, points[v]))}) is not finite"),
        (~np.isfinite(radii), lambda v: f"radius {radii[v]!s} is not finite"),
        (~(radii > 0), lambda v: f"radius {radii[v]!s} is not positive"),
    )
    for bad, describe in checks:
        hits = np.flatnonzero(bad)
        if hits.size:
            _raise_at(int(hits[0]), describe(int(hits[0])), offsets, source)
    beyond = validate.fiber_values(points, radii)
    if beyond is not None:
        _raise_at(*beyond, offsets, source)


def _raise_at(v, problem, offsets, source):
    k = int(np.searchsorted(offsets, v, side="right") - 1)
    raise FiberDataError(problem, strand=k, vertex=v - int(offsets[k]), source=source)


# ---------------------------------------------------------------------------------------------------------------
# Files


def load_fibers(path, **options):
    """Load a fiber file, choosing the format by extension: `.hair` (Cem Yuksel's binary), `.txt` (text), or a USD
    stage (`.usd`, `.usda`, `.usdc`: BasisCurves, `warp_hair.usd`, which takes `options` prim, radius, segments)."""
    path = Path(path)
    if path.suffix.lower() in USD_SUFFIXES:
        from .usd import read_usd

        return read_usd(path, **options)
    if options:
        raise ValueError(f"{path}: {', '.join(sorted(options))} apply to USD files only")
    return _format_for(path)[0](path)


def save_fibers(assembly, path):
    """Save `assembly`, choosing the format by extension: `.hair`, `.txt`, or USD (linear BasisCurves)."""
    path = Path(path)
    if path.suffix.lower() in USD_SUFFIXES:
        from .usd import write_usd

        return write_usd(assembly, path)
    _format_for(path)[1](assembly, path)


def _format_for(path):
    formats = {".hair": (read_hair, write_hair), ".txt": (read_text, write_text)}
    try:
        return formats[path.suffix.lower()]
    except KeyError:
        known = ", ".join([*formats, *USD_SUFFIXES])
        raise ValueError(f"{path}: unknown fiber file extension {path.suffix!r}; expected one of {known}") from None


# Cem Yuksel's .hair header, little-endian, 128 bytes: signature, strand count, point count, array flags,
# default segment count, default thickness, default transparency, default colour (3), info string.
_HAIR_HEADER = struct.Struct("<4s4I5f88s")
_HAIR_SIGNATURE = b"HAIR"
_HAS_SEGMENTS, _HAS_POINTS, _HAS_THICKNESS, _HAS_TRANSPARENCY, _HAS_COLOUR = 1, 2, 4, 8, 16
# The per-point arrays in file order: (flag, name, float32 values per point).
_HAIR_POINT_ARRAYS = (
    (_HAS_POINTS, "points", 3),
    (_HAS_THICKNESS, "thickness", 1),
    (_HAS_TRANSPARENCY, "transparency", 1),
    (_HAS_COLOUR, "colour", 3),
)
_HAIR_MAX_SEGMENTS = int(np.iinfo(np.uint16).max)
_HAIR_INFO_BYTES = 88


def read_hair(path):
    """Load a Cem Yuksel `.hair` file (the format of the hair models in pbrt's and Mitsuba's example scenes).

    The file's thickness is the fiber DIAMETER: the returned radii are thickness / 2. Absent segment or
    thickness arrays take the header's defaults. Transparency and colour arrays are checked but not kept.
    A malformed file raises `FiberDataError` (a ValueError) naming the file and, where it applies, the strand;
    so do bytes after the declared arrays (a file whose header does not describe its data).
    """
    path = Path(path)
    return _parse_hair(path.read_bytes(), path)


def write_hair(assembly, path, *, info="warp-hair"):
    """Save `assembly` as a Cem Yuksel `.hair` file with segments, points and thickness arrays.

    Thickness is written as the fiber DIAMETER, 2 × radius (exact in float32, so a round trip is lossless).
    The format counts segments in uint16: a strand may have at most 65535 segments. `info` fills the header's
    88-byte comment (ASCII, cut to 87 bytes to keep a terminating NUL).
    """
    path = Path(path)
    segments = assembly.vertex_counts - 1
    too_long = np.flatnonzero(segments > _HAIR_MAX_SEGMENTS)
    if too_long.size:
        k = int(too_long[0])
        raise FiberDataError(
            f"has {segments[k]} segments; a .hair file holds at most {_HAIR_MAX_SEGMENTS} per strand",
            strand=k,
            source=path,
        )
    header = _HAIR_HEADER.pack(
        _HAIR_SIGNATURE,
        assembly.num_strands,
        assembly.num_vertices,
        _HAS_SEGMENTS | _HAS_POINTS | _HAS_THICKNESS,
        int(segments[0]) if segments.size else 0,
        float(2 * assembly.radii[0]) if assembly.num_vertices else 0.0,
        0.0,
        1.0,
        1.0,
        1.0,
        info.encode("ascii", "replace")[: _HAIR_INFO_BYTES - 1],
    )
    with open(path, "wb") as f:
        f.write(header)
        f.write(segments.astype("<u2").tobytes())
        f.write(assembly.points.astype("<f4").tobytes())
        f.write((assembly.radii * np.float32(2)).astype("<f4").tobytes())


class _HairHeader(NamedTuple):
    strands: int
    points: int
    flags: int
    default_segments: int
    default_thickness: float


def _parse_hair(data, source):
    header = _read_hair_header(data, source)
    ends, position = _hair_strand_ends(data, header, source)
    arrays = _read_hair_point_arrays(data, position, header, ends, source)
    end = position + sum(4 * width * header.points for flag, _, width in _HAIR_POINT_ARRAYS if header.flags & flag)
    if len(data) > end:
        # Bytes the header does not account for mean a header that disagrees with its data: refuse to guess.
        raise FiberDataError(
            f"{len(data) - end} bytes after the data the header declares ({end} bytes); the header's counts or "
            "flags do not describe this file",
            source=source,
        )
    thickness = arrays.get("thickness")
    if thickness is None:
        thickness = np.full(header.points, header.default_thickness, dtype=np.float32)
    offsets = np.concatenate([np.zeros(1, dtype=np.int64), ends])
    return FiberAssembly(arrays["points"], thickness * np.float32(0.5), offsets, source=source)


def _read_hair_header(data, source):
    if len(data) < _HAIR_HEADER.size:
        raise FiberDataError(
            f"truncated: {len(data)} bytes, shorter than the {_HAIR_HEADER.size}-byte .hair header", source=source
        )
    signature, strands, points, flags, segments, thickness, *_ = _HAIR_HEADER.unpack_from(data)
    if signature != _HAIR_SIGNATURE:
        raise FiberDataError(
            f"bad signature {signature!r}: a .hair file starts with {_HAIR_SIGNATURE!r}", source=source
        )
    if not flags & _HAS_POINTS:
        raise FiberDataError("the header declares no points array (flag bit 1 clear)", source=source)
    return _HairHeader(strands, points, flags, segments, thickness)


def _hair_strand_ends(data, header, source):
    """(the index one past each strand's last point (S,) int64, byte position after the segments array)."""
    position = _HAIR_HEADER.size
    if header.flags & _HAS_SEGMENTS:
        end = position + 2 * header.strands
        if len(data) < end:
            raise _truncated("segments", end, len(data), (len(data) - position) // 2, source)
        counts = np.frombuffer(data, dtype="<u2", count=header.strands, offset=position).astype(np.int64) + 1
        ends = np.cumsum(counts)
        _check_point_total(ends, header.points, source)
        return ends, end
    per_strand = header.default_segments + 1
    # Checked before allocating anything: a corrupt header may promise billions of strands.
    last_end = header.strands * per_strand
    if last_end > header.points:
        first_past = header.points // per_strand
        raise _point_count_error(first_past, (first_past + 1) * per_strand, header.points, source)
    if last_end < header.points:
        raise _point_count_error(header.strands - 1 if header.strands else None, last_end, header.points, source)
    fitting = (len(data) - position) // 12
    if fitting < header.points:
        raise _truncated("points", position + 12 * header.points, len(data), fitting // per_strand, source)
    return np.arange(1, header.strands + 1, dtype=np.int64) * per_strand, position


def _check_point_total(ends, points, source):
    total = int(ends[-1]) if ends.size else 0
    if total > points:
        first_past = int(np.searchsorted(ends, points, side="right"))
        raise _point_count_error(first_past, int(ends[first_past]), points, source)
    if total < points:
        raise _point_count_error(len(ends) - 1 if ends.size else None, total, points, source)


def _point_count_error(strand, end, points, source):
    if strand is None:
        return FiberDataError(f"the header promises {points} points but no strands", source=source)
    relation = "past" if end > points else "short of"
    return FiberDataError(
        f"the strand ends at point {end}, {relation} the header's point count {points}", strand=strand, source=source
    )


def _truncated(array, needed, size, strand, source):
    return FiberDataError(
        f"truncated: the file ends inside the {array} array (the header promises {needed} bytes, found {size})",
        strand=strand,
        source=source,
    )


def _read_hair_point_arrays(data, position, header, ends, source):
    arrays = {}
    for flag, name, width in _HAIR_POINT_ARRAYS:
        if not header.flags & flag:
            continue
        size = 4 * width * header.points
        if len(data) < position + size:
            complete = (len(data) - position) // (4 * width)
            strand = int(np.searchsorted(ends, complete, side="right"))
            raise _truncated(name, position + size, len(data), strand, source)
        values = np.frombuffer(data, dtype="<f4", count=width * header.points, offset=position)
        arrays[name] = values.reshape(-1, width) if width > 1 else values
        position += size
    return arrays


def read_text(path):
    """Load the plain-text fiber format (Mitsuba 3's `linearcurve` files use it).

    One `x y z radius` line per vertex, a blank line between strands; lines starting with `#` are comments.
    UTF-8, with or without a byte-order mark. A malformed file raises `FiberDataError` (a ValueError) naming the file, line and strand.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise FiberDataError(f"not a UTF-8 text file (byte {error.start}: {error.reason})", source=path) from None
    return _parse_text(text, path)


def write_text(assembly, path):
    """Save `assembly` in the plain-text format: one `x y z radius` line per vertex, a blank line between
    strands, and nothing else, so that Mitsuba 3's `linearcurve` and `bsplinecurve` load the file too (their
    parser takes no comment lines). Values are written with 9 significant digits, which round-trips float32
    exactly."""
    row = "%.9g %.9g %.9g %.9g\n"
    # One format string for the whole file: formatting it in one call is several times faster than per row.
    template = [row] * assembly.num_vertices
    for last in assembly.strand_offsets[1:-1] - 1:
        template[last] = row + "\n"
    values = np.column_stack([assembly.points, assembly.radii]).ravel().tolist()
    Path(path).write_text("".join(template) % tuple(values), encoding="utf-8")


def _parse_text(text, source):
    lines = [line.strip() for line in text.splitlines()]
    blank = np.fromiter((not line for line in lines), dtype=bool, count=len(lines))
    is_data = np.fromiter((bool(line) and line[0] != "#" for line in lines), dtype=bool, count=len(lines))
    data_rows = np.flatnonzero(is_data)
    # A data line starts a new strand when a blank line lies between it and the previous data line.
    blanks_before = np.cumsum(blank)[data_rows]
    starts = np.ones(len(data_rows), dtype=bool)
    starts[1:] = np.diff(blanks_before) > 0
    strand_of_row = np.cumsum(starts) - 1
    values = _read_text_values([lines[row] for row in data_rows], data_rows, strand_of_row, source)
    offsets = np.concatenate([[0], np.cumsum(np.bincount(strand_of_row))]).astype(np.int64)
    try:
        return FiberAssembly(values[:, :3], values[:, 3], offsets, source=source)
    except FiberDataError as error:
        if error.strand is None:
            raise
        row = data_rows[offsets[error.strand] + (error.vertex or 0)]
        raise error.located(line=int(row) + 1) from None


def _read_text_values(data_lines, data_rows, strand_of_row, source):
    """(V, 4) float64 from the data lines, or a FiberDataError naming the first bad line."""
    if not data_lines:
        return np.zeros((0, 4))
    values = _parse_rows(data_lines)
    if values is not None:
        return values
    j = _first_unreadable(data_lines)
    tokens = data_lines[j].split()
    quoted = repr(data_lines[j][:80])
    if len(tokens) != 4:
        problem = f"expected 4 numbers 'x y z radius', found {len(tokens)}: {quoted}"
    else:
        problem = f"cannot read {quoted} as 4 numbers 'x y z radius'"
    raise FiberDataError(problem, line=int(data_rows[j]) + 1, strand=int(strand_of_row[j]), source=source)


def _parse_rows(lines):
    """(n, 4) float64 when every line holds 4 numbers, else None."""
    try:
        values = np.loadtxt(lines, dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    return values if values.shape[1] == 4 else None


def _first_unreadable(lines):
    # Bisection keeps the search as fast as one parse of the whole file, even for a bad last line.
    lo, hi = 0, len(lines)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _parse_rows(lines[lo:mid]) is None:
            hi = mid
        else:
            lo = mid
    return lo


# ---------------------------------------------------------------------------------------------------------------
# Generators
#
# Scene units throughout. The swatch generators lay fibers along +y in the x–y plane, facing +z and centred on
# the origin, and order the strands layer by layer (layer 0, the front one, first), left to right in a layer.

# A swatch fiber wanders sideways by up to this fraction of jitter × spacing. With the ±jitter/2 root jitter,
# neighbours in a layer then stay at least spacing × (1 − (1 + 2·_WANDER)·jitter) apart.
_WANDER = 0.125
# Above this the jitter could push fiber axes past the documented width of the swatch.
_MAX_JITTER = 0.4
# The default spacing is this much more than the spacing at which neighbours could just touch, so that
# float32 rounding never makes them overlap.
_SPACING_MARGIN = 1.05


def swatch(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    spacing=None,
    jitter=0.25,
    segments=8,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
):
    """A flat swatch of straight, parallel fibers, like a hair swatch card.

    Fibers run along +y from their roots at y = −length/2 to their tips at +length/2 and spread across x, in `layers` layers stacked
    towards −z: layer k lies near z = −k·layer_gap, so layer 0 (at z = 0) faces a camera on +z. Odd layers are
    offset by half a spacing to cover the gaps between the fibers of even ones, so the swatch has no
    see-through gaps. Strands are ordered layer by layer, left to right; when `layers` does not divide
    `count`, the first `count % layers` layers hold one fiber more.

    Args:
        count: number of fibers.
        layers: number of layers, 1 to `count`.
        length: fiber length along y, scene units.
        radius: fiber radius, scene units, the same at every vertex.
        spacing: distance between neighbouring fiber axes within a layer, scene units. Default: from `width`
            when given (width / fibers per layer), else 2.1·radius / (1 − 1.25·jitter), just over the spacing
            at which neighbours in a layer could touch (0.0122 with the other defaults).
        jitter: irregularity as a fraction of `spacing`, in [0, 0.4]: each fiber moves by up to ±jitter/2 ×
            spacing in x and in z, and wanders sideways (x) along its length by up to ±jitter/8 × spacing.
        segments: straight segments per fiber (segments + 1 vertices, evenly spaced in y).
        width: extent of the swatch across x, scene units: every fiber axis stays within |x| ≤ width/2.
            Default: spacing × fibers per layer (1.95 with the other defaults). Give `spacing` or `width`, not
            both.
        seed: seed of the NumPy random generator; a seed always gives the same swatch.
        layer_gap: distance between neighbouring layers along z, scene units. Default: 2·radius +
            jitter·spacing, at which fibers of different layers never touch.
        drape: radius of a cylinder (axis along x, top at z = 0) to lay the swatch over, scene units, above
            length / π; default flat. Shows the highlight band of swatch photographs (see `_swatch_assembly`).

    With the default spacing and layer gap no two fibers intersect. A smaller spacing, or a `width` that
    implies one, packs them tighter and lets neighbours overlap.
    """
    _check_size(count, segments)
    rng = np.random.default_rng(seed)
    y = _heights(length, segments)
    x, z = _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng)
    return _swatch_assembly(x, y, z, radius, drape)


def wavy(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    amplitude=0.02,
    wavelength=0.2,
    phase_jitter=0.15,
    spacing=None,
    jitter=0.25,
    segments=None,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
):
    """A swatch of wavy fibers: the fibers of `swatch`, each swinging in x as amplitude·sin(2π·y/wavelength + phase).

    Args:
        count, layers, length, radius, spacing, jitter, width, seed, layer_gap, drape: as for `swatch` (fiber axes
            reach up to `amplitude` beyond its width; `length` is the extent along y, not the arc length).
        amplitude: half the peak-to-peak swing of a wave in x, scene units.
        wavelength: length of one wave along y, scene units.
        phase_jitter: how independent the fibers' waves are, in [0, 1]. Each fiber's phase is a phase shared
            by the swatch plus a random offset uniform in [0, 2π·phase_jitter): 0 gives waves in step, as in a
            combed wavy swatch, 1 independent waves. Fibers out of step cross their neighbours.
        segments: straight segments per fiber. Default: 12 per wavelength, ceil(12·length / wavelength).
    """
    _check_positive(amplitude=amplitude, wavelength=wavelength)
    segments = _segments_per_period(segments, length, wavelength, 12, "wavelength")
    _check_size(count, segments)
    rng = np.random.default_rng(seed)
    y = _heights(length, segments)
    x, z = _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng)
    angle = _fiber_phases(count, phase_jitter, rng)[:, None] + 2 * np.pi * y / wavelength
    return _swatch_assembly(x + amplitude * np.sin(angle), y, z, radius, drape)


def curly(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    curl_radius=0.02,
    pitch=0.1,
    phase_jitter=1.0,
    spacing=None,
    jitter=0.25,
    segments=None,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
):
    """A swatch of curly fibers: helices around the fiber axes of `swatch`, all turning the same way.

    Each fiber is (x + curl_radius·cos a, y, z + curl_radius·sin a) with a = 2π·y/pitch + phase.

    Args:
        count, layers, length, radius, spacing, jitter, width, seed, layer_gap, drape: as for `swatch` (fibers reach
            up to `curl_radius` beyond its width and layers; `length` is the extent along y, not the arc
            length).
        curl_radius: radius of the helix, scene units.
        pitch: rise along y per turn, scene units.
        phase_jitter: how independent the fibers' curls are, in [0, 1]. Each fiber's phase is a phase shared
            by the swatch plus a random offset uniform in [0, 2π·phase_jitter): 1 gives independent curls,
            0 curls in step (one ringlet-like sheet).
        segments: straight segments per fiber. Default: 16 per turn, ceil(16·length / pitch).
    """
    _check_positive(curl_radius=curl_radius, pitch=pitch)
    segments = _segments_per_period(segments, length, pitch, 16, "pitch")
    _check_size(count, segments)
    rng = np.random.default_rng(seed)
    y = _heights(length, segments)
    x, z = _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng)
    angle = _fiber_phases(count, phase_jitter, rng)[:, None] + 2 * np.pi * y / pitch
    return _swatch_assembly(x + curl_radius * np.cos(angle), y, z + curl_radius * np.sin(angle), radius, drape)


def fur(
    count=2000,
    patch=0.5,
    length=0.1,
    root_radius=0.0015,
    tip_radius=0.0003,
    lean=30.0,
    bend=20.0,
    length_jitter=0.2,
    segments=6,
    seed=0,
):
    """Short fur fibers rising along +z from a base patch in the x–y plane (z = 0), centred on the origin.

    Each fiber leans away from +z towards its own random azimuth, and bends further that way towards the tip.
    Strand vertex 0 is the root.

    Args:
        count: number of fibers.
        patch: size of the base patch, scene units: the side of a square, or (extent in x, extent in y).
            Roots are uniformly random inside it.
        length: mean fiber length (along the fiber), scene units.
        root_radius: fiber radius at the root, scene units.
        tip_radius: fiber radius at the tip, scene units; the radius tapers linearly from root to tip.
        lean: largest lean of a fiber's root from +z, degrees; each fiber leans by a uniform random angle in
            [0, lean] towards a uniformly random azimuth.
        bend: extra lean gathered from root to tip, degrees, in the fiber's own lean direction. lean + bend must
            stay below 90 so that every fiber keeps rising.
        length_jitter: each fiber's length is length·(1 + u) with u uniform in [−length_jitter, length_jitter];
            in [0, 1).
        segments: straight segments per fiber.
        seed: seed of the NumPy random generator; a seed always gives the same fur.
    """
    _check_size(count, segments)
    _check_positive(length=length, root_radius=root_radius, tip_radius=tip_radius)
    if not (lean >= 0 and bend >= 0 and lean + bend < 90):
        raise ValueError(f"lean and bend must be >= 0 with lean + bend < 90 degrees, got {lean} and {bend}")
    if not 0 <= length_jitter < 1:
        raise ValueError(f"length_jitter must be in [0, 1), got {length_jitter}")
    rng = np.random.default_rng(seed)
    roots = _patch_roots(patch, count, rng)
    lengths = length * (1 + length_jitter * rng.uniform(-1, 1, count))
    root_lean = np.radians(lean) * rng.uniform(0, 1, count)
    azimuth = rng.uniform(0, 2 * np.pi, count)
    # Each segment points along the fiber's lean at its midpoint, which grows linearly from root to tip.
    midpoint = (np.arange(segments) + 0.5) / segments
    tilt = root_lean[:, None] + np.radians(bend) * midpoint
    steps = np.stack(
        [np.sin(tilt) * np.cos(azimuth)[:, None], np.sin(tilt) * np.sin(azimuth)[:, None], np.cos(tilt)], axis=-1
    ) * (lengths / segments)[:, None, None]
    offsets = np.concatenate([np.zeros((count, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    radii = np.linspace(root_radius, tip_radius, segments + 1)
    return FiberAssembly.from_arrays(roots[:, None, :] + offsets, np.broadcast_to(radii, (count, segments + 1)))


def _heights(length, segments):
    _check_positive(length=length)
    _check_count(segments=segments)
    return np.linspace(-length / 2, length / 2, segments + 1)


def _segments_per_period(segments, length, period, per_period, name):
    if segments is not None:
        return segments
    _check_positive(length=length, **{name: period})
    needed = per_period * length / period
    if not needed <= validate.INT32_MAX:
        raise ValueError(
            f"{name} = {period!r} over length {length!r} needs {needed:.3g} segments per fiber ({per_period} per "
            f"period), more than {validate.INT32_MAX}; give a longer {name} or set segments"
        )
    return math.ceil(needed)


# Peak bytes per vertex while a generator builds its arrays (tracemalloc: 20 000 fibers of 20 segments, ~100).
_GENERATOR_BYTES_PER_VERTEX = 128


def _check_size(count, segments):
    """Before allocating: count fibers of `segments` segments must fit int32 indices and the free memory."""
    _check_count(count=count, segments=segments)
    vertices = operator.index(count) * (operator.index(segments) + 1)
    if vertices > validate.INT32_MAX:
        raise ValueError(
            f"{count} fibers of {segments} segments make {vertices} vertices, more than the {validate.INT32_MAX} a "
            "fiber assembly indexes"
        )
    validate.memory(f"{count} fibers of {segments} segments ({vertices} vertices)", vertices * _GENERATOR_BYTES_PER_VERTEX)


def _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng):
    """x and z (S, N) of straight swatch fibers at heights y (N,): jittered, staggered roots plus wander."""
    _check_count(count=count, layers=layers)
    if layers > count:
        raise ValueError(f"layers must be at most count, got {layers} layers for {count} fibers")
    _check_positive(radius=radius)
    if not 0 <= jitter <= _MAX_JITTER:
        raise ValueError(f"jitter must be in [0, {_MAX_JITTER}], got {jitter}")
    sizes = np.full(layers, count // layers)
    sizes[: count % layers] += 1
    spacing = _swatch_spacing(int(sizes[0]), radius, spacing, width, jitter)
    layer_gap = 2 * radius + jitter * spacing if layer_gap is None else layer_gap
    _check_positive(layer_gap=layer_gap)

    layer = np.repeat(np.arange(layers), sizes)
    index_in_layer = np.arange(count) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    stagger = np.where(layer % 2 == 1, 0.25, -0.25) if layers > 1 else 0.0
    x = (index_in_layer - (sizes[layer] - 1) / 2 + stagger) * spacing
    x += jitter * spacing * rng.uniform(-0.5, 0.5, count)
    z = -layer * layer_gap + jitter * spacing * rng.uniform(-0.5, 0.5, count)

    # One slow sideways bow per fiber, at most one wave over its length, so neighbours stay roughly parallel.
    extent = y[-1] - y[0]
    wander = _WANDER * jitter * spacing * rng.uniform(-1, 1, count)
    wander_wavelength = extent * rng.uniform(1, 2, count)
    wander_phase = rng.uniform(0, 2 * np.pi, count)
    bow = np.sin(2 * np.pi * y / wander_wavelength[:, None] + wander_phase[:, None])
    return x[:, None] + wander[:, None] * bow, np.repeat(z[:, None], len(y), axis=1)


def _swatch_spacing(per_layer, radius, spacing, width, jitter):
    if spacing is not None and width is not None:
        raise ValueError("give spacing or width, not both")
    if width is not None:
        _check_positive(width=width)
        return width / per_layer
    if spacing is not None:
        _check_positive(spacing=spacing)
        return spacing
    closest = 1 - (1 + 2 * _WANDER) * jitter
    return _SPACING_MARGIN * 2 * radius / closest


def _fiber_phases(count, phase_jitter, rng):
    if not 0 <= phase_jitter <= 1:
        raise ValueError(f"phase_jitter must be in [0, 1], got {phase_jitter}")
    return rng.uniform(0, 2 * np.pi) + 2 * np.pi * phase_jitter * rng.uniform(0, 1, count)


def _swatch_assembly(x, y, z, radius, drape=None):
    """The assembly of fibers with axes (x, y, z); with `drape`, the swatch is laid over a cylinder.

    Draping bends the flat swatch over a cylinder of radius `drape` whose axis runs along x at z = −drape, the
    way hair swatches are photographed: (y, z) → ((drape + z) sin(y/drape), (drape + z) cos(y/drape) − drape).
    Layer 0 lies on the cylinder, deeper layers inside it, and lengths along y become arc lengths. Seen from +z
    the fibers' tangents then sweep through a range of angles, so one image shows the highlight band whose
    position and width the longitudinal controls (α, β_m) set; a flat swatch shows one angle only.
    """
    y = np.broadcast_to(y, x.shape)
    if drape is not None:
        _check_positive(drape=drape)
        half_angle = np.abs(y).max() / drape
        if half_angle >= np.pi / 2:
            raise ValueError(f"drape = {drape} is too tight for the swatch's length: it must exceed length / π = {2 * np.abs(y).max() / np.pi:.4g}")
        if (z <= -drape).any():
            raise ValueError(f"drape = {drape} is smaller than the swatch's depth {-z.min():.4g}")
        bent = drape + z
        y, z = bent * np.sin(y / drape), bent * np.cos(y / drape) - drape
    points = np.stack([x, y, z], axis=-1)
    return FiberAssembly.from_arrays(points, radius)


def _patch_roots(patch, count, rng):
    extent_x, extent_y = np.broadcast_to(np.asarray(patch, dtype=np.float64), (2,))
    _check_positive(patch_x=extent_x, patch_y=extent_y)
    x = rng.uniform(-extent_x / 2, extent_x / 2, count)
    y = rng.uniform(-extent_y / 2, extent_y / 2, count)
    return np.column_stack([x, y, np.zeros(count)])


def _check_positive(**values):
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def _check_count(**values):
    for name, value in values.items():
        if operator.index(value) < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
