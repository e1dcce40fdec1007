"""Shared point-cloud geometry: rigid motions (SE(3) log/exp, transforms), voxel keys and downsampling,
neighbourhoods, connected components, PCA normals and curvature, and the two classical region-growing
segmentations (threshold and smoothness constraint).

Everything is vectorised: neighbourhoods come from scipy's cKDTree, covariances are batched, and
region growing is phrased as connected components over the graph of neighbour pairs that pass the test.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

_CHUNK: Final = 200_000  # points per batch when gathering neighbourhoods, bounds memory


# ------------------------------------------------------------------------------------------ SE(3) and vectors


def hat(w: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) skew-symmetric matrices."""
    z = np.zeros(len(w))
    return np.stack(
        [
            np.stack([z, -w[:, 2], w[:, 1]], -1),
            np.stack([w[:, 2], z, -w[:, 0]], -1),
            np.stack([-w[:, 1], w[:, 0], z], -1),
        ],
        axis=1,
    )


def se3_log(pose: np.ndarray) -> np.ndarray:
    """Twist (v, w) of a 4 x 4 rigid transform, translation part first (Sophus' order)."""
    w = Rotation.from_matrix(pose[:3, :3]).as_rotvec()
    theta = float(np.linalg.norm(w))
    wx = hat(w[None])[0]
    if theta < 1e-9:
        v_inv = np.eye(3) - 0.5 * wx
    else:
        half = 0.5 * theta
        v_inv = np.eye(3) - 0.5 * wx + (1.0 - half / np.tan(half)) / theta**2 * (wx @ wx)
    return np.r_[v_inv @ pose[:3, 3], w]


def se3_exp_apply(twist: np.ndarray, scales: np.ndarray, points: np.ndarray) -> np.ndarray:
    """exp(s_i * twist) applied to point i, for all points at once."""
    v, w = twist[:3], twist[3:]
    s = np.asarray(scales, np.float64)
    ws = s[:, None] * w[None, :]
    theta = norms(ws)
    small = theta < 1e-9
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    p = np.asarray(points, np.float64)
    # Rodrigues for R p and V v without building N matrices: w x p and w x (w x p).
    wp = cross_rows(ws, p)
    vs = s[:, None] * v[None, :]
    wv = cross_rows(ws, vs)
    return p + vs + a[:, None] * wp + b[:, None] * (cross_rows(ws, wp) + wv) + c[:, None] * cross_rows(ws, wv)


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross spends most of its time reshaping)."""
    out = np.empty_like(b)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def se3_exp(twist: np.ndarray) -> np.ndarray:
    """4 x 4 rigid transform of a twist (v, w)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(twist[3:]).as_matrix()
    out[:3, 3] = se3_exp_apply(twist, np.ones(1), np.zeros((1, 3)))[0]
    return out


def sweep_motion(delta: np.ndarray, fraction: float) -> np.ndarray:
    """The part `fraction` of a rigid motion (along its screw axis)."""
    return delta if fraction == 1.0 else se3_exp(fraction * se3_log(delta))


def transform(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 3) moved by a 4 x 4 pose. einsum, not `@`: a BLAS call for a 3-wide product spends more
    time waking threads than computing on a busy machine."""
    return np.einsum("ij,nj->ni", pose[:3, :3], points) + pose[:3, 3]


def norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms along the last axis (much faster than np.linalg.norm(..., axis=-1) for 3-vectors)."""
    return np.sqrt(np.einsum("...i,...i->...", v, v))


# ------------------------------------------------------------------------------------------ voxels


def voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Integer voxel coordinates (N, 3) int64 of each point."""
    return np.floor(np.asarray(points) / voxel_m).astype(np.int64)


def voxel_index(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Index (N,) of each point's voxel, the voxels numbered in the order of their keys."""
    keys = voxel_keys(points, voxel_m)
    packed = _pack_keys(keys)
    rows = keys if packed is None else packed
    return np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1)


