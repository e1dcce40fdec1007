"""LRGNet's per-point features over a voxelised cloud, and their per-step normalisation.

A cloud is reduced to one point per voxel (the centroid of its raw points); normals and curvature come from
PCA over the raw points of the surrounding 3 x 3 x 3 voxels. The 16 features of a voxel are
`[x, y, z, u, v, w, r, g, b, nx, ny, nz, curvature, planarity, linearity, verticality]`: xyz with z above the
scene's floor (x, y are made relative to the region's median at each step), room-normalised xyz in [0, 1],
colour in [0, 1] (zero without colour), the unit normal and the curvature, which at each step are made relative
to the region's median; then the local shape, kept absolute because it transfers between buildings: planarity
(λ2 - λ3) / λ1 and linearity (λ1 - λ2) / λ1 of the local eigenvalues λ1 ≥ λ2 ≥ λ3, and |n_z| (1 on floors,
0 on walls). Weights of feature layout 3 (shipped since round P2:
docs/decisions.md#round-p2-lrgnet-plane-features-full-size) read two more per step, appended by `step_features`:
the distance to the region's plane and |cos| between the voxel's normal and the region's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from aftershock.pipeline.geometry import voxel_keys
from aftershock.pipeline.types import LabelledCloud

NUM_FEATURES: Final = 16
# Per-step features of layout 3, appended after the 16: the voxel's distance to the region's plane and the cosine
# between its normal and the region's, both sign-free — what smoothness region growing tests, made explicit.
PLANE_FEATURES: Final = 2
LOCAL_XY: Final = slice(0, 2)
HEIGHT: Final = slice(2, 3)
NORMALISED: Final = slice(6, 13)  # colour, normal, curvature: minus the region's median per step
NORMAL: Final = slice(9, 12)
# The region's reference (`region_centre`): median x, y | colour, normal, curvature (NORMALISED) | z.
CENTRE_XY: Final = slice(0, 2)
CENTRE_NORMALISED: Final = slice(2, 9)
CENTRE_NORMAL: Final = slice(5, 8)
CENTRE_Z: Final = slice(9, 10)


def neighbour_offsets(reach: int) -> np.ndarray:
    """Voxel offsets within `reach` voxels in every axis, the voxel itself excluded ((2r+1)^3 - 1, 3)."""
    r = range(-reach, reach + 1)
    return np.array([(i, j, k) for i in r for j in r for k in r if (i, j, k) != (0, 0, 0)], np.int64)


@dataclass(slots=True)
class VoxelCloud:
    """A cloud reduced to voxels, with everything region growing needs."""

    points: np.ndarray  # (M, 3) float64 voxel centroids
    features: np.ndarray  # (M, 16) float32, before per-step normalisation
    curvature: np.ndarray  # (M,) float32
    adjacency: np.ndarray  # (M, K) int64 indices of the occupied neighbouring voxels, -1 where empty
    voxel_of_point: np.ndarray  # (N,) int64 voxel index of every raw point
    first_point: np.ndarray  # (M,) int64 index of the first raw point of every voxel (for its labels)
    color: bool = True  # the cloud had colour (without, the colour features are zero)

    def __len__(self) -> int:
        return len(self.points)


def _neighbour_table(keys: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(M, K) indices of the occupied voxels at the given offsets from each voxel, -1 where empty."""
    reach = int(np.abs(offsets).max())
    lo = keys.min(axis=0) - reach
    span = keys.max(axis=0) - lo + reach + 1
    k = keys - lo

    def code(a: np.ndarray) -> np.ndarray:
        return (a[..., 0] * span[1] + a[..., 1]) * span[2] + a[..., 2]

    codes = code(k)
    order = np.argsort(codes, kind="stable")
    sorted_codes = codes[order]
    probe = code(k[:, None, :] + offsets[None, :, :])  # (M, K)
    pos = np.searchsorted(sorted_codes, probe).clip(max=len(codes) - 1)
    hit = sorted_codes[pos] == probe
    return np.where(hit, order[pos], -1)


def canonical_normals(normals: np.ndarray) -> np.ndarray:
    """Normals with their largest component positive: one sign for a whole wall as for a whole floor (orienting
    to +z alone leaves the sign of a wall's normals to noise, and the per-step median difference would see it)."""
    n = np.asarray(normals)
    big = np.take_along_axis(n, np.abs(n).argmax(axis=-1)[..., None], axis=-1)
    return np.where(big < 0, -n, n)


