"""Consolidation after growth: segments that run round a crease between two planes are cut there, and touching
segments that are pieces of one plane become one segment.

Crease split: without colour, growth leaks round the right-angled edges between structure (a ceiling segment
takes the top of the walls, a wall the strip of floor at its foot). Inside every segment, the voxels whose
normals agree within an angle with a touching voxel of the same segment form smooth parts; every flat part of at
least a minimum size but the segment's largest becomes a segment of its own. Two large planes meeting at an edge
are never one object, while a chair or a box stays whole (its faces are small or not flat).

Coplanar merge: greedy growth stops a region when no candidate passes the add threshold, which cuts large flat
surfaces (a disaster ceiling came out in 39 pieces). Two segments merge when both are flat, their normals agree
within an angle, each centroid lies within a distance of the other's plane, and they touch along at least a few
voxel pairs (so that a corner or a stray voxel does not join two walls). Merges are transitive.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.geometry import graph_components, label_pca
from aftershock.pipeline.refine.features import NORMAL, VoxelCloud

MAX_FLATNESS: Final = 0.01  # smallest eigenvalue / sum over a whole segment: a plane, not a box or a chair
MIN_CONTACTS: Final = 3  # touching voxel pairs between two segments before they may merge


def _touching_pairs(vc: VoxelCloud) -> np.ndarray:
    """Pairs (E, 2) of touching voxels, each pair once in both directions."""
    e = np.stack([np.repeat(np.arange(len(vc)), vc.adjacency.shape[1]), vc.adjacency.ravel()], axis=1)
    return e[e[:, 1] >= 0]


def split_creases(vc: VoxelCloud, labels: np.ndarray, max_angle_deg: float, min_voxels: int) -> np.ndarray:
    """Voxel labels (M,) with every flat smooth part of at least `min_voxels` voxels but each segment's largest
    given a new id (after the existing ones); smooth parts join touching voxels of one segment whose normals
    agree within `max_angle_deg` (sign-agnostic, as in threshold region growing)."""
    e = _touching_pairs(vc)
    normals = vc.features[:, NORMAL]
    same = labels[e[:, 0]] == labels[e[:, 1]]
    same &= np.abs(np.einsum("ij,ij->i", normals[e[:, 0]], normals[e[:, 1]])) >= np.cos(np.radians(max_angle_deg))
    part = graph_components(len(vc), e[same])
    _, _, shares, size = label_pca(vc.points, part)
    flatness = shares[:, 0]  # smallest eigenvalue over the sum
    big = np.flatnonzero((size >= min_voxels) & (flatness < MAX_FLATNESS))
    if len(big) == 0:
        return labels
    owner = np.zeros(len(size), np.int64)
    owner[part] = labels  # a part lies inside one segment
    big = big[np.argsort(-size[big], kind="stable")]
    _, first = np.unique(owner[big], return_index=True)
    moved = np.delete(big, first)  # every big part but the largest of its segment
    if len(moved) == 0:
        return labels
    new_id = np.zeros(len(size), np.int64)
    new_id[moved] = int(labels.max()) + 1 + np.arange(len(moved))
    out = labels.copy()
    sel = new_id[part] > 0
    out[sel] = new_id[part[sel]]
    return out


def merge_coplanar(vc: VoxelCloud, labels: np.ndarray, max_angle_deg: float, max_offset_m: float) -> np.ndarray:
    """Voxel labels (M,) with touching coplanar flat segments joined; ids are those of the lowest member."""
    e = _touching_pairs(vc)
    a, b = labels[e[:, 0]], labels[e[:, 1]]
    cross = a < b
    pairs, contacts = np.unique(np.stack([a[cross], b[cross]], axis=1), axis=0, return_counts=True)
    if len(pairs) == 0:
        return labels
    pairs = pairs[contacts >= MIN_CONTACTS]
    centre, normal, shares, count = label_pca(vc.points, labels)
    flatness = np.where(count >= 3, shares[:, 0], 1.0)  # fewer than 3 points: no plane
    i, j = pairs[:, 0], pairs[:, 1]
    d = centre[j] - centre[i]
    ok = (flatness[i] < MAX_FLATNESS) & (flatness[j] < MAX_FLATNESS)
    ok &= np.abs(np.einsum("ij,ij->i", normal[i], normal[j])) >= np.cos(np.radians(max_angle_deg))
    ok &= np.abs(np.einsum("ij,ij->i", d, normal[i])) <= max_offset_m
    ok &= np.abs(np.einsum("ij,ij->i", d, normal[j])) <= max_offset_m
    if not ok.any():
        return labels
    n = int(labels.max()) + 1
    component = graph_components(n, np.stack([i[ok], j[ok]], axis=1))
    lowest = np.full(component.max() + 1, n, np.int64)
    np.minimum.at(lowest, component, np.arange(n))
    return lowest[component][labels]
