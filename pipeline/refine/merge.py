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

from aftershock.pipeline.geometry import label_pca
from aftershock.pipeline.refine.features import VoxelCloud

MAX_FLATNESS: Final = 0.01  # smallest eigenvalue / sum over a whole segment: a plane, not a box or a chair
MIN_CONTACTS: Final = 3  # touching voxel pairs between two segments before they may merge


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
    centre, normal, flatness, count = label_pca(vc.points, labels)
    flatness = np.where(count >= 3, flatness, 1.0)  # fewer than 3 points: no plane
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
