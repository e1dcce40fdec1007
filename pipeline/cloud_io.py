"""Labelled point-cloud files in the DESIGN.md format: PLY with `x y z`, `red green blue` and, where known,
`class_id`, `instance_id` (and optionally `intensity`, `nx ny nz`, `confidence`). Inputs and outputs use the same
format."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Final

import numpy as np
from plyfile import PlyData, PlyElement, PlyParseError

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.outputs import check_output, same_file, write_atomically

__all__ = ["check_output", "read_cloud", "same_file", "write_atomically", "write_cloud"]
from aftershock.pipeline.types import LabelledCloud

_INTENSITY_NAMES: Final = ("intensity", "scalar_intensity", "scalar_Intensity", "reflectance")
# A PLY header comment saying that red, green, blue stand in for a colour the source did not have
STAND_IN_COLOR_COMMENT: Final = "aftershock: no colour recorded (red green blue are a stand-in)"


def check_ply_body(path: Path) -> None:
    """Refuse a PLY whose header says binary but whose body holds ASCII text or fewer bytes than its fixed-size
    elements need: read as binary, such a file gives nonsense points without an error."""
    with path.open("rb") as fh:
        head = fh.read(_PLY_HEADER_MAX)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return  # plyfile names the problem
    body_at = head.find(b"\n", end) + 1
    lines = head[:end].decode("ascii", "replace").splitlines()
    fmt = next((ln.split()[1] for ln in lines if ln.startswith("format") and len(ln.split()) > 1), "ascii")
    if fmt == "ascii":
        _check_ply_rows(path, lines, body_at)
        return
    sample = head[body_at : body_at + 256]
    if len(sample) >= 16 and all(c in _ASCII_NUMBER_BYTES for c in sample):
        raise InputError(f"the header says {fmt}, but the data is ASCII text; fix the header's format line", path)
    size = path.stat().st_size - body_at
    expected = _ply_fixed_bytes(lines)
    if expected is not None and size < expected:
        raise InputError(f"the header says {fmt} with {expected} bytes of data, but the file holds {size}", path)
    if expected is not None and size > expected:
        _warn(path, f"the header declares {expected} bytes of data but the file holds {size}; the rest is not read")


def _warn(path: Path, message: str) -> None:
    import warnings

    from aftershock.pipeline.errors import DamagedLogWarning

    warnings.warn(DamagedLogWarning(f"{path}: {message}"), stacklevel=3)


def _check_ply_rows(path: Path, lines: list[str], body_at: int) -> None:
    """An ASCII PLY whose elements declare fewer rows than its body holds (10 vertices over 500 rows) reads only
    the declared ones: say so. Rows are counted in blocks, never holding the file."""
    declared = 0
    for ln in lines:
        words = ln.split()
        if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            declared += int(words[2])
    rows = 0
    carry = b""
    with path.open("rb") as fh:
        fh.seek(body_at)
        while block := fh.read(1 << 20):
            pieces = (carry + block).split(b"\n")
            carry = pieces.pop()
            rows += sum(1 for piece in pieces if piece.strip())
    rows += bool(carry.strip())  # a last row without its newline
    if rows > declared:
        _warn(
            path, f"the header declares {declared} rows but the file holds {rows}; only the first {declared} are read"
        )


_PLY_HEADER_MAX: Final = 64 * 1024
_ASCII_NUMBER_BYTES: Final = frozenset(b"0123456789+-.eE \t\r\nnaifNAIF")
_PLY_SIZES: Final = {
    **dict.fromkeys(("char", "int8", "uchar", "uint8"), 1),
    **dict.fromkeys(("short", "int16", "ushort", "uint16"), 2),
    **dict.fromkeys(("int", "int32", "uint", "uint32", "float", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}


def _ply_fixed_bytes(lines: list[str]) -> int | None:
    """Bytes the binary body of a PLY header needs, or None when an element has list properties."""
    total = 0
    count = 0
    for ln in [*lines, "element end 0"]:
        words = ln.split()
        if words[:1] == ["element"] and len(words) == 3:
            count = int(words[2]) if words[2].isdigit() else 0
        elif words[:1] == ["property"] and len(words) >= 3:
            if words[1] == "list" or words[1] not in _PLY_SIZES:
                return None
            total += count * _PLY_SIZES[words[1]]
    return total


def read_cloud(path: str | Path) -> LabelledCloud:
    """Read a PLY (any float/int vertex properties; labels and colour where present)."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file", p)
    if not p.is_file():
        raise InputError("not a regular file", p)
    if not os.access(p, os.R_OK):
        raise InputError("cannot read the file (permission denied)", p)
    if p.suffix.lower() != ".ply":
        return _read_with_open3d(p)
    check_ply_body(p)
    try:
        ply = PlyData.read(str(p))
    except (PlyParseError, ValueError, OSError, UnicodeDecodeError) as exc:
        raise InputError(f"not a readable PLY file ({exc})", p) from None
    if "vertex" not in ply:
        raise InputError("PLY has no vertex element", p)
    v = ply["vertex"].data
    names = set(v.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise InputError("PLY vertices have no x, y, z", p)
    points = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    colors = None
    if {"red", "green", "blue"} <= names and STAND_IN_COLOR_COMMENT not in ply.comments:
        rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1)
        colors = (rgb * 255 if rgb.dtype.kind == "f" and rgb.max(initial=0) <= 1.0 else rgb).astype(np.uint8)
    intensity = None
    for name in _INTENSITY_NAMES:
        if name in names:
            intensity = np.asarray(v[name], dtype=np.float32)
            break
    else:
        extra = [n for n in v.dtype.names if v.dtype[n].kind == "f" and n not in _KNOWN_FLOATS]
        if len(extra) == 1:  # an unnamed scanner scalar field, as in the crack data
            intensity = np.asarray(v[extra[0]], dtype=np.float32)
    normals = None
    if {"nx", "ny", "nz"} <= names:
        normals = np.stack([v["nx"], v["ny"], v["nz"]], axis=1).astype(np.float32)
    class_ids = np.asarray(v["class_id"]).astype(np.uint16) if "class_id" in names else None
    instance_ids = np.asarray(v["instance_id"]).astype(np.uint32) if "instance_id" in names else None
    confidence = np.asarray(v["confidence"], dtype=np.float32) if "confidence" in names else None
    return LabelledCloud(points, colors, intensity, class_ids, instance_ids, normals, confidence)


