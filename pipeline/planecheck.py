"""Label agreement with the large planes of a map, found without the labeller (`make bench-real`).

A map's floor, ceiling and walls can be checked without annotation: RANSAC planes (open3d's `segment_plane`,
iterated on what earlier planes left) in the levelled map (z is up) are sorted by their normal. The lowest
large horizontal plane below the sensor is the floor, the highest above it the ceiling; vertical planes at least
`WALL_MIN_HEIGHT_M` tall and `WALL_MIN_WIDTH_M` wide are walls. Agreement is the share of a plane's points that
carry its class. Nothing here reads the pipeline's labelling or structure code: it is the yardstick for them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

import numpy as np
from scipy.spatial import cKDTree

from aftershock.pipeline.classes import CLASS_NAMES, NUM_CLASSES, SemanticClass

DISTANCE_M: Final = 0.06  # a point within this of a plane is on it (maps are 0.1 m voxels indoors)
RANSAC_ITERATIONS: Final = 2000
MAX_PLANES: Final = 40
MIN_PLANE_POINTS: Final = 30  # the search stops at the first plane with fewer points
LEVEL_TOLERANCE_DEG: Final = 10.0  # a normal this close to up is horizontal, to horizontal is vertical
GAP_M: Final = 1.0  # one plane's points more than this apart (along the plane, across up) are separate pieces
CELL_M: Final = 0.5  # footprint cells of a horizontal plane
MIN_SLAB_AREA_M2: Final = 3.0  # a horizontal plane covering less than this is not a floor or ceiling
SLAB_SHARE: Final = 0.2  # ... and at least this share of the largest horizontal plane on its side of the sensor
# A horizontal plane nearer the sensor's height than this is taken for a cut through the map along the sensor's
# level rings (the two sparse indoor logs of shared/data show them), not for a floor or a ceiling.
MIN_CLEARANCE_M: Final = 0.4
BEYOND_MIN_M: Final = 0.15  # map points further than this beyond a slab (and nearer than BEYOND_MAX_M) are
BEYOND_MAX_M: Final = 1.5  # on its hidden side: a floor has none under it, a ceiling none over it
MAX_BEYOND: Final = 0.2  # share of a slab's footprint cells that may have points on its hidden side
WALL_MIN_HEIGHT_M: Final = 1.2
WALL_MIN_WIDTH_M: Final = 1.5
CROSS_NEIGHBOURS: Final = 24  # map points around each plane point looked at for the map continuing across it
CROSS_RADIUS_M: Final = 0.3
CROSS_OFFSET: Final = 1.5  # x DISTANCE_M: a neighbour this far off the plane lies on one side of it
MAX_CROSSING: Final = 0.5  # a plane with more of its points crossed than this is a cut, not a surface
EXTENT_PERCENTILES: Final = (2.0, 98.0)  # extents ignore the outermost points (noise, grazing returns)

Kind = Literal["horizontal", "vertical", "slanted"]


@dataclass(frozen=True)
class Plane:
    """One plane piece of a map: unit `normal` (pointing up for horizontal ones), the map `indices` on it,
    its median height, and its extents: `width_m` across up (longest in-plane extent for horizontal ones),
    `height_m` along up (for horizontal ones, the shorter in-plane extent); `area_m2` from occupied cells."""

    normal: np.ndarray
    indices: np.ndarray
    kind: Kind
    z_m: float
    width_m: float
    height_m: float
    area_m2: float


@dataclass(frozen=True)
class RoomPlanes:
    floor: Plane | None
    ceiling: Plane | None
    walls: list[Plane] = field(default_factory=list)


def _kind(normal: np.ndarray, tolerance_deg: float) -> Kind:
    up = abs(float(normal[2]))
    if up >= np.cos(np.radians(tolerance_deg)):
        return "horizontal"
    if up <= np.sin(np.radians(tolerance_deg)):
        return "vertical"
    return "slanted"


def _pieces(u: np.ndarray, gap_m: float) -> list[np.ndarray]:
    """Split positions along one axis where consecutive sorted values are more than `gap_m` apart; indices into u."""
    order = np.argsort(u, kind="stable")
    cuts = np.flatnonzero(np.diff(u[order]) > gap_m) + 1
    return np.split(order, cuts)


def _extent(values: np.ndarray) -> float:
    lo, hi = np.percentile(values, EXTENT_PERCENTILES)
    return float(hi - lo)


def _describe(points: np.ndarray, indices: np.ndarray, normal: np.ndarray, kind: Kind) -> Plane:
    p = points[indices]
    if kind == "vertical":
        across = np.array([-normal[1], normal[0], 0.0])
        across /= max(float(np.linalg.norm(across)), 1e-12)
        u = p @ across
        width, height = _extent(u), _extent(p[:, 2])
        cells = np.unique(np.floor(np.stack([u, p[:, 2]], 1) / CELL_M).astype(np.int64), axis=0)
    else:
        xy = p[:, :2] - p[:, :2].mean(axis=0)
        _, _, vt = np.linalg.svd(xy, full_matrices=False) if len(xy) > 1 else (None, None, np.eye(2))
        a, b = _extent(xy @ vt[0]), _extent(xy @ vt[1])
        width, height = max(a, b), min(a, b)
        cells = np.unique(np.floor(p[:, :2] / CELL_M).astype(np.int64), axis=0)
    return Plane(normal, indices, kind, float(np.median(p[:, 2])), width, height, len(cells) * CELL_M**2)


def crossing_share(points: np.ndarray, tree: cKDTree, indices: np.ndarray, normal: np.ndarray) -> float:
    """Share of a plane's points whose surroundings continue on both sides of it: a plane that cuts through
    other surfaces, such as the ring a multi-beam sensor's level beam draws on the walls, not a surface."""
    p = points[indices]
    dist, nb = tree.query(p, k=CROSS_NEIGHBOURS, distance_upper_bound=CROSS_RADIUS_M)
    found = np.isfinite(dist)
    offsets = np.where(found, (points[np.minimum(nb, len(points) - 1)] - p[:, None, :]) @ normal, 0.0)
    limit = CROSS_OFFSET * DISTANCE_M
    return float(np.mean((offsets > limit).any(axis=1) & (offsets < -limit).any(axis=1)))


