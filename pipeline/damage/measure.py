"""Crack instances and their size: connected components of crack points, each measured on its own
best-fit plane by the exact minimum-area rectangle (tried against every hull edge, so any orientation),
and the point-wise / per-crack scores against a truth mask."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Final

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from aftershock.pipeline.geometry import graph_components, radius_pairs, relabel_by_size
from aftershock.pipeline.types import Crack

_EPS: Final = 1e-12


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
    """Length, width, centre (3,), length axis (3,) and plane normal (3,) of the minimum-area rectangle of
    one crack's points, measured on the crack's own best-fit plane (the rectangle's width is the extent of
    the whole group across its long side, not the crack's opening: see `crack_shape`)."""
    centroid, basis = fit_plane(points)
    xy = (np.asarray(points, np.float64) - centroid) @ basis[:2].T
    rect = min_area_rectangle(xy)
    centre = centroid + rect.center @ basis[:2]
    axis = rect.axis @ basis[:2]
    return rect.length, rect.width, centre, axis / max(np.linalg.norm(axis), _EPS), basis[2]


@dataclass(frozen=True, slots=True)
class CrackShape:
    """One crack measured on its best-fit plane.

    `length`, `rect_width`, `centre` and `axis` are those of the exact minimum-area rectangle; `width` is the
    crack's opening: the median, over slices across the rectangle's long axis, of the extent of each strand
    of points across its own local direction (the strand's principal axis); `max_width` the 90th percentile
    of the same (both at most `rect_width`). A strand several point rows long spans nearly the whole
    opening, so the extent is not corrected for the spacing; an opening narrower than the spacing measures
    (near) zero."""

    length: float
    rect_width: float
    width: float
    max_width: float
    centre: np.ndarray
    axis: np.ndarray
    normal: np.ndarray
    strands: int  # slices-strands the width was measured on (0 = too few points: width = rectangle width)


def _local_opening(xy: np.ndarray, spacing_m: float, sample: int = 2000) -> float:
    """Typical opening of a crack from how many of its points lie around each one: a strip of width w
    holds about 2 r w / h² points within r of a point on it (h the spacing). Local, so that a network of
    crossing cracks is not taken for one wide crack; saturates near 1.6 r for a broad band."""
    radius = 5 * spacing_m
    pick = xy[:: max(1, len(xy) // sample)]
    count = cKDTree(xy).query_ball_point(pick, radius, return_length=True, workers=-1)
    return float(np.median(count)) * spacing_m**2 / (2 * radius)


def _strand_widths(xy: np.ndarray, rect: Rectangle, spacing_m: float, gap_m: float) -> np.ndarray:
    """Width across each strand: the rectangle's long axis is cut into slices a few crack widths long; the
    points of a slice split into strands where they are more than `gap_m` apart across it; each strand's
    extent is measured across its own principal direction (a straight strip cut obliquely still measures
    its true width). Strands of fewer than three points are left out."""
    h = max(spacing_m, _EPS)
    u = rect.axis
    v = np.array([-u[1], u[0]])
    t = (xy - rect.center) @ u
    s = (xy - rect.center) @ v
    slice_m = 3.0 * max(_local_opening(xy, h), 2 * h)
    cut = np.floor((t - t.min()) / slice_m).astype(np.int64)
    order = np.lexsort((s, cut))
    cut, s_o, xy_o = cut[order], s[order], xy[order]
    new = np.r_[True, (np.diff(cut) != 0) | (np.diff(s_o) > gap_m)]
    strand = np.cumsum(new) - 1
    count = np.bincount(strand)
    mean = np.stack([np.bincount(strand, xy_o[:, i]) for i in range(2)], axis=1) / count[:, None]
    d = xy_o - mean[strand]
    cxx = np.bincount(strand, d[:, 0] * d[:, 0])
    cyy = np.bincount(strand, d[:, 1] * d[:, 1])
    cxy = np.bincount(strand, d[:, 0] * d[:, 1])
    angle = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # principal direction of each strand
    spread = np.sqrt((cxx - cyy) ** 2 + 4 * cxy**2)
    oriented = (cxx + cyy + spread) >= 2.25 * (cxx + cyy - spread)  # principal axes at least 1.5 : 1
    # a strand wider than long (a broad band cut short) has no direction of its own: across the long axis
    angle = np.where(oriented, angle, np.arctan2(u[1], u[0]))
    across = d[:, 0] * -np.sin(angle[strand]) + d[:, 1] * np.cos(angle[strand])
    starts = np.flatnonzero(new)
    extent = np.maximum.reduceat(across, starts) - np.minimum.reduceat(across, starts)
    return extent[count >= 3]


def crack_shape(
    points: np.ndarray, spacing_m: float, gap_m: float | None = None, surface: np.ndarray | None = None
) -> CrackShape:
    """Length and orientation (minimum-area rectangle) and opening width (see `CrackShape`) of one crack's
    points on the best-fit plane of `surface` (the element's points around the crack; default the crack's own
    points, which for a thin crack are nearly a line: the plane through them then tilts into the crack's
    depth and widens it). Strands of a slice are split at gaps over `gap_m` (default 2 spacings)."""
    pts = np.asarray(points, np.float64)
    centroid, basis = fit_plane(pts if surface is None or len(surface) < 3 else surface)
    centroid = pts.mean(axis=0)
    xy = (pts - centroid) @ basis[:2].T
    rect = min_area_rectangle(xy)
    centre = centroid + rect.center @ basis[:2]
    axis = rect.axis @ basis[:2]
    axis = axis / max(np.linalg.norm(axis), _EPS)
    widths = _strand_widths(xy, rect, spacing_m, gap_m or 2 * spacing_m) if len(xy) >= 3 else np.zeros(0)
    if len(widths) == 0:
        width = max_width = max(rect.width, spacing_m)
    else:
        # a strand measured across a poorly defined direction can come out wider than the whole group
        width, max_width = (min(float(np.percentile(widths, q)), rect.width) for q in (50, 90))
    return CrackShape(rect.length, rect.width, width, max_width, centre, axis, basis[2], len(widths))


def resolvable_width(surface: np.ndarray, normal: np.ndarray, spacing_m: float, sample: int = 2000) -> float:
    """The narrowest opening the scan can measure at a crack: two samples across it (Nyquist: twice the local
    point spacing) widened by the surface noise on both sides of it (twice the robust spread of the surface's
    offsets from its plane), since the noise blurs where an opening starts and ends. Local spacing and noise are
    those of `surface`, the element's points around the crack; fewer than 10 of them: twice `spacing_m`."""
    pts = np.asarray(surface, np.float64)
    if len(pts) < 10:
        return 2.0 * spacing_m
    pick = pts[:: max(1, len(pts) // sample)]
    dist, _ = cKDTree(pts).query(pick, k=2, workers=-1)
    local = float(np.median(dist[:, 1]))
    offset = (pts - pts.mean(axis=0)) @ np.asarray(normal, np.float64)
    noise = 1.4826 * float(np.median(np.abs(offset - np.median(offset))))
    return 2.0 * local + 2.0 * noise


def surface_around(tree: cKDTree, points: np.ndarray, members: np.ndarray, reach_m: float) -> np.ndarray:
    """The element's points (crack or not) within `reach_m` of a crack's points: the surface the crack is
    measured on. Queried from at most 500 of the crack's points, spread along it."""
    step = max(1, len(members) // 500)
    near = tree.query_ball_point(points[members[::step]], reach_m, workers=-1)
    return points[np.unique(np.concatenate([np.asarray(n, np.int64) for n in near]))]


def supported(
    points: np.ndarray, mask: np.ndarray, radius_m: float, min_share: float, by: np.ndarray | None = None
) -> np.ndarray:
    """Points of `mask` of which at least `min_share` of the points within `radius_m` (crack or not) are in
    `by` (default `mask` itself). An open crack is a groove: its points have crack points all around them; a
    false positive at the edge of a smoothed halo or alone on sound concrete has mostly sound neighbours, and
    removed before linking it can neither widen a crack nor bridge two. (A flat, unrecessed crack one point
    wide would not pass either: the rule suits cracks wider than about a third of `radius_m`.)"""
    mask = np.asarray(mask, bool).copy()
    idx = np.flatnonzero(mask)
    if min_share <= 0 or radius_m <= 0 or len(idx) == 0:
        return mask
    src = idx if by is None else np.flatnonzero(by)
    if len(src) == 0:
        return np.zeros_like(mask)
    crack = cKDTree(points[src]).query_ball_point(points[idx], radius_m, return_length=True, workers=-1)
    every = cKDTree(points).query_ball_point(points[idx], radius_m, return_length=True, workers=-1)
    mask[idx[crack < min_share * every]] = False
    return mask


def components(points: np.ndarray, link_m: float, min_points: int) -> np.ndarray:
    """Connected components of points closer than `link_m`: ids 1..K by decreasing size, 0 = too small."""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    return relabel_by_size(graph_components(n, radius_pairs(points, link_m)), min_points)


def measure_cracks(
    points: np.ndarray,
    mask: np.ndarray,
    link_m: float,
    min_points: int,
    severe_width_m: float,
    spacing_m: float = 0.0,
    min_elongation: float = 0.0,
    surface_m: float = 0.02,
    core: np.ndarray | None = None,
) -> tuple[list[Crack], np.ndarray]:
    """Each connected group of crack points (`mask`) as a `Crack`, largest first, and the per-point crack id
    (0 = not crack, a group under `min_points`, or a blob: length under `min_elongation` times its opening
    width). Groups are linked, and length and orientation measured, on all of `mask`; the opening width only
    on the group's `core` points when given (e.g. those whose neighbours were detected before smoothing:
    smoothing joins a crack's speckled detections but also rims it with sound concrete). A width is never
    reported below the point spacing: nothing narrower can be seen, so such widths are clamped to the
    spacing and marked unresolved."""
    mask = np.asarray(mask, bool)
    ids = np.zeros(len(points), np.int64)
    idx = np.flatnonzero(mask)
    groups = components(points[idx], link_m, min_points)
    tree = cKDTree(points) if len(idx) else None
    reach = max(surface_m, 2 * link_m)
    cracks: list[Crack] = []
    for k in range(1, int(groups.max(initial=0)) + 1):  # one iteration per crack, not per point
        members = idx[groups == k]
        surface = surface_around(tree, points, members, reach)
        shape = crack_shape(points[members], spacing_m, link_m, surface)
        inner = members[core[members]] if core is not None else members
        if len(inner) >= 3 and len(inner) < len(members):
            opening = crack_shape(points[inner], spacing_m, link_m, surface)
            shape = replace(shape, width=opening.width, max_width=opening.max_width, strands=opening.strands)
        if shape.length < min_elongation * shape.width:
            continue
        ids[members] = len(cracks) + 1
        resolvable = resolvable_width(surface, shape.normal, spacing_m)
        resolved = shape.width >= resolvable
        width = max(shape.width, spacing_m)
        area = len(members) * spacing_m**2  # each point stands for a spacing-sized square of the surface
        cracks.append(
            Crack(
                instance_id=len(cracks) + 1,
                center=shape.centre,
                length_m=float(shape.length),
                width_m=float(width),
                num_points=len(members),
                axis=shape.axis,
                normal=shape.normal,
                severe=bool(resolved and width >= severe_width_m),  # an unresolved width is only a bound
                width_resolved=bool(resolved),
                max_width_m=float(max(shape.max_width, spacing_m)),
                rect_width_m=float(shape.rect_width),
                area_width_m=float(area / max(shape.length, _EPS)),
                resolvable_m=float(resolvable),
            )
        )
    return cracks, ids


def keep_cracks(cracks: list[Crack], ids: np.ndarray, keep: list[bool]) -> tuple[list[Crack], np.ndarray]:
    """The cracks with `keep` True, renumbered 1..K in their order, and the per-point ids to match (the points of
    the others are no crack, id 0)."""
    new_id = np.zeros(len(cracks) + 1, np.int64)
    kept: list[Crack] = []
    for c, k in zip(cracks, keep, strict=True):  # one renumbering per crack
        if k:
            new_id[c.instance_id] = len(kept) + 1
            c.instance_id = len(kept) + 1
            kept.append(c)
    return kept, new_id[ids]


def keep_narrow(
    cracks: list[Crack], ids: np.ndarray, points: int, max_share: float, min_elongation: float
) -> tuple[list[Crack], np.ndarray]:
    """The cracks that are narrow (`keep_cracks`): at least `min_elongation` times longer than their mean width
    (`Crack.area_width_m`: area over length; a stain or a shaded patch is about as wide as it is long, however
    its opening measures) and holding at most `max_share` of the element's `points` (a whole face that scores
    high is lit differently, not cracked)."""
    keep = [c.num_points <= max_share * points and c.length_m >= min_elongation * c.area_width_m for c in cracks]
    return keep_cracks(cracks, ids, keep)


@dataclass(frozen=True, slots=True)
class CrackMatch:
    """One true crack (a connected component of the truth mask, linked and measured exactly as the reported
    cracks are) and the reported crack holding most of its points (`crack_id` 0: none holds a third)."""

    true_length_m: float
    true_width_m: float
    true_points: int
    crack_id: int
    length_m: float
    width_m: float


@dataclass(frozen=True, slots=True)
class Scores:
    """Point-wise precision/recall/F1, and the size errors of what a field team reads: the main (largest)
    true crack against the whole reported crack that holds most of its points (`length_error_m`,
    `width_error_m`; false positives linked onto it included; true groups that are blobs, not cracks, are
    left out as the reported cracks leave them out), the median of the same over every true crack
    that was found (`median_*`), and every match. Widths are openings (`CrackShape.width`) clamped to the
    point spacing on both sides. `study_*` are the study's errors: the detected part of the main true crack
    (truth ∩ prediction) against the whole main true crack, both by the minimum-area rectangle — they never
    see a false positive, so they flatter."""

    precision: float
    recall: float
    f1: float
    length_error_m: float
    width_error_m: float
    true_length_m: float
    true_width_m: float
    found_length_m: float
    found_width_m: float
    median_length_error_m: float
    median_width_error_m: float
    true_cracks: int
    found_cracks: int
    study_length_error_m: float
    study_width_error_m: float
    matches: tuple[CrackMatch, ...] = field(default=())
    true_blobs: int = 0


def score(
    points: np.ndarray,
    predicted: np.ndarray,
    truth: np.ndarray,
    link_m: float,
    min_points: int,
    spacing_m: float,
    crack_ids: np.ndarray,
    cracks: list[Crack],
    min_elongation: float = 0.0,
) -> Scores:
    """Precision, recall and F1 of the crack points `predicted`, and the size errors of the reported
    `cracks` (per-point ids `crack_ids`) against the true cracks of `truth` (see `Scores`). True groups
    shorter than `min_elongation` times their width (spalls, not cracks) are left out of the size errors
    as they are left out of the reported cracks, and counted in `true_blobs`."""
    predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
    tp = float(np.sum(predicted & truth))
    precision = tp / max(float(predicted.sum()), 1.0)
    recall = tp / max(float(truth.sum()), 1.0)
    f1 = 2 * precision * recall / max(precision + recall, _EPS)
    nan = float("nan")
    idx = np.flatnonzero(truth)
    groups = components(points[idx], link_m, min_points) if len(idx) else np.zeros(0, np.int64)
    if groups.max(initial=0) == 0:
        return Scores(precision, recall, f1, nan, nan, nan, nan, nan, nan, nan, nan, 0, 0, nan, nan, (), 0)
    tree = cKDTree(points)
    reach = 2 * link_m
    matches = []
    blobs = 0
    for k in range(1, int(groups.max()) + 1):  # one iteration per true crack
        members = idx[groups == k]
        shape = crack_shape(points[members], spacing_m, link_m, surface_around(tree, points, members, reach))
        if shape.length < min_elongation * shape.width:
            blobs += 1
            continue
        overlap = np.bincount(crack_ids[members], minlength=len(cracks) + 1)
        overlap[0] = 0
        best = int(np.argmax(overlap))
        found = best > 0 and overlap[best] * 3 >= len(members)
        c = cracks[best - 1] if found else None
        matches.append(
            CrackMatch(
                shape.length,
                max(shape.width, spacing_m),
                len(members),
                best if found else 0,
                c.length_m if c else nan,
                c.width_m if c else nan,
            )
        )
    if not matches:
        return Scores(precision, recall, f1, nan, nan, nan, nan, nan, nan, nan, nan, 0, 0, nan, nan, (), blobs)
    main = matches[0]
    found_m = [m for m in matches if m.crack_id]
    dl = [abs(m.length_m - m.true_length_m) for m in found_m]
    dw = [abs(m.width_m - m.true_width_m) for m in found_m]
    main_pts = idx[groups == 1]  # the study's main crack: the largest true group, whatever its shape
    study_l = study_w = nan
    hit = main_pts[predicted[main_pts]]
    if len(hit) >= 3:
        tl, tw, *_ = crack_size(points[main_pts])
        fl, fw, *_ = crack_size(points[hit])
        study_l, study_w = abs(fl - tl), abs(fw - tw)
    return Scores(
        precision,
        recall,
        f1,
        abs(main.length_m - main.true_length_m),
        abs(main.width_m - main.true_width_m),
        main.true_length_m,
        main.true_width_m,
        main.length_m,
        main.width_m,
        float(np.median(dl)) if dl else nan,
        float(np.median(dw)) if dw else nan,
        len(matches),
        len(found_m),
        study_l,
        study_w,
        tuple(matches),
        blobs,
    )
