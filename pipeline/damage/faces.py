"""An element's faces and their orthoimages: planes fitted to the element (a column's four sides, a wall's or a
slab's one), each face unrolled into images at the scan's resolution (grey level, intensity, depth behind the
fitted surface, point count) so that cracks can be sought as thin dark ridges on a flat picture.

Faces are found by sequential RANSAC on a sample (the largest plane first; a plane must hold a share of the
points and agree with their normals) and every point joins the nearest plane within reach. A curved surface
(a round column) comes out as several narrow planes, which leaves its edges to the edge mask of each face.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy import ndimage

from aftershock.pipeline.geometry import block_pca

MAX_FACES: Final = 6
_SAMPLE: Final = 6000
_TRIALS: Final = 300


@dataclass(frozen=True, slots=True)
class Face:
    """A fitted plane: a point on it (3,), in-plane axes u, v and outward normal (3, 3 rows), and its points."""

    origin: np.ndarray
    basis: np.ndarray
    members: np.ndarray  # indices into the element's points


@dataclass(frozen=True, slots=True)
class Ortho:
    """One face unrolled: images (H, W) and the pixel (row, col) of each of the face's points."""

    face: Face
    pixel_m: float
    count: np.ndarray  # points per pixel
    grey: np.ndarray  # mean log grey level (NaN where no point)
    intensity: np.ndarray  # mean log intensity (NaN where none)
    depth: np.ndarray  # mean signed offset from the fitted surface, metres, outward positive (NaN where none)
    chroma: np.ndarray  # (H, W, 2) mean r and g chromaticity (r, g over r + g + b; NaN where none or no colour)
    rows: np.ndarray
    cols: np.ndarray


def _plane_of(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    return centre, vt[2]


def fit_faces(points: np.ndarray, spacing_m: float, seed: int = 0) -> list[Face]:
    """The element's planar faces, largest first (see the module docstring). A face holds at least 5 % of the
    points; inliers lie within max(1.5 cm, 4 spacings) of the plane with normals within 30° of its own."""
    pts = np.asarray(points, np.float64)
    n = len(pts)
    rng = np.random.default_rng(seed)
    tol = max(0.015, 4 * spacing_m)
    normals, _, _ = block_pca(pts, max(3 * spacing_m, 0.01))
    pick = rng.choice(n, size=min(n, _SAMPLE), replace=False)
    sp, sn = pts[pick], normals[pick]
    free = np.ones(len(sp), bool)
    planes: list[tuple[np.ndarray, np.ndarray]] = []
    cos_tol = np.cos(np.deg2rad(30.0))
    while len(planes) < MAX_FACES and free.sum() >= 0.05 * len(sp):
        idx = np.flatnonzero(free)
        tri = idx[rng.integers(0, len(idx), size=(_TRIALS, 3))]
        a, b, c = sp[tri[:, 0]], sp[tri[:, 1]], sp[tri[:, 2]]
        nrm = np.cross(b - a, c - a)
        norm = np.linalg.norm(nrm, axis=1)
        ok = norm > 1e-9
        nrm = nrm[ok] / norm[ok, None]
        a = a[ok]
        dist = np.abs(np.einsum("tk,tnk->tn", nrm, sp[idx][None, :, :] - a[:, None, :]))
        agree = cos_tol <= np.abs(sn[idx] @ nrm.T).T
        support = ((dist <= tol) & agree).sum(axis=1)
        best = int(np.argmax(support))
        inl = idx[(dist[best] <= tol) & agree[best]]
        if len(inl) < 0.05 * len(sp):
            break
        centre, normal = _plane_of(sp[inl])
        d = np.abs((sp[idx] - centre) @ normal)
        inl = idx[(d <= tol) & (np.abs(sn[idx] @ normal) >= cos_tol)]
        if len(inl) < 0.05 * len(sp):
            break
        centre, normal = _plane_of(sp[inl])
        planes.append((centre, normal))
        free[inl] = False
    if not planes:
        centre, normal = _plane_of(sp)
        planes.append((centre, normal))
    centroid = pts.mean(axis=0)
    dist = np.stack([np.abs((pts - c) @ nv) for c, nv in planes], axis=1)
    nearest = dist.argmin(axis=1)
    near = dist[np.arange(n), nearest] <= 2 * tol
    _, _, vt = np.linalg.svd(sp - sp.mean(axis=0), full_matrices=False)
    long_axis = vt[0]
    faces = []
    for k, (centre, normal) in enumerate(planes):
        members = np.flatnonzero(near & (nearest == k))
        if len(members) < 0.02 * n:
            continue
        outward = normal if (centre - centroid) @ normal >= 0 or len(planes) == 1 else -normal
        if len(planes) == 1 and abs(outward[2]) > 0.5 and outward[2] < 0:
            outward = -outward  # a lone horizontal plane is seen from above
        v = long_axis - (long_axis @ outward) * outward
        if np.linalg.norm(v) < 0.3:  # the element's long axis is the face's normal: the face's own long axis
            q = pts[members] - pts[members].mean(axis=0)
            q = q - np.outer(q @ outward, outward)
            v = np.linalg.svd(q[:: max(1, len(q) // 5000)], full_matrices=False)[2][0]
        v = v / np.linalg.norm(v)
        u = np.cross(v, outward)
        faces.append(Face(centre, np.stack([u, v, outward]), members))
    return sorted(faces, key=lambda f: len(f.members), reverse=True)


def _fill(image: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised convolution: the Gaussian-weighted mean of the known pixels around each pixel."""
    num = ndimage.gaussian_filter(np.where(weight > 0, image, 0.0) * weight, sigma, mode="constant")
    den = ndimage.gaussian_filter(weight, sigma, mode="constant")
    return num / np.maximum(den, 1e-12)


def unroll(
    face: Face,
    points: np.ndarray,
    grey: np.ndarray,
    intensity: np.ndarray | None,
    pixel_m: float,
    detrend_m: float,
    chroma: np.ndarray | None = None,
) -> Ortho:
    """The face's orthoimages at `pixel_m` (see `Ortho`). The depth is the offset from the fitted plane less
    its smooth trend over `detrend_m` (the surface's own unevenness, a face fitted slightly askew)."""
    q = points[face.members] - face.origin
    uvw = q @ face.basis.T
    col = np.floor((uvw[:, 0] - uvw[:, 0].min()) / pixel_m).astype(np.int64)
    row = np.floor((uvw[:, 1] - uvw[:, 1].min()) / pixel_m).astype(np.int64)
    h, w = int(row.max()) + 1, int(col.max()) + 1
    flat = row * w + col
    count = np.bincount(flat, minlength=h * w).astype(np.float64)

    def mean_of(values: np.ndarray) -> np.ndarray:
        s = np.bincount(flat, weights=values, minlength=h * w)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (s / count).reshape(h, w)

    cnt = count.reshape(h, w)
    depth = mean_of(uvw[:, 2])
    has = cnt > 0
    trend = _fill(np.nan_to_num(depth), has.astype(np.float64), detrend_m / pixel_m)
    depth = depth - trend
    inten = mean_of(intensity[face.members]) if intensity is not None else np.full((h, w), np.nan)
    if chroma is not None:
        chro = np.stack([mean_of(chroma[face.members, i]) for i in range(2)], axis=2)
    else:
        chro = np.full((h, w, 2), np.nan)
    return Ortho(face, pixel_m, cnt, mean_of(grey[face.members]), inten, depth, chro, row, col)
