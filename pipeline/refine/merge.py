"""Consolidation after growth: touching segments that are pieces of one plane become one segment.

Greedy growth stops a region when no candidate passes the add threshold, which cuts large flat surfaces (a
disaster ceiling came out in 39 pieces). Two segments merge when both are flat, their normals agree within an
angle, each centroid lies within a distance of the other's plane, and they touch along at least a few voxel
pairs (so that a corner or a stray voxel does not join two walls). Merges are transitive.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.refine.features import VoxelCloud

MAX_FLATNESS: Final = 0.01  # smallest eigenvalue / sum over a whole segment: a plane, not a box or a chair
MIN_CONTACTS: Final = 3  # touching voxel pairs between two segments before they may merge


def segment_planes(points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per label 0..max: centroid (L, 3), unit normal (L, 3) and flatness (L,) of its points (1 when < 3 points)."""
    n = int(labels.max()) + 1
    p = points - points.mean(axis=0)  # conditioning
    count = np.bincount(labels, minlength=n).astype(np.float64)
    safe = np.maximum(count, 1)[:, None]
    mean = np.stack([np.bincount(labels, p[:, i], n) for i in range(3)], axis=1) / safe
    outer = np.stack([np.bincount(labels, p[:, i] * p[:, j], n) for i in range(3) for j in range(3)], axis=1)
    cov = (outer / safe).reshape(n, 3, 3) - mean[:, :, None] * mean[:, None, :]
    evals, evecs = np.linalg.eigh(cov)
    total = evals.sum(axis=1)
    flatness = np.where(total > 1e-12, evals[:, 0].clip(min=0) / np.where(total > 1e-12, total, 1.0), 1.0)
    flatness[count < 3] = 1.0
    return mean, evecs[:, :, 0], flatness


def merge_coplanar(vc: VoxelCloud, labels: np.ndarray, max_angle_deg: float, max_offset_m: float) -> np.ndarray:
    """Voxel labels (M,) with touching coplanar flat segments joined; ids are those of the lowest member."""
    e = np.stack([np.repeat(np.arange(len(vc)), vc.adjacency.shape[1]), vc.adjacency.ravel()], axis=1)
    e = e[e[:, 1] >= 0]
    a, b = labels[e[:, 0]], labels[e[:, 1]]
    cross = a < b
    pairs, contacts = np.unique(np.stack([a[cross], b[cross]], axis=1), axis=0, return_counts=True)
    if len(pairs) == 0:
        return labels
    pairs = pairs[contacts >= MIN_CONTACTS]
    centre, normal, flatness = segment_planes(vc.points, labels)
    i, j = pairs[:, 0], pairs[:, 1]
    d = centre[j] - centre[i]
    ok = (flatness[i] < MAX_FLATNESS) & (flatness[j] < MAX_FLATNESS)
    ok &= np.abs(np.einsum("ij,ij->i", normal[i], normal[j])) >= np.cos(np.radians(max_angle_deg))
    ok &= np.abs(np.einsum("ij,ij->i", d, normal[i])) <= max_offset_m
    ok &= np.abs(np.einsum("ij,ij->i", d, normal[j])) <= max_offset_m
    if not ok.any():
        return labels
    n = int(labels.max()) + 1
    graph = coo_matrix((np.ones(int(ok.sum()), np.int8), (i[ok], j[ok])), shape=(n, n))
    component = connected_components(graph, directed=False)[1]
    lowest = np.full(component.max() + 1, n, np.int64)
    np.minimum.at(lowest, component, np.arange(n))
    return lowest[component][labels]