def find_planes(
    points: np.ndarray,
    *,
    distance_m: float = DISTANCE_M,
    max_planes: int = MAX_PLANES,
    min_points: int = MIN_PLANE_POINTS,
    tolerance_deg: float = LEVEL_TOLERANCE_DEG,
    seed: int = 0,
) -> list[Plane]:
    """The planes of a levelled map, largest first: RANSAC on the points no earlier plane took, each plane's
    points split into pieces where they lie more than GAP_M apart (along the plane, across up for vertical
    ones, along the wider axis for others) so that two walls on one line are two walls. A plane most of whose
    points have the map on both sides is a cut, not a surface: it is dropped, and its points join the vertical
    planes they lie on."""
    import open3d as o3d

    o3d.utility.random.seed(seed)
    pts = np.asarray(points, dtype=np.float64)
    tree = cKDTree(pts)
    remaining = np.arange(len(pts))
    cut: list[np.ndarray] = []
    found: list[tuple[np.ndarray, np.ndarray, Kind]] = []
    for _ in range(max_planes):
        if len(remaining) < max(min_points, 3):
            break
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[remaining]))
        model, inliers = cloud.segment_plane(distance_m, 3, RANSAC_ITERATIONS, probability=1.0)
        if len(inliers) < min_points:
            break
        normal = np.asarray(model[:3], dtype=np.float64)
        normal /= np.linalg.norm(normal)
        if normal[2] < 0:
            normal = -normal
        on = remaining[np.asarray(inliers, dtype=np.int64)]
        remaining = np.setdiff1d(remaining, on, assume_unique=True)
        if crossing_share(pts, tree, on, normal) > MAX_CROSSING:
            cut.append(on)
            continue
        kind = _kind(normal, tolerance_deg)
        if kind == "vertical":
            axis = np.array([-normal[1], normal[0], 0.0])
            axis /= np.linalg.norm(axis)
        else:
            xy = pts[on, :2] - pts[on, :2].mean(axis=0)
            axis = np.append(np.linalg.svd(xy, full_matrices=False)[2][0], 0.0)
        for piece in _pieces(pts[on] @ axis, GAP_M):
            if len(piece) >= min_points:
                found.append((on[piece], normal, kind))
    spare = np.concatenate(cut) if cut else np.zeros(0, np.int64)
    out = []
    for indices, normal, kind in found:
        if kind == "vertical" and len(spare):
            indices = np.concatenate([indices, _on_piece(pts, indices, normal, spare, distance_m)])
        out.append(_describe(pts, indices, normal, kind))
    return sorted(out, key=lambda q: -len(q.indices))


def _on_piece(
    points: np.ndarray, indices: np.ndarray, normal: np.ndarray, spare: np.ndarray, distance_m: float
) -> np.ndarray:
    """The `spare` points within `distance_m` of a vertical piece's plane and inside its extent across up."""
    offset = float(np.median(points[indices] @ normal))
    axis = np.array([-normal[1], normal[0], 0.0]) / max(float(np.hypot(normal[0], normal[1])), 1e-12)
    u = points[indices] @ axis
    near = np.abs(points[spare] @ normal - offset) <= distance_m
    us = points[spare] @ axis
    return spare[near & (us >= u.min()) & (us <= u.max())]


