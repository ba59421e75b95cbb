"""`FiberAssembly`: strands of hair or fur as polylines with a radius per vertex, the container the renderer
reads, checked on construction (`FiberDataError` locates a problem by file, line, strand and vertex). Plain NumPy.
Strands are listed root first (the package docstring says why)."""

from __future__ import annotations

import operator

import numpy as np

from .. import validate


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

    def __init__(self, points, radii, strand_offsets, *, strand_random=None, source=None):
        # Values beyond float32 range become inf here, which the checks below report by strand.
        with np.errstate(over="ignore"):
            self.points = _frozen(np.array(points, dtype=np.float32))
            self.radii = _frozen(np.array(radii, dtype=np.float32))
        self.strand_offsets = _frozen(_as_offsets(strand_offsets, source))
        _check_shapes(self.points, self.radii, self.strand_offsets, source)
        _check_strands(self.points, self.radii, self.strand_offsets, source)
        # Each strand's random value in [0, 1] where the file gives one (a USD `random` primvar); None: the
        # renderer draws it from the strand's index as Cycles does (model/variation.py).
        self.strand_random = None if strand_random is None else _frozen(_checked_random(strand_random, self, source))

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
    def from_strands(cls, strands, *, strand_random=None, source=None):
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
        return cls(np.concatenate(points), np.concatenate(radii), offsets, strand_random=strand_random, source=source)

    @classmethod
    def concatenate(cls, assemblies):
        """One assembly holding the strands of all `assemblies`, in order."""
        assemblies = list(assemblies)
        if not assemblies:
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(1, dtype=np.int64))
        starts = np.cumsum([0] + [a.num_vertices for a in assemblies[:-1]])
        offsets = [np.zeros(1, dtype=np.int64)]
        offsets += [a.strand_offsets[1:] + start for a, start in zip(assemblies, starts)]
        given = [a.strand_random is not None for a in assemblies]
        return cls(
            np.concatenate([a.points for a in assemblies]),
            np.concatenate([a.radii for a in assemblies]),
            np.concatenate(offsets),
            # Only where every part has its own: an index-drawn value depends on the strand's place in the whole.
            strand_random=np.concatenate([a.strand_random for a in assemblies]) if all(given) else None,
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

    def segment_arc_fractions(self):
        """(start, span), (M,) float64 each in `segments` order: the share of its strand's length before each
        segment and the share it covers (a strand of zero length shares it equally), for root-to-tip profiles."""
        p0, p1, _, _, strand_id, _ = self.segments()
        lengths = np.linalg.norm(p1.astype(np.float64) - p0.astype(np.float64), axis=1)
        totals = np.bincount(strand_id, weights=lengths, minlength=self.num_strands)
        counts = self.vertex_counts - 1
        degenerate = totals[strand_id] <= 0.0
        span = np.where(degenerate, 1.0 / counts[strand_id], lengths / np.where(degenerate, 1.0, totals[strand_id]))
        before = np.cumsum(span) - span
        first_of_strand = np.concatenate([[0], np.cumsum(counts)[:-1]])
        start = before - before[first_of_strand][strand_id]
        return start, span

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
        return f"FiberAssembly({self.num_strands} strands, {self.num_vertices} vertices, {self.num_segments} segments)"


def _checked_random(values, assembly, source):
    values = np.array(values, dtype=np.float32).reshape(-1)
    if values.shape != (assembly.num_strands,):
        raise FiberDataError(
            f"strand_random must hold one value per strand ({assembly.num_strands}), got {values.size}", source=source
        )
    bad = np.flatnonzero(~((values >= 0.0) & (values <= 1.0)))
    if bad.size:
        raise FiberDataError(f"random value {values[bad[0]]} is outside [0, 1]", strand=int(bad[0]), source=source)
    return values


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
