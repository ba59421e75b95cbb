"""Fiber files: Cem Yuksel's binary `.hair` and the plain-text `x y z radius` curves of Mitsuba 3, chosen by
extension by `load_fibers` / `save_fibers` (which hand USD stages to `usd.py`). Malformed files raise a
`FiberDataError` naming the file, line, strand and vertex."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .assembly import FiberAssembly, FiberDataError
from .usd import SUFFIXES as USD_SUFFIXES


def load_fibers(path, **options):
    """Load a fiber file, choosing the format by extension: `.hair` (Cem Yuksel's binary), `.txt` (text), or a USD
    stage (`.usd`, `.usda`, `.usdc`: BasisCurves, `warp_hair.geometry.usd`, which takes `options` prim, radius,
    segments)."""
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
    UTF-8, with or without a byte-order mark. A malformed file raises `FiberDataError` (a ValueError) naming the file,
    line and strand.
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