_KNOWN_FLOATS: Final = frozenset({"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha", "confidence"})


def finite_points(
    cloud: LabelledCloud, path: str | Path, notice: Callable[[str], None]
) -> tuple[LabelledCloud, np.ndarray]:
    """The cloud without points whose coordinates are NaN or infinite (one notice says how many went), and
    the kept indices (to cut per-point masks alike); InputError when nothing usable is left."""
    ok = np.isfinite(cloud.points).all(axis=1)
    keep = np.flatnonzero(ok)
    if len(keep) == len(cloud):
        return cloud, keep
    if len(keep) == 0:
        raise InputError(f"none of its {len(cloud)} points has finite coordinates", path)
    notice(f"{path}: dropped {len(cloud) - len(keep)} of {len(cloud)} points with NaN or infinite coordinates")
    return cloud.select(keep), keep


def _read_with_open3d(p: Path) -> LabelledCloud:
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(p)
    if len(pcd.points) == 0:
        raise InputError("no points could be read", p)
    colors = (np.asarray(pcd.colors) * 255).astype(np.uint8) if pcd.has_colors() else None
    return LabelledCloud(np.asarray(pcd.points), colors)


def write_cloud(
    path: str | Path, cloud: LabelledCloud, *, force: bool = False, binary: bool = True, stand_in_color: bool = False
) -> Path:
    """Write a labelled PLY; refuses to overwrite unless `force`. The format always carries red, green, blue: a
    cloud without colour gets grey, and that (or colour the caller made up, `stand_in_colour`) is marked in the
    header so that `read_cloud` gives the cloud back without colour."""
    p = check_output(path, force)
    n = len(cloud)
    fields: list[tuple[str, str]] = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    columns: dict[str, np.ndarray] = {"x": cloud.points[:, 0], "y": cloud.points[:, 1], "z": cloud.points[:, 2]}
    colors = cloud.colors if cloud.colors is not None else np.full((n, 3), 200, np.uint8)
    comments = [STAND_IN_COLOR_COMMENT] if stand_in_color or cloud.colors is None else []
    for i, name in enumerate(("red", "green", "blue")):
        fields.append((name, "u1"))
        columns[name] = colors[:, i]
    if cloud.normals is not None:
        for i, name in enumerate(("nx", "ny", "nz")):
            fields.append((name, "f4"))
            columns[name] = cloud.normals[:, i]
    optional = (
        ("intensity", "f4", cloud.intensity),
        ("class_id", "i4", cloud.class_ids),
        ("instance_id", "i4", cloud.instance_ids),
        ("confidence", "f4", cloud.confidence),
    )
    for name, kind, values in optional:
        if values is not None:
            fields.append((name, kind))
            columns[name] = values
    data = np.empty(n, dtype=fields)
    for name, _ in fields:
        data[name] = columns[name]
    ply = PlyData([PlyElement.describe(data, "vertex")], text=not binary, comments=comments)
    write_atomically(p, lambda tmp: ply.write(str(tmp)))
    return p
