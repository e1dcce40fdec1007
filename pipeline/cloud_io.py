"""Labelled point-cloud files in the DESIGN.md format: PLY with `x y z`, `red green blue` and, where known,
`class_id`, `instance_id` (and optionally `intensity`, `nx ny nz`). Inputs and outputs use the same format."""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
from plyfile import PlyData, PlyElement, PlyParseError

from aftershock.pipeline.errors import InputError, OutputError
from aftershock.pipeline.types import LabelledCloud

_INTENSITY_NAMES: Final = ("intensity", "scalar_intensity", "scalar_Intensity", "reflectance")


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse to overwrite an existing file unless forced; make the parent folder; fail early if unwritable."""
    p = Path(path)
    if p.exists() and not force:
        raise OutputError("already exists (pass --force to overwrite)", p)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror}", p.parent) from None
    if not _writable(p.parent):
        raise OutputError("folder is not writable", p.parent)
    return p


def _writable(folder: Path) -> bool:
    import os

    return os.access(folder, os.W_OK | os.X_OK)


def read_cloud(path: str | Path) -> LabelledCloud:
    """Read a PLY (any float/int vertex properties; labels and colour where present)."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file", p)
    if p.suffix.lower() != ".ply":
        return _read_with_open3d(p)
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
    if {"red", "green", "blue"} <= names:
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
    return LabelledCloud(points, colors, intensity, class_ids, instance_ids, normals)


_KNOWN_FLOATS: Final = frozenset({"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha"})


def _read_with_open3d(p: Path) -> LabelledCloud:
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(p))
    if len(pcd.points) == 0:
        raise InputError("no points could be read", p)
    colors = (np.asarray(pcd.colors) * 255).astype(np.uint8) if pcd.has_colors() else None
    return LabelledCloud(np.asarray(pcd.points), colors)


def write_cloud(path: str | Path, cloud: LabelledCloud, *, force: bool = False, binary: bool = True) -> Path:
    """Write a labelled PLY; refuses to overwrite unless `force`."""
    p = check_output(path, force)
    n = len(cloud)
    fields: list[tuple[str, str]] = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    columns: dict[str, np.ndarray] = {"x": cloud.points[:, 0], "y": cloud.points[:, 1], "z": cloud.points[:, 2]}
    colors = cloud.colors if cloud.colors is not None else np.full((n, 3), 200, np.uint8)
    for i, name in enumerate(("red", "green", "blue")):
        fields.append((name, "u1"))
        columns[name] = colors[:, i]
    if cloud.normals is not None:
        for i, name in enumerate(("nx", "ny", "nz")):
            fields.append((name, "f4"))
            columns[name] = cloud.normals[:, i]
    if cloud.intensity is not None:
        fields.append(("intensity", "f4"))
        columns["intensity"] = cloud.intensity
    if cloud.class_ids is not None:
        fields.append(("class_id", "i4"))
        columns["class_id"] = cloud.class_ids
    if cloud.instance_ids is not None:
        fields.append(("instance_id", "i4"))
        columns["instance_id"] = cloud.instance_ids
    data = np.empty(n, dtype=fields)
    for name, _ in fields:
        data[name] = columns[name]
    try:
        PlyData([PlyElement.describe(data, "vertex")], text=not binary).write(str(p))
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", p) from None
    return p