def _pca_over_neighbourhood(
    raw: np.ndarray, voxel_of_point: np.ndarray, adjacency: np.ndarray, m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From the raw points of 27 voxels: normals (canonical sign), curvature = smallest eigenvalue / sum, and the
    local shape (M, 3): planarity, linearity, |n_z|."""
    centre = raw.mean(axis=0)
    p = raw - centre  # conditioning: second moments about the scene centre
    count = np.bincount(voxel_of_point, minlength=m).astype(np.float64)
    first = np.stack([np.bincount(voxel_of_point, p[:, i], m) for i in range(3)], axis=1)
    outer = np.stack([np.bincount(voxel_of_point, p[:, i] * p[:, j], m) for i in range(3) for j in range(3)], axis=1)
    pad = np.vstack  # stats of "no voxel" (index -1 -> the appended zero row)
    count_p, first_p, outer_p = pad([count[:, None], [[0.0]]]), pad([first, [[0.0] * 3]]), pad([outer, [[0.0] * 9]])
    nb = np.concatenate([np.arange(m)[:, None], adjacency], axis=1)  # self + 26 = the 3 x 3 x 3 block
    n = count_p[nb, 0].sum(axis=1)
    s1 = first_p[nb].sum(axis=1)
    s2 = outer_p[nb].sum(axis=1).reshape(m, 3, 3)
    mean = s1 / n[:, None]
    cov = s2 / n[:, None, None] - mean[:, :, None] * mean[:, None, :]
    evals, evecs = np.linalg.eigh(cov)
    normals = canonical_normals(evecs[:, :, 0])
    total = evals.sum(axis=1)
    curvature = np.where(total > 1e-12, evals[:, 0].clip(min=0) / np.where(total > 1e-12, total, 1), 0.0)
    curvature[n < 3] = 1.0
    ev = evals.clip(min=0)
    big = np.where(ev[:, 2] > 1e-12, ev[:, 2], 1.0)
    shape = np.stack([(ev[:, 1] - ev[:, 0]) / big, (ev[:, 2] - ev[:, 1]) / big, np.abs(normals[:, 2])], axis=1)
    shape[n < 3] = 0.0
    return normals.astype(np.float32), curvature.astype(np.float32), shape.astype(np.float32)


def voxelise(cloud: LabelledCloud, voxel_m: float, delta_m: float | None = None) -> VoxelCloud:
    """One point per voxel with its 16 base features, its neighbourhood and the raw-point mapping.

    Two voxels are neighbours when they lie within δ of each other in every axis, counted in whole voxels
    (at least one): with δ = the voxel size, the 26 voxels touching a voxel. Measured between voxels rather than
    between centroids, so that surfaces sampled at the voxel size stay connected."""
    raw = cloud.points
    keys = voxel_keys(raw, voxel_m)
    uniq, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    m = len(uniq)
    count = np.bincount(inverse, minlength=m).astype(np.float64)
    centroid = np.stack([np.bincount(inverse, raw[:, i], m) for i in range(3)], axis=1) / count[:, None]
    touching = _neighbour_table(uniq, neighbour_offsets(1))
    normals, curvature, shape = _pca_over_neighbourhood(raw, inverse, touching, m)
    reach = max(1, round((delta_m if delta_m is not None else voxel_m) / voxel_m))
    adjacency = touching if reach == 1 else _neighbour_table(uniq, neighbour_offsets(reach))
    if cloud.colors is not None:
        summed = [np.bincount(inverse, cloud.colors[:, i].astype(np.float64), m) for i in range(3)]
        rgb = np.stack(summed, axis=1) / count[:, None] / 255.0
    else:
        rgb = np.zeros((m, 3))
    lo, hi = centroid.min(axis=0), centroid.max(axis=0)
    room = (centroid - lo) / np.where(hi - lo > 1e-9, hi - lo, 1.0)
    xyz = centroid.copy()
    xyz[:, 2] -= lo[2]
    features = np.concatenate([xyz, room, rgb, normals, curvature[:, None], shape], axis=1).astype(np.float32)
    return VoxelCloud(centroid, features, curvature, adjacency, inverse, first, cloud.colors is not None)


def region_centre(features: np.ndarray, region: np.ndarray) -> np.ndarray:
    """The per-step reference of a region: median of x, y, of colour/normal/curvature and of z, (10,) float32."""
    f = features[region]
    medians = [np.median(f[:, cols], axis=0) for cols in (LOCAL_XY, NORMALISED, HEIGHT)]
    return np.concatenate(medians).astype(np.float32)


def reads_plane(in_features: int) -> bool:
    """Whether a network with this many inputs was trained on feature layout 3 (the plane features)."""
    return in_features > NUM_FEATURES


def plane_features(raw: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(..., 2) distance of each voxel to the plane through the region's median point along its median normal, and
    |cos| between the voxel's normal and that normal; `raw` (..., 16) features before normalisation, `centre`
    (..., 10) their region's reference (leading dimensions broadcast)."""
    n = centre[..., CENTRE_NORMAL]
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    offset = np.concatenate([raw[..., LOCAL_XY] - centre[..., CENTRE_XY], raw[..., HEIGHT] - centre[..., CENTRE_Z]], -1)
    distance = np.abs((offset * n).sum(axis=-1))
    cosine = np.abs((raw[..., NORMAL] * n).sum(axis=-1))
    return np.stack([distance, cosine], axis=-1).astype(np.float32)


def step_features(features: np.ndarray, idx: np.ndarray, centre: np.ndarray, plane: bool = False) -> np.ndarray:
    """Features of the points `idx`, normalised by a region's reference from `region_centre`; with `plane`, the
    two plane features of layout 3 appended."""
    f = features[idx].copy()
    extra = plane_features(f, centre) if plane else None
    f[:, LOCAL_XY] -= centre[CENTRE_XY]
    f[:, NORMALISED] -= centre[CENTRE_NORMALISED]
    return f if extra is None else np.concatenate([f, extra], axis=1)
