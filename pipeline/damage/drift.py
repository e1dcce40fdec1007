"""Story drift and tilt: floor and ceiling slabs from the point density along the up axis, one RANSAC plane
per slab face, and each upper slab's horizontal drift and tilt against the lowest one.

Tilt is the slab plane's. Drift is how far a slab's top surface moved horizontally at the building centre:
summed story by story from how far each story's walls and columns lean between its floor and its ceiling
(their foot and head read next to the slabs, with the slabs' own turn and thickness accounted for).

Where "up" comes from is stated in every result (`gravity`):
- `frame-z`: the input frame's z axis is taken as vertical (a map registered from a levelled start, or a
  simulator world);
- `ground-plane`: the lowest slab's plane is taken as level; the cloud is turned so that its normal is z
  before the stories are measured (tilts are always against the lowest plane either way).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

import numpy as np
from scipy.ndimage import median_filter

from aftershock.pipeline.config import DriftConfig
from aftershock.pipeline.types import Story

_MIN_SLAB_POINTS: Final = 50
_RANSAC_SCORE_POINTS: Final = 4000  # hypotheses are scored on a sample; the winner is refined on all points
_MIN_END_POINTS: Final = 20  # points in the window next to a wall's foot or head
NOT_MEASURED_ONE_SLAB: Final = "one slab found: drift and tilt need a second slab to be measured against"
REFERENCE_SLAB: Final = "the lowest slab: the reference the other slabs' drift and tilt are measured against"


class Gravity(StrEnum):
    FRAME_Z = "frame-z"
    GROUND_PLANE = "ground-plane"


@dataclass(slots=True)
class DriftResult:
    stories: list[Story]
    gravity: str
    slab_bands: list[tuple[float, float]] = field(default_factory=list)  # z ranges taken as slabs
    notes: list[str] = field(default_factory=list)


def slab_bands(
    z: np.ndarray, bin_m: float, ratio: float, neighbourhood: int, merge_m: float
) -> list[tuple[float, float]]:
    """z ranges whose point density is more than `ratio` times the median of the surrounding bins; bands
    closer than `merge_m` (the top and underside of one slab) are joined."""
    if len(z) == 0:
        return []
    lo = float(z.min())
    edges = lo + bin_m * np.arange(int(np.ceil((z.max() - lo) / bin_m)) + 2)
    counts, _ = np.histogram(z, bins=edges)
    return bands_of_counts(counts, edges, ratio, neighbourhood, merge_m)


def bands_of_counts(
    counts: np.ndarray, edges: np.ndarray, ratio: float, neighbourhood: int, merge_m: float
) -> list[tuple[float, float]]:
    """`slab_bands` of a height histogram (`counts` per bin between `edges`): the one test of a story slab,
    shared by drift and the structure model (which keeps its histogram up to date as the map grows)."""
    size = 2 * (neighbourhood // 2) + 1
    local = median_filter(counts.astype(np.float64), size=size, mode="constant", cval=0.0)
    # Around an empty stretch the median is 0; a slab then needs at least the median of all non-empty bins.
    floor = np.median(counts[counts > 0]) if np.any(counts > 0) else 0.0
    slab = counts > ratio * np.maximum(local, floor * 0.5)
    bands: list[tuple[float, float]] = []
    idx = np.flatnonzero(slab)
    if len(idx) == 0:
        return bands
    splits = np.flatnonzero(np.diff(idx) > 1) + 1
    for run in np.split(idx, splits):  # one iteration per slab band
        start, stop = float(edges[run[0]]), float(edges[run[-1] + 1])
        if bands and start - bands[-1][1] < merge_m:
            bands[-1] = (bands[-1][0], stop)
        else:
            bands.append((start, stop))
    return bands


def fit_plane_lsq(points: np.ndarray) -> np.ndarray:
    """Least-squares plane (a, b, c, d), unit normal with c ≥ 0."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    n = vt[-1] if vt[-1, 2] >= 0 else -vt[-1]
    return np.append(n, -n @ centroid)


