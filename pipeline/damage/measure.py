"""Crack instances and their size: connected components of crack points, each measured on its own
best-fit plane by the exact minimum-area rectangle (tried against every hull edge, so any orientation),
and the point-wise / per-crack scores against a truth mask."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from pipeline.geometry import radius_pairs
from pipeline.types import Crack

_EPS: Final = 1e-12


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


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and rows of in-plane axes + normal (3, 3): rows 0, 1 span the plane, row 2 is the normal."""
    pts = np.asarray(points, np.float64)
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    if vt.shape[0] < 3:  # fewer than three points: complete the basis
        vt = np.linalg.qr(np.vstack([vt, np.eye(3)]).T)[0].T[:3]
    if np.linalg.det(vt) < 0:
        vt[2] *= -1
    return centroid, vt


@dataclass(frozen=True, slots=True)
class Rectangle:
    """A rectangle in a plane: centre (2,), unit direction of the long side (2,), long and short side."""

    center: np.ndarray
    axis: np.ndarray
    length: float
    width: float


def min_area_rectangle(xy: np.ndarray) -> Rectangle:
    """Exact minimum-area enclosing rectangle of 2-D points: one side lies on a hull edge (Freeman & Shapira),
    so every hull edge direction is tried at once, vectorised. Degenerate input (collinear, < 3 points)
    gives the extent along the principal direction and zero width."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return Rectangle(np.zeros(2), np.array([1.0, 0.0]), 0.0, 0.0)
    try:
        hull = xy[ConvexHull(xy).vertices] if len(xy) >= 3 else None
    except QhullError:
        hull = None
    if hull is None:
        centre = xy.mean(axis=0)
        if len(xy) == 1:
            return Rectangle(centre, np.array([1.0, 0.0]), 0.0, 0.0)
        _, _, vt = np.linalg.svd(xy - centre, full_matrices=False)
        u = vt[0]
        t = (xy - centre) @ u
        return Rectangle(centre + u * (t.max() + t.min()) / 2, u, float(t.max() - t.min()), 0.0)
    edges = np.roll(hull, -1, axis=0) - hull
    edges = edges[np.linalg.norm(edges, axis=1) > _EPS]
    u = edges / np.linalg.norm(edges, axis=1, keepdims=True)  # (E, 2) edge directions
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    a = hull @ u.T  # (H, E) coordinates of every hull vertex along every edge direction
    b = hull @ v.T
    ext_a = a.max(axis=0) - a.min(axis=0)
    ext_b = b.max(axis=0) - b.min(axis=0)
    best = int(np.argmin(ext_a * ext_b))
    mid_a = (a[:, best].max() + a[:, best].min()) / 2
    mid_b = (b[:, best].max() + b[:, best].min()) / 2
    centre = mid_a * u[best] + mid_b * v[best]
    if ext_a[best] >= ext_b[best]:
        return Rectangle(centre, u[best], float(ext_a[best]), float(ext_b[best]))
    return Rectangle(centre, v[best], float(ext_b[best]), float(ext_a[best]))


def crack_size(points: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
    """Length, width, centre (3,), length axis (3,) and plane normal (3,) of one crack's points, measured on
    the crack's own best-fit plane."""
    centroid, basis = fit_plane(points)
    xy = (np.asarray(points, np.float64) - centroid) @ basis[:2].T
    rect = min_area_rectangle(xy)
    centre = centroid + rect.center @ basis[:2]
    axis = rect.axis @ basis[:2]
    return rect.length, rect.width, centre, axis / max(np.linalg.norm(axis), _EPS), basis[2]


def components(points: np.ndarray, link_m: float, min_points: int) -> np.ndarray:
    """Connected components of points closer than `link_m`: ids 1..K by decreasing size, 0 = too small."""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = radius_pairs(points, link_m)
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    new_id = np.zeros(len(counts), np.int64)
    big = counts[order] >= min_points
    new_id[order[big]] = np.arange(1, big.sum() + 1)
    return new_id[inverse.reshape(-1)]