def _cell_keys(xy: np.ndarray) -> np.ndarray:
    c = np.floor(xy / CELL_M).astype(np.int64)
    return (c[:, 0] << 32) ^ (c[:, 1] & 0xFFFFFFFF)


def beyond_share(points: np.ndarray, plane: Plane, up: bool) -> float:
    """Share of a horizontal plane's footprint cells with map points beyond it (above when `up`, else below):
    a floor hides what lies under it and a ceiling what lies over it, so a cut through furniture or the rings
    of a multi-beam sensor shows points on the far side."""
    cells = np.unique(_cell_keys(points[plane.indices, :2]))
    dz = points[:, 2] - plane.z_m
    far = (dz > BEYOND_MIN_M) & (dz < BEYOND_MAX_M) if up else (dz < -BEYOND_MIN_M) & (dz > -BEYOND_MAX_M)
    hit = np.unique(_cell_keys(points[far, :2]))
    return float(np.isin(cells, hit, assume_unique=True).mean())


def room_planes(points: np.ndarray, planes: Sequence[Plane], sensor_z: float) -> RoomPlanes:
    """Floor (lowest large horizontal plane at least MIN_CLEARANCE_M below the sensor with nothing under it),
    ceiling (highest as far above it with nothing over it) and walls (vertical planes at least WALL_MIN_HEIGHT_M
    tall and WALL_MIN_WIDTH_M wide). Large: at least MIN_SLAB_AREA_M2 and SLAB_SHARE of the largest horizontal
    plane on that side."""
    slabs = [q for q in planes if q.kind == "horizontal" and q.area_m2 >= MIN_SLAB_AREA_M2]

    def side(up: bool) -> list[Plane]:
        qs = [q for q in slabs if (q.z_m - sensor_z if up else sensor_z - q.z_m) >= MIN_CLEARANCE_M]
        least = SLAB_SHARE * max((q.area_m2 for q in qs), default=0.0)
        return [q for q in qs if q.area_m2 >= least and beyond_share(points, q, up) <= MAX_BEYOND]

    below, above = side(False), side(True)
    walls = [
        q for q in planes if q.kind == "vertical" and q.height_m >= WALL_MIN_HEIGHT_M and q.width_m >= WALL_MIN_WIDTH_M
    ]
    return RoomPlanes(
        min(below, key=lambda q: q.z_m) if below else None,
        max(above, key=lambda q: q.z_m) if above else None,
        walls,
    )


def agreement(
    class_ids: np.ndarray, planes: Sequence[Plane], cls: SemanticClass | tuple[SemanticClass, ...]
) -> float | None:
    """Share of the planes' points (pooled) labelled `cls` (one of them, when several); None where there is
    no such plane."""
    if not planes:
        return None
    idx = np.concatenate([q.indices for q in planes])
    wanted = [int(c) for c in (cls if isinstance(cls, tuple) else (cls,))]
    return float(np.mean(np.isin(np.asarray(class_ids)[idx], wanted)))


def class_shares(class_ids: np.ndarray, indices: np.ndarray | None = None) -> dict[str, float]:
    """Share of points per class name (of `indices`, else of all), largest first; unlabelled as `unlabelled`."""
    ids = np.asarray(class_ids).astype(np.int64)
    if indices is not None:
        ids = ids[indices]
    if len(ids) == 0:
        return {}
    names = [*CLASS_NAMES, "unlabelled"]
    counts = np.bincount(np.minimum(ids, NUM_CLASSES), minlength=NUM_CLASSES + 1)
    shares = {names[c]: float(counts[c] / len(ids)) for c in np.flatnonzero(counts)}
    return dict(sorted(shares.items(), key=lambda kv: -kv[1]))


@dataclass(frozen=True)
class PlaneCheck:
    """What `check_map` found: the planes, and each structural class's agreement (None: no such plane)."""

    room: RoomPlanes
    floor: float | None
    ceiling: float | None
    wall: float | None
    shares: dict[str, float]


def check_map(points: np.ndarray, class_ids: np.ndarray, sensor_z: float, seed: int = 0) -> PlaneCheck:
    room = room_planes(points, find_planes(points, seed=seed), sensor_z)
    return PlaneCheck(
        room,
        # what one stands on: the floor indoors, the ground outdoors (the structure model's class 14)
        agreement(class_ids, [room.floor] if room.floor else [], (SemanticClass.FLOOR, SemanticClass.GROUND)),
        agreement(class_ids, [room.ceiling] if room.ceiling else [], SemanticClass.CEILING),
        agreement(class_ids, room.walls, SemanticClass.WALL),
        class_shares(class_ids),
    )
