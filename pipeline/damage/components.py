"""Building components to look for cracks on: cut a scene into elements and pick them by size or by a box.

Elements come from, in order of preference: a box the user gives; the labelled instances of structural
classes (column, wall, beam, floor, ceiling) when the cloud carries them; otherwise region growing on normals
and colour over a 0.1 m neighbourhood (on a coarse voxel copy, mapped back to every point).
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.classes import STRUCTURAL_CLASSES
from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.geometry import pca_normals, threshold_region_growing, voxel_downsample
from aftershock.pipeline.types import LabelledCloud

COLUMN_DIMS_M: Final = (0.4, 0.4, 2.6)  # the study's columns


def in_box(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Indices of the points inside an axis-aligned box (2, 3) = min corner, max corner."""
    lo, hi = np.sort(np.asarray(box, np.float64).reshape(2, 3), axis=0)
    return np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))


def extents(points: np.ndarray) -> np.ndarray:
    """Sizes (3,) of a point set, largest first: along its principal axis, then the sides of the minimum-area
    rectangle of its cross-section (a square column's cross-section has no principal direction of its own)."""
    from aftershock.pipeline.damage.measure import min_area_rectangle

    sample = points[:: max(1, len(points) // 20000)]
    centred = sample - sample.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    along = centred @ vt[0]
    rect = min_area_rectangle(centred @ vt[1:].T)
    return np.sort([along.max() - along.min(), rect.length, rect.width])[::-1]


def matches_dims(points: np.ndarray, dims: tuple[float, float, float], tolerance: float) -> bool:
    """True when the two largest principal extents are within ±`tolerance` (relative) of the two largest
    expected sizes and the smallest is not larger than expected: the whole element or one of its faces
    (region growing on normals splits a column into its faces)."""
    want = np.sort(np.asarray(dims, np.float64))[::-1]
    got = extents(points)
    close = np.abs(got[:2] - want[:2]) <= tolerance * np.maximum(want[:2], 0.05)
    return bool(np.all(close) and got[2] <= want[2] * (1 + tolerance) + 0.02)


def segment(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    """Segment id of every point (0 = too small) from region growing on normals and colour."""
    keep, voxel_of = voxel_downsample(cloud.points, cfg.element_voxel_m)
    pts = cloud.points[keep]
    normals, _ = pca_normals(pts, k=16, radius_m=2 * cfg.element_radius_m)
    colors = cloud.colors[keep] if cloud.colors is not None else None
    labels = threshold_region_growing(
        pts, normals, colors, cfg.element_radius_m, cfg.element_angle_deg, cfg.element_color_distance
    )
    return labels[voxel_of]


def extract_elements(
    cloud: LabelledCloud,
    cfg: CrackConfig,
    dims: tuple[float, float, float] | None = None,
    box: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Index arrays of the elements of `cloud` to assess, largest first: the points in `box`; else labelled
    structural instances; else region-growing segments. With `dims`, only elements of about that size."""
    if box is not None:
        idx = in_box(cloud.points, box)
        return [idx] if len(idx) else []
    if cloud.class_ids is not None and cloud.instance_ids is not None:
        structural = np.isin(cloud.class_ids, np.array([int(c) for c in STRUCTURAL_CLASSES]))
        ids = np.where(structural & (cloud.instance_ids > 0), cloud.instance_ids.astype(np.int64), 0)
    else:
        ids = segment(cloud, cfg)
    order = np.argsort(ids, kind="stable")
    uniq, starts, counts = np.unique(ids[order], return_index=True, return_counts=True)
    elements = [
        order[s : s + c] for u, s, c in zip(uniq, starts, counts, strict=True) if u != 0 and c >= cfg.element_min_points
    ]
    if dims is not None:
        elements = [e for e in elements if matches_dims(cloud.points[e], dims, cfg.dims_tolerance)]
    return sorted(elements, key=len, reverse=True)