def measure_cracks(
    points: np.ndarray,
    mask: np.ndarray,
    link_m: float,
    min_points: int,
    severe_width_m: float,
    spacing_m: float = 0.0,
) -> tuple[list[Crack], np.ndarray]:
    """Each connected group of crack points (`mask`) as a `Crack`, largest first, and the per-point crack id
    (0 = not crack or a group under `min_points`). A width is never reported below the point spacing:
    nothing narrower can be seen, so such widths are clamped to the spacing and marked unresolved."""
    mask = np.asarray(mask, bool)
    ids = np.zeros(len(points), np.int64)
    idx = np.flatnonzero(mask)
    ids[idx] = components(points[idx], link_m, min_points)
    cracks: list[Crack] = []
    for k in range(1, int(ids.max(initial=0)) + 1):  # one iteration per crack, not per point
        pts = points[ids == k]
        length, width, centre, axis, normal = crack_size(pts)
        resolved = width >= spacing_m
        width = max(width, spacing_m)
        cracks.append(
            Crack(
                instance_id=k,
                center=centre,
                length_m=float(length),
                width_m=float(width),
                num_points=len(pts),
                axis=axis,
                normal=normal,
                severe=bool(width >= severe_width_m),
                width_resolved=bool(resolved),
            )
        )
    return cracks, ids


@dataclass(frozen=True, slots=True)
class Scores:
    """Point-wise precision/recall/F1 and size errors of the main (largest) true crack, two ways:
    `length_error_m`/`width_error_m` as the study measured them (the detected part of the main true crack,
    i.e. main truth ∩ prediction, against the whole main true crack), and `instance_*` (stricter: the
    whole predicted crack instance that overlaps the main true crack most, false positives included)."""

    precision: float
    recall: float
    f1: float
    length_error_m: float
    width_error_m: float
    true_length_m: float
    true_width_m: float
    found_length_m: float
    found_width_m: float
    instance_length_error_m: float
    instance_width_error_m: float


def score(points: np.ndarray, predicted: np.ndarray, truth: np.ndarray, link_m: float, min_points: int) -> Scores:
    """Precision, recall and F1 over the points of the evaluated cloud, and the size errors (see `Scores`)."""
    predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
    tp = float(np.sum(predicted & truth))
    precision = tp / max(float(predicted.sum()), 1.0)
    recall = tp / max(float(truth.sum()), 1.0)
    f1 = 2 * precision * recall / max(precision + recall, _EPS)
    nan = float("nan")
    if not truth.any():
        return Scores(precision, recall, f1, nan, nan, nan, nan, nan, nan, nan, nan)
    true_ids = np.zeros(len(points), np.int64)
    true_ids[truth] = components(points[truth], link_m, 1)
    main = true_ids == 1
    true_len, true_wid, *_ = crack_size(points[main])
    found = main & predicted
    if found.sum() < 3:
        return Scores(precision, recall, f1, nan, nan, true_len, true_wid, nan, nan, nan, nan)
    found_len, found_wid, *_ = crack_size(points[found])
    pred_ids = np.zeros(len(points), np.int64)
    pred_ids[predicted] = components(points[predicted], link_m, min_points)
    overlap = np.bincount(pred_ids[main], minlength=int(pred_ids.max(initial=0)) + 1)
    overlap[0] = 0
    inst_len = inst_wid = nan
    if overlap.max(initial=0) > 0:
        inst_len, inst_wid, *_ = crack_size(points[pred_ids == int(np.argmax(overlap))])
    return Scores(
        precision,
        recall,
        f1,
        abs(found_len - true_len),
        abs(found_wid - true_wid),
        true_len,
        true_wid,
        found_len,
        found_wid,
        abs(inst_len - true_len),
        abs(inst_wid - true_wid),
    )