def ransac_plane(
    points: np.ndarray, threshold_m: float, iterations: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Plane (4,) and inlier mask: all hypotheses drawn and scored at once on a sample, the best refined by
    least squares over its inliers among all points."""
    n = len(points)
    tri = points[rng.integers(0, n, size=(iterations, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    good = norm > 1e-12
    if not good.any():  # every triple drawn lies on one line: no plane to find
        return np.array([0.0, 0.0, 1.0, 0.0]), np.zeros(n, bool)
    normals, tri = normals[good] / norm[good, None], tri[good]
    d = -np.einsum("ij,ij->i", normals, tri[:, 0])
    sample = points[rng.choice(n, size=min(n, _RANSAC_SCORE_POINTS), replace=False)]
    score = sample @ normals.T  # (points, hypotheses), worked in place: one temporary
    score += d
    np.abs(score, out=score)
    support = (score < threshold_m).sum(axis=0)
    best = int(np.argmax(support))
    plane = np.append(normals[best], d[best])
    before = None
    for _ in range(3):  # refine: least squares on the inliers, then re-select them
        inliers = np.abs(points @ plane[:3] + plane[3]) < threshold_m
        if before is not None and np.array_equal(inliers, before):
            return plane, inliers  # the plane was fitted on these: it would come out the same
        if inliers.sum() < 3:
            break
        plane = fit_plane_lsq(points[inliers])
        before = inliers
    inliers = np.abs(points @ plane[:3] + plane[3]) < threshold_m
    return plane, inliers


def _level(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) that takes `normal` to +z by the shortest turn."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(normal, z)
    s, c = np.linalg.norm(v), float(normal @ z)
    if s < 1e-12:
        return np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / s**2)


def tilt_angles(normal: np.ndarray) -> tuple[float, float, float]:
    """Tilt of a unit normal from +z in degrees: about x (positive = turned from +z towards −y), about y
    (towards +x), and the total angle."""
    n = normal / np.linalg.norm(normal)
    about_x = np.degrees(np.arctan2(-n[1], n[2]))
    about_y = np.degrees(np.arctan2(n[0], n[2]))
    total = np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0)))
    return float(about_x), float(about_y), float(total)


def footprint_centre(points: np.ndarray) -> np.ndarray:
    """Horizontal (x, y) centre of a slab surface: the middle of its extent, trimmed of a few stray points."""
    lo = np.percentile(points[:, :2], 0.2, axis=0)
    hi = np.percentile(points[:, :2], 99.8, axis=0)
    return (lo + hi) / 2


@dataclass(slots=True)
class _Surface:
    plane: np.ndarray
    centre: np.ndarray
    points: int
    height: float


def _surfaces(band: np.ndarray, cfg: DriftConfig, rng: np.random.Generator) -> list[_Surface]:
    """The horizontal surfaces of one slab band, lowest first: its underside (a ceiling) and/or its top (a
    floor), when both were seen. A second plane with open space between it and the first (beam bottoms
    under a roof seen only from below) is not the slab's other face."""
    out: list[_Surface] = []
    rest = band
    for _ in range(2):
        if len(rest) < _MIN_SLAB_POINTS:
            break
        plane, inliers = ransac_plane(rest, cfg.ransac_threshold_m, cfg.ransac_iterations, rng)
        count = int(inliers.sum())
        if count < _MIN_SLAB_POINTS or abs(plane[2]) < np.cos(np.deg2rad(cfg.max_slab_tilt_deg)):
            break
        if out and count < 0.2 * out[0].points:
            break
        on = rest[inliers]
        rest = rest[~inliers]
        if out and _between(rest, out[0].plane, plane) > 0.5 * count:
            break  # open space between them (beam sides): beam bottoms under a ceiling, not a slab's two faces
        out.append(_Surface(plane, footprint_centre(on), count, float(np.median(on[:, 2]))))
    return sorted(out, key=lambda s: s.height)


def _between(pts: np.ndarray, a: np.ndarray, b: np.ndarray, margin_m: float = 0.03) -> int:
    """Points strictly between two nearly horizontal planes (none inside a solid slab)."""
    za = -(pts[:, :2] @ a[:2] + a[3]) / a[2]
    zb = -(pts[:, :2] @ b[:2] + b[3]) / b[2]
    lo, hi = np.minimum(za, zb), np.maximum(za, zb)
    return int(np.count_nonzero((pts[:, 2] > lo + margin_m) & (pts[:, 2] < hi - margin_m)))


@dataclass(slots=True)
class _Wall:
    """One tall vertical face of a story: horizontal unit normal, centroid (x, y), how far its top moved
    against its bottom along the normal (m), and its support."""

    normal: np.ndarray
    centroid: np.ndarray
    lean: float
    points: int


def story_fraction(pts: np.ndarray, floor: np.ndarray, ceiling: np.ndarray) -> np.ndarray:
    """Each point's height as a fraction of the local story height: 0 on the floor plane, 1 on the ceiling
    plane, measured straight up at the point (tilted slabs make the story taller on one side)."""
    zf = -(pts[:, :2] @ floor[:2] + floor[3]) / floor[2]
    zc = -(pts[:, :2] @ ceiling[:2] + ceiling[3]) / ceiling[2]
    return (pts[:, 2] - zf) / np.maximum(zc - zf, 1e-6)


def _line(s: np.ndarray, offset: np.ndarray, degree: int = 1) -> np.ndarray | None:
    """Straight line (slope, intercept; or a polynomial of `degree`) of offset against s, refitted twice without
    points more than three deviations (at least 2 mm) off it: door leaves and frames flush with a wall do not
    lean with it."""
    keep = np.ones(len(s), bool)
    line = None
    for _ in range(3):
        if keep.sum() < _MIN_END_POINTS or np.ptp(s[keep]) < 0.03:
            return None
        line = np.polyfit(s[keep], offset[keep], degree)
        res = np.abs(np.polyval(line, s) - offset)
        keep = res < max(3.0 * 1.4826 * np.median(res[keep]), 0.002)
    return line


def story_walls(
    pts: np.ndarray, floor: np.ndarray, ceiling: np.ndarray, cfg: DriftConfig, rng: np.random.Generator
) -> list[_Wall]:
    """Tall vertical faces (walls, columns) of the story between two slab planes, each with how far it leans.

    Points are placed by their story fraction s (`story_fraction`), which follows the floor and ceiling
    planes wherever they are tilted. Faces are found by RANSAC between `wall_s_min` and `wall_s_max`
    (below the beams, which hide the heads of walls on column lines); a face is taken when it covers that
    span (furniture, doors and windows do not, and they do not lean with the story). Its lean is the offset
    along its normal of its head (s = 1) against its foot (s = 0), each from a straight line fitted in a
    window (`wall_end_s` of the story high) at the bottom and at the top of that span, carried to s = 0 and
    s = 1: between the ends a wall whose slabs turned differently bows, and its pieces below windows and
    above doors bow differently, but every piece runs straight to the slab it is fixed to."""
    s = story_fraction(pts, floor, ceiling)
    mid = (s > cfg.wall_s_min) & (s < cfg.wall_s_max)
    rest, rest_s = pts[mid], s[mid]
    windows = [
        (0.02, 0.02 + cfg.wall_end_s),
        (0.98 - cfg.wall_end_s, 0.98),
        (cfg.wall_s_max - cfg.wall_end_s, cfg.wall_s_max),
    ]
    walls: list[_Wall] = []
    for _ in range(cfg.wall_planes):  # one iteration per plane
        if len(rest) < cfg.wall_min_points:
            break
        plane, inliers = ransac_plane(rest, cfg.wall_threshold_m, cfg.ransac_iterations, rng)
        if inliers.sum() < cfg.wall_min_points:
            break
        on, on_s = rest[inliers], rest_s[inliers]
        rest, rest_s = rest[~inliers], rest_s[~inliers]
        lo, hi = np.percentile(on_s, [2, 98])
        if abs(plane[2]) > 0.1 or lo > cfg.wall_s_min + 0.1 or hi < cfg.wall_s_max - 0.08:
            continue
        normal = plane[:2] / np.linalg.norm(plane[:2])
        # A wall between two slabs that turned differently bows as a parabola in s (it blends two rigid
        # motions): its head can lie a centimetre or more off the line of its middle, so the wall is followed
        # by a parabola, and its points near the slabs are looked for within a wider band than the plane's.
        whole = _line(on_s, on[:, :2] @ normal, degree=2)
        if whole is None:
            continue
        along = np.array([-normal[1], normal[0]])
        u = on[:, :2] @ along
        box = (np.abs(pts @ plane[:3] + plane[3]) < 3.0 * cfg.wall_threshold_m) & (
            (pts[:, :2] @ along > u.min()) & (pts[:, :2] @ along < u.max())
        )
        near, near_s = pts[box], s[box]
        offset = near[:, :2] @ normal
        # Points of the wall itself follow the whole wall's line within a few mm (its bow); a beam face in
        # front of its head, or a hanging slab panel, does not.
        on_wall = np.abs(np.polyval(whole, near_s) - offset) < cfg.wall_outlier_m
        ends = []
        for w_lo, w_hi in windows:
            sel = on_wall & (near_s > w_lo) & (near_s < w_hi)
            ends.append(_line(near_s[sel], offset[sel]))
        foot, head = ends[0], ends[1] if ends[1] is not None else ends[2]
        if foot is None or head is None:
            continue
        lean = float(np.polyval(head, 1.0) - np.polyval(foot, 0.0))
        walls.append(_Wall(normal, on[:, :2].mean(axis=0), lean, len(on)))
    return walls


def _rotation(normal: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) taking +z to `normal` by the shortest turn (how a level with that normal turned)."""
    return _level(np.zeros((0, 3)), normal).T


def _consensus(a: np.ndarray, rhs: np.ndarray, support: np.ndarray, tol: float) -> np.ndarray:
    """Start for the robust fit: of the drifts solved from every pair of walls facing different ways, the
    one most walls (by support) agree with to within `tol`."""
    i, j = np.triu_indices(len(a), 1)
    pair = np.stack([a[i, :2], a[j, :2]], axis=1)  # (P, 2, 2)
    ok = np.abs(np.linalg.det(pair)) > 0.3
    if not ok.any():
        return np.linalg.lstsq(a, rhs, rcond=None)[0]
    d = np.linalg.solve(pair[ok], np.stack([rhs[i[ok]], rhs[j[ok]]], axis=1)[..., None])[..., 0]
    agree = (np.abs(a[:, :2] @ d.T - rhs[:, None]) < tol) * support[:, None]
    best = d[int(np.argmax(agree.sum(axis=0)))]
    return np.append(best, 0.0)


def story_step(
    walls: list[_Wall],
    centre: np.ndarray,
    floor_normal: np.ndarray,
    ceiling_normal: np.ndarray,
    thickness: float,
    cfg: DriftConfig,
) -> np.ndarray | None:
    """Drift (x, y) in metres of the upper level against the lower one, at the building centre and at the
    top of the upper slab, from the leans of the story's walls.

    A wall at r (from the centre) has its foot on the lower level and its head under the upper slab, a slab
    thickness below where the upper level's drift is taken; both levels turned (their slab normals). So its
    lean along its normal n is n · (D + (R_up - I)(r, -t) - (R_low - I)(r, 0) + ω × r): D is the drift
    step, ω a small turn about z that tilts do not show. D and ω by least squares, walls that disagree
    by more than `wall_outlier_m` (doors ajar, furniture) left out. None when fewer than `wall_min_count`
    walls or they face fewer than two ways."""
    if len(walls) < cfg.wall_min_count:
        return None
    n = np.array([w.normal for w in walls])
    r = np.array([w.centroid for w in walls]) - centre
    r_up, r_low = _rotation(ceiling_normal) - np.eye(3), _rotation(floor_normal) - np.eye(3)
    head = np.c_[r, np.full(len(r), -thickness)] @ r_up.T
    foot = np.c_[r, np.zeros(len(r))] @ r_low.T
    rhs = np.array([w.lean for w in walls]) - np.einsum("ij,ij->i", n, head[:, :2] - foot[:, :2])
    a = np.c_[n, n[:, 0] * -r[:, 1] + n[:, 1] * r[:, 0]]
    sv = np.linalg.svd(n, compute_uv=False)
    if sv[-1] < 0.2 * sv[0]:
        return None  # all walls face one way: the other drift component is not seen
    base = np.ones(len(walls))
    x = _consensus(a, rhs, base, cfg.wall_outlier_m)
    for _ in range(10):  # iteratively reweighted least squares, Tukey's biweight
        weight = base * np.clip(1.0 - ((a @ x - rhs) / cfg.wall_outlier_m) ** 2, 0.0, None) ** 2
        if np.count_nonzero(weight) < cfg.wall_min_count:
            return None
        x = np.linalg.lstsq(a * weight[:, None], rhs * weight, rcond=None)[0]
    return x[:2]


def _bands(pts: np.ndarray, cfg: DriftConfig) -> list[tuple[float, float]]:
    """Slab bands with bins no finer than the point spacing (a voxelised map would alias finer bins), over
    the same height window whatever the bin."""
    from aftershock.pipeline.geometry import point_spacing

    bin_m = max(cfg.bin_m, point_spacing(pts, sample=5000, seed=cfg.seed))
    window = max(3, round(cfg.neighbourhood_bins * cfg.bin_m / bin_m))
    return slab_bands(pts[:, 2], bin_m, cfg.density_ratio, window, cfg.slab_merge_m)


def _height_at(plane: np.ndarray, xy: np.ndarray) -> float:
    return float(-(plane[:2] @ xy + plane[3]) / plane[2])


def _distinct(slabs: list[list[_Surface]], centre: np.ndarray, merge_m: float) -> list[list[_Surface]]:
    """Slabs lowest first, one per level: a slab whose plane (at the centre) lies within `merge_m` of a
    bigger one's is the same slab found from two density bands."""
    order = sorted(slabs, key=lambda x: -max(y.points for y in x))
    kept: list[list[_Surface]] = []
    for x in order:
        z = _height_at(x[-1].plane, centre)
        if all(abs(z - _height_at(k[-1].plane, centre)) >= merge_m for k in kept):
            kept.append(x)
    return sorted(kept, key=lambda x: _height_at(x[-1].plane, centre))


def _thicknesses(slabs: list[list[_Surface]], centre: np.ndarray) -> np.ndarray:
    """Each slab's thickness at the centre (top minus underside), NaN when only one side was seen."""
    return np.array(
        [_height_at(x[-1].plane, centre) - _height_at(x[0].plane, centre) if len(x) > 1 else np.nan for x in slabs]
    )


def measure_drift(points: np.ndarray, cfg: DriftConfig) -> DriftResult:
    """Stories (lowest first) of a structure: each slab plane with its drift (mm) and tilt (°) against the
    lowest plane. One slab alone comes back with drift and tilt None and its `reason`, and a note."""
    gravity = Gravity(cfg.gravity)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    notes: list[str] = []
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():  # a NaN would end every plane fit in a LinAlgError
        notes.append(f"{int((~finite).sum())} point(s) with non-finite coordinates left out")
        pts = pts[finite]
    rot = np.eye(3)
    rng = np.random.default_rng(cfg.seed)
    if len(pts) < _MIN_SLAB_POINTS:
        return DriftResult([], gravity.value, notes=[*notes, "too few points to find story slabs"])
    if gravity is Gravity.GROUND_PLANE:
        bands = _bands(pts, cfg)
        if bands:
            lo, hi = bands[0]
            low = pts[(pts[:, 2] >= lo) & (pts[:, 2] < hi)]
            plane, _ = ransac_plane(low, cfg.ransac_threshold_m, cfg.ransac_iterations, rng)
            rot = _level(pts, plane[:3])
            pts = pts @ rot.T
    bands = _bands(pts, cfg)
    slabs: list[list[_Surface]] = []
    for lo, hi in bands:  # one iteration per slab
        # A tilted slab spreads over more height than its densest bins: look for its plane around the band.
        band = pts[(pts[:, 2] >= lo - cfg.slab_pad_m) & (pts[:, 2] < hi + cfg.slab_pad_m)]
        surfaces = _surfaces(band, cfg, rng) if len(band) >= _MIN_SLAB_POINTS else []
        if surfaces:
            slabs.append(surfaces)
    if slabs:  # a slab covers a floor: a small horizontal patch (a table top, a pile) is not one
        largest = max(max(x.points for x in surfaces) for surfaces in slabs)
        slabs = [x for x in slabs if max(y.points for y in x) >= cfg.min_slab_share * largest]
    if len(slabs) < 2:
        notes.append(f"{len(slabs)} story slab(s) found: drift needs at least two")
    stories: list[Story] = []
    if not slabs:
        return DriftResult(stories, gravity.value, bands, notes)
    centre = slabs[0][-1].centre
    slabs = _distinct(slabs, centre, cfg.slab_merge_m)
    thickness = _thicknesses(slabs, centre)
    seen = thickness[np.isfinite(thickness)]
    fill = float(np.median(seen)) if len(seen) else 0.0
    if any(len(x) < 2 for x in slabs[1:]):
        notes.append(
            f"a slab seen from one side only: its thickness is taken as {fill:.3f} m "
            + ("(the median of the slabs seen from both sides)" if len(seen) else "(no slab seen from both sides)")
        )
    thickness = np.where(np.isfinite(thickness), thickness, fill)
    # A story runs from the top surface (floor) of one slab to the underside (ceiling) of the next; its drift
    # step comes from how far its walls and columns lean (`story_walls`, `story_step`), or failing that how
    # far the ceiling's footprint moved against the floor's. Drifts add up from the lowest slab and are those
    # of each slab's top surface at the building centre.
    base = slabs[0][-1]
    to_base = _level(pts, base.plane[:3])  # tilts against the lowest plane
    drift = np.zeros(2)
    for i, surfaces in enumerate(slabs):
        if i > 0:
            below = slabs[i - 1][-1]
            story_pts = pts[(pts[:, 2] > below.height - 1.0) & (pts[:, 2] < surfaces[0].height + 1.0)]
            walls = story_walls(story_pts, below.plane, surfaces[0].plane, cfg, rng)
            step = story_step(walls, centre, below.plane[:3], surfaces[0].plane[:3], float(thickness[i]), cfg)
            if step is None:
                notes.append(f"story {i - 1}: too few tall walls or columns seen; drift from slab footprints")
                step = surfaces[0].centre - below.centre
            drift = drift + step * 1000.0
        main = max(surfaces, key=lambda s: s.points)
        tx, ty, total = tilt_angles(to_base @ main.plane[:3])
        normal = rot.T @ main.plane[:3]  # back to the input frame
        stories.append(
            Story(
                index=i,
                height_m=float((rot.T @ np.array([0.0, 0.0, main.height]))[2])
                if gravity is Gravity.FRAME_Z
                else main.height,
                plane=np.append(normal, main.plane[3]),
                drift_x_mm=float(drift[0]),
                drift_y_mm=float(drift[1]),
                drift_mm=float(np.hypot(*drift)),
                tilt_x_deg=tx,
                tilt_y_deg=ty,
                tilt_deg=total,
                num_points=sum(s.points for s in surfaces),
            )
        )
    if len(stories) == 1:  # one slab alone: nothing was measured, which is not a drift of 0
        only = stories[0]
        only.drift_x_mm = only.drift_y_mm = only.drift_mm = None
        only.tilt_x_deg = only.tilt_y_deg = only.tilt_deg = None
        only.reason = NOT_MEASURED_ONE_SLAB
    elif stories:
        stories[0].reason = REFERENCE_SLAB
    return DriftResult(stories, gravity.value, bands, notes)