def voxel_downsample(points: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One point per voxel: (indices of the first point of each voxel, in input order; voxel index of every point)."""
    keys = voxel_keys(points, voxel_m)
    packed = _pack_keys(keys)
    # np.unique over rows sorts opaque row bytes and is ~15x slower than over one packed int64 key.
    rows = keys if packed is None else packed
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[inverse.reshape(-1)]


def _pack_keys(keys: np.ndarray) -> np.ndarray | None:
    """(N, 3) integer voxel keys as one int64 each (21 bits per axis), or None when they do not fit."""
    if len(keys) == 0:
        return None
    lo = keys.min(axis=0)
    span = keys.max(axis=0) - lo
    if np.any(span >= 1 << 21):
        return None
    k = keys - lo
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def knn(points: np.ndarray, k: int, tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distances and indices (N, k) of the k nearest neighbours of every point (itself included)."""
    tree = tree or cKDTree(points)
    k = min(k, len(points))
    dist, idx = tree.query(points, k=k, workers=-1)
    return dist.reshape(len(points), k), idx.reshape(len(points), k)


def radius_pairs(points: np.ndarray, radius_m: float, tree: cKDTree | None = None) -> np.ndarray:
    """All unordered pairs (P, 2) of points closer than `radius_m`."""
    tree = tree or cKDTree(points)
    return tree.query_pairs(radius_m, output_type="ndarray")


def pca_normals(
    points: np.ndarray, k: int = 16, radius_m: float | None = None, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 3) float32 and curvature (N,) float32 = smallest eigenvalue / sum of eigenvalues,
    from PCA over the k nearest neighbours (restricted to `radius_m` when given; fewer than 3 → curvature 1).
    Normals are oriented to +z where they are not horizontal, so that flips do not split regions."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    normals = np.zeros((n, 3), np.float32)
    curvature = np.ones(n, np.float32)
    if n < 3:
        return normals, curvature
    tree = tree or cKDTree(pts)
    kk = min(k, n)
    for start in range(0, n, _CHUNK):
        stop = min(n, start + _CHUNK)
        dist, idx = tree.query(pts[start:stop], k=kk, workers=-1)
        dist, idx = dist.reshape(-1, kk), idx.reshape(-1, kk)
        valid = np.ones_like(dist, dtype=bool) if radius_m is None else dist <= radius_m
        nb = pts[idx]  # (B, k, 3)
        w = valid[..., None].astype(np.float64)
        count = w.sum(axis=1)  # (B, 1)
        mean = (nb * w).sum(axis=1) / np.maximum(count, 1)
        centred = (nb - mean[:, None, :]) * w
        cov = np.einsum("bki,bkj->bij", centred, centred) / np.maximum(count, 1)[:, :, None]
        evals, evecs = np.linalg.eigh(cov)
        nrm = evecs[:, :, 0]
        flip = nrm[:, 2] < 0
        nrm[flip] *= -1
        normals[start:stop] = nrm
        total = evals.sum(axis=1)
        curv = np.where(total > 0, evals[:, 0] / np.where(total > 0, total, 1), 0.0)
        curv[count[:, 0] < 3] = 1.0
        curvature[start:stop] = curv
    return normals, curvature


def graph_components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Component label (N,) of each of n nodes of the undirected graph of `pairs` (E, 2)."""
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels


def relabel_by_size(labels: np.ndarray, min_size: int) -> np.ndarray:
    """Segments as 1..S (largest first); segments smaller than `min_size` become 0."""
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    new_id = np.zeros(len(counts), np.int64)
    big = counts[order] >= min_size
    new_id[order[big]] = np.arange(1, big.sum() + 1)
    return new_id[inverse.reshape(-1)]


def threshold_region_growing(
    points: np.ndarray,
    normals: np.ndarray,
    colors: np.ndarray | None,
    radius_m: float,
    max_angle_deg: float,
    max_color_dist: float | None,
    min_size: int = 1,
) -> np.ndarray:
    """Region growing on normal and colour thresholds: points within `radius_m` join when their normals
    differ by less than `max_angle_deg` (sign-agnostic) and their RGB (0..1) differ by less than
    `max_color_dist`. Returns segment ids 1..S by size; segments under `min_size` points get 0."""
    pairs = radius_pairs(points, radius_m)
    n = len(points)
    if len(pairs) == 0:
        return relabel_by_size(np.arange(n), min_size)
    cos = np.abs(np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]))
    ok = cos >= np.cos(np.deg2rad(max_angle_deg))
    if colors is not None and max_color_dist is not None:
        rgb = np.asarray(colors, np.float32) / 255.0
        ok &= np.linalg.norm(rgb[pairs[:, 0]] - rgb[pairs[:, 1]], axis=1) < max_color_dist
    return relabel_by_size(graph_components(n, pairs[ok]), min_size)


def smoothness_region_growing(
    points: np.ndarray,
    normals: np.ndarray,
    curvature: np.ndarray,
    k: int = 16,
    max_angle_deg: float = 10.0,
    curvature_threshold: float = 0.05,
    min_size: int = 1,
) -> np.ndarray:
    """Smoothness-constraint region growing (Rabbani et al. 2006): regions grow across neighbours whose
    normals differ by less than `max_angle_deg`, but only points with curvature below the threshold keep
    growing (act as seeds). Equivalent vectorised form: connected components over smooth points, then each
    rough point joins the region of its smoothest qualifying neighbour."""
    pts = np.asarray(points)
    n = len(pts)
    _, idx = knn(pts, k + 1)
    src = np.repeat(np.arange(n), idx.shape[1])
    dst = idx.reshape(-1)
    keep = src != dst
    src, dst = src[keep], dst[keep]
    cos = np.abs(np.einsum("ij,ij->i", normals[src], normals[dst]))
    angle_ok = cos >= np.cos(np.deg2rad(max_angle_deg))
    smooth = curvature < curvature_threshold
    both = angle_ok & smooth[src] & smooth[dst]
    labels = graph_components(n, np.stack([src[both], dst[both]], axis=1))
    # Rough points attach to the smooth neighbour of lowest curvature that passes the angle test.
    attach = angle_ok & ~smooth[src] & smooth[dst]
    if attach.any():
        s, d = src[attach], dst[attach]
        order = np.lexsort((curvature[d], s))
        s, d = s[order], d[order]
        first = np.r_[True, s[1:] != s[:-1]]
        labels[s[first]] = labels[d[first]]
    return relabel_by_size(labels, min_size)


def attach_small_segments(points: np.ndarray, labels: np.ndarray, min_size: int) -> np.ndarray:
    """Segments with fewer than `min_size` points (and label 0) take the label of the nearest point
    of a large segment."""
    labels = np.asarray(labels).copy()
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    small = (counts[inverse.reshape(-1)] < min_size) | (labels == 0)
    if small.all() or not small.any():
        return labels
    tree = cKDTree(points[~small])
    _, nearest = tree.query(points[small], k=1, workers=-1)
    labels[small] = labels[~small][nearest]
    return labels


def group_pca(groups: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PCA normals (B, 3) float32 and curvature (B,) float32 of B padded point groups (B, k, 3), using only
    the entries where `valid` (B, k) is True; groups of fewer than 3 points get a zero normal and
    curvature 1. Normals are oriented to +z like `pca_normals`."""
    g = np.asarray(groups, dtype=np.float64)
    w = np.asarray(valid, dtype=np.float64)[..., None]
    count = w.sum(axis=1)  # (B, 1)
    mean = (g * w).sum(axis=1) / np.maximum(count, 1)
    centred = (g - mean[:, None, :]) * w
    cov = np.einsum("bki,bkj->bij", centred, centred) / np.maximum(count, 1)[:, :, None]
    evals, evecs = np.linalg.eigh(cov)
    nrm = evecs[:, :, 0]
    nrm[nrm[:, 2] < 0] *= -1
    total = evals.sum(axis=1)
    curv = np.where(total > 0, evals[:, 0] / np.where(total > 0, total, 1), 0.0)
    few = count[:, 0] < 3
    curv[few] = 1.0
    nrm[few] = 0.0
    return nrm.astype(np.float32), curv.astype(np.float32)


def block_sums(points: np.ndarray, values: np.ndarray, cell_m: float) -> np.ndarray:
    """For every point, the sums of `values` (N, K) over all points in the 3×3×3 block of `cell_m` voxels
    around its voxel: a fast, density-independent neighbourhood (about ±1.5 cells) in O(27 · V log V)."""
    vals = np.asarray(values, np.float64).reshape(len(points), -1)
    keys = voxel_keys(points, cell_m)
    keys -= keys.min(axis=0) - 1
    dims = keys.max(axis=0) + 2
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    uniq, inverse = np.unique(flat, return_inverse=True)
    per_voxel = np.zeros((len(uniq), vals.shape[1]))
    np.add.at(per_voxel, inverse.reshape(-1), vals)
    total = np.zeros_like(per_voxel)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                other = uniq + (dx * dims[1] + dy) * dims[2] + dz
                j = np.minimum(np.searchsorted(uniq, other), len(uniq) - 1)
                hit = uniq[j] == other
                total[hit] += per_voxel[j[hit]]
    return total[inverse.reshape(-1)]


def point_moments(centred: np.ndarray) -> np.ndarray:
    """Per point (N, 13): 1, x, y, z and the nine products x_i x_j — summed over any grouping, its PCA."""
    outer = (centred[:, :, None] * centred[:, None, :]).reshape(-1, 9)
    return np.concatenate([np.ones((len(centred), 1)), centred, outer], axis=1)


def _pca_of_moments(total: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean (G, 3), unit normal (G, 3) (sign-agnostic), eigenvalues (G, 3) as shares of their sum (ascending;
    the first is the curvature) and count (G,) of groups from their summed `point_moments` (G, 13)."""
    count = total[:, 0]
    n = np.maximum(count, 1)  # empty groups: zeros, not NaN
    mean = total[:, 1:4] / n[:, None]
    cov = total[:, 4:].reshape(-1, 3, 3) / n[:, None, None] - mean[:, :, None] * mean[:, None, :]
    evals, evecs = np.linalg.eigh(cov)
    evals = np.clip(evals, 0, None)
    sums = evals.sum(axis=1, keepdims=True)
    shares = np.where(sums > 0, evals / np.where(sums > 0, sums, 1), 0.0)
    return mean, evecs[:, :, 0], shares, count


def block_pca(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA over the 3×3×3 block of `cell_m` voxels around each point (as the crack study did):
    unit normals (N, 3) (sign-agnostic), curvature (N,) = smallest eigenvalue / sum, and point count (N,)."""
    pts = np.asarray(points, np.float64)
    q = pts - pts.mean(axis=0)
    _, normals, shares, count = _pca_of_moments(block_sums(q, point_moments(q), cell_m))
    return normals, shares[:, 0], count


def label_pca(points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCA of the points of each label 0..max: centroid (L, 3), unit normal (L, 3) (sign-agnostic), eigenvalues
    (L, 3) as shares of their sum, ascending (the first is the curvature), and point count (L,)."""
    pts = np.asarray(points, np.float64)
    origin = pts.mean(axis=0)  # conditioning
    q = pts - origin
    total = np.zeros((int(labels.max()) + 1, 13))
    np.add.at(total, labels, point_moments(q))
    mean, normals, shares, count = _pca_of_moments(total)
    return mean + origin, normals, shares, count


def point_spacing(points: np.ndarray, sample: int = 20_000, seed: int = 0) -> float:
    """Median distance from a point to its nearest neighbour (on a random sample of at most `sample` points)."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:
        return float("inf")
    tree = cKDTree(pts)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(pts), size=min(sample, len(pts)), replace=False)
    dist, _ = tree.query(pts[pick], k=2, workers=-1)
    return float(np.median(dist[:, 1]))
