"""Openings (windows and doors) of the structure model: gaps in a wall's face, from the floor up (a door) or from
a sill up (a window), bounded by wall on both sides, that the sensor saw through.

Per wall line (confirmed wall pieces that are parallel and coplanar, however far apart along the line: a door
leaves two walls), an occupancy grid over (along the wall, height above the story's floor) of the pieces'
voxels; a column of the grid is wall, door-like (empty low and high) or window-like (wall low, empty high). A run
of door- or window-like columns between wall columns, of a plausible size, is a candidate. A hole that is only
occlusion (something in front shadowing the wall) is not an opening: a candidate needs returns behind the
wall's face through it (a ray from the sensor that saw a voxel crosses the face inside the candidate: glass,
a frame, a door leaf, the room beyond), over a share of its width (`opening_min_seen`).

Voxels in an opening near the wall's face (frames, glass, a closed leaf) and a door's open leaf beside its jambs
take the opening's class, fused with the network's like any element's (see `model.StructureModel._fuse`).
Found at the end of a run, over every wall (after every tile was refitted), and kept with the elements.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.structure.elements import Element, Kind

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel, _Piece
    from aftershock.pipeline.voxel_map import VoxelMap

_LINK: Final = 2.0  # pieces of a line lie within this many plane thresholds of each other's planes (glass
# set back in a window's reveal, 0.12 m and more behind, does not)
_BEYOND_M: Final = 0.25  # a return this far behind the face lies past the wall's thickness: the room beyond
_LOCAL_M: Final = 1.5  # a gap's face is the line fitted to the wall's voxels this far on both sides of it
_LOW_BAND: Final = (0.15, 0.6)  # heights (above the floor) under any sill ...
_HIGH_BAND: Final = (1.2, 1.8)  # ... and above any sill, under any door's head
_WALL_SHARE: Final = 0.3  # a band is wall where this share of its cells hold the wall's voxels ...
_EMPTY_SHARE: Final = 0.1  # ... and empty under this share
_END_M: Final = 0.6  # a line's face reaches this far past its pieces' ends (a wall's stub beside a door)
_BOUND_CELLS: Final = 2  # an opening has this many columns of wall at least on either side
_BESIDE_TOP_M: Final = 0.5  # the wall beside an opening reaches this close to the top of the wall's face at least
_FACE_MAX_SHARE: Final = 0.3  # a gap's face holds voxels in at most this share of its cells
_FRONT_M: Final = 0.15  # an opening's voxels lie at most this far in front of the face (a frame, a sill board)
_LEAF_REACH_M: Final = 0.45  # an open leaf lies within this of its jamb along the wall (it swings 65-110 degrees)
_LEAF_TALL_M: Final = 1.0  # a leaf's cells hold voxels over this height at least (a table's or a chair's do not)
_LEAF_THICK_M: Final = 0.12  # a leaf's voxels lie this close to its line through the jamb
_LEAF_MIN_VOXELS: Final = 10
_LEAF_EXTRA_M: Final = 0.4  # a leaf reaches this much farther than the gap is wide (frames and its edge narrow the gap)
_LEAF_ON_SHARE: Final = 0.5  # of the tall cells near a jamb, this share on one line at least (both faces seen)
_JAMB_M: Final = 0.15  # a door's frame and the leaf's edge fill the grid's cells this far into its gap
_LEAF_EDGE_M: Final = 0.6  # a leaf seen edge-on is at most this wide (a few cm of panel, both faces and drift)


@dataclass(slots=True)
class Opening:
    """A window or a door: a rectangle in a wall's face (`normal`, `offset` of its local line, `u` along the
    direction (-n_y, n_x), `z` heights) and the voxels that take its class."""

    id: int
    kind: Kind
    normal: np.ndarray
    offset: float
    u: tuple[float, float]
    z: tuple[float, float]
    seen: float  # share of its width the sensor saw through
    rows: np.ndarray

    def element(self) -> Element:
        t = np.array([-self.normal[1], self.normal[0]])
        base = -self.offset * self.normal
        a, b = base + self.u[0] * t, base + self.u[1] * t
        lo = np.r_[np.minimum(a, b), self.z[0]]
        hi = np.r_[np.maximum(a, b), self.z[1]]
        return Element(self.id, self.kind, lo, hi, plane=np.r_[self.normal, 0.0, self.offset], voxels=len(self.rows))


class Sightlines:
    """Where the sensor stood when each map voxel opened (the start of the ray that found it)."""

    def __init__(self) -> None:
        self.origins = np.full((4096, 3), np.nan, np.float32)
        self.n = 0

    def observe(self, n_rows: int, origin: np.ndarray) -> None:
        """Voxels up to `n_rows` (those opened since the last call) were seen from `origin`."""
        if n_rows > len(self.origins):
            grown = np.full((max(n_rows, 2 * len(self.origins)), 3), np.nan, np.float32)
            grown[: len(self.origins)] = self.origins
            self.origins = grown
        if n_rows > self.n:
            self.origins[self.n : n_rows] = np.asarray(origin, np.float32)[:3]
            self.n = n_rows

    def of(self, rows: np.ndarray) -> np.ndarray:
        """(K, 3) where the sensor stood when each row opened (NaN where `observe` never said)."""
        out = np.full((len(rows), 3), np.nan, np.float32)
        known = rows < self.n
        out[known] = self.origins[rows[known]]
        return out


def _lines(model: StructureModel) -> list[list[int]]:
    """Confirmed wall pieces grouped by line: parallel, coplanar, at most `opening_max_width_m` apart along it."""
    cfg = model.cfg
    ids = list(model.wall_of_piece)
    if not ids:
        return []
    ps = [model.pieces[i] for i in ids]
    normal = np.array([p.normal for p in ps])
    offset = np.array([p.offset for p in ps])
    u = np.array([p.u for p in ps])
    direction = np.c_[-normal[:, 1], normal[:, 0]]
    mid = u.mean(axis=1)
    centre = direction * mid[:, None] - normal * offset[:, None]
    cos = np.abs(normal @ normal.T)
    dist = np.abs(centre @ normal.T + offset[None, :])
    ends = np.stack([centre + direction * (u[:, :1] - mid[:, None]), centre + direction * (u[:, 1:] - mid[:, None])], 1)
    proj = np.einsum("ikc,jc->ijk", ends, direction)
    gap = np.maximum(proj.min(2) - u[None, :, 1], u[None, :, 0] - proj.max(2))
    link = (cos > np.cos(np.radians(cfg.wall_merge_deg))) & (dist < _LINK * cfg.plane_threshold_m)
    link &= (_LINK * cfg.plane_threshold_m > dist.T) & (gap < cfg.opening_max_width_m)
    a, b = np.nonzero(link)
    _, group = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(len(ids), len(ids))), directed=False)
    return [[ids[k] for k in np.flatnonzero(group == g)] for g in range(group.max() + 1)]


def _face_pieces(ps: list[_Piece], pos: np.ndarray, origin: np.ndarray, known: np.ndarray, thr: float) -> list[_Piece]:
    """A line's pieces in its face: without those standing behind another of them, across most of their width
    (glass or a frame set back in a window's reveal)."""
    out = []
    for p in ps:  # one iteration per piece of the line (a handful)
        pr = p.rows[p.rows < len(known)]
        if not len(pr):
            continue
        c = pos[pr, :2].mean(axis=0)
        behind = False
        for q in ps:
            if q is p:
                continue
            overlap = min(p.u[1], q.u[1]) - max(p.u[0], q.u[0])
            qr = q.rows[q.rows < len(known)]
            seen = qr[known[qr]]
            if overlap < 0.5 * (p.u[1] - p.u[0]) or not len(seen):
                continue
            side = np.sign(np.median(origin[seen, :2] @ q.normal + q.offset))
            behind |= bool(side * (c @ q.normal + q.offset) < -thr)
        if not behind:
            out.append(p)
    return out or ps


def _face_rows(ps: list[_Piece], pos: np.ndarray, kind_cls: np.ndarray, thr: float) -> np.ndarray:
    """The voxels in a line's face: its pieces' and those on a piece's plane beside it (a piece's plane
    drifts from its neighbour's, and a refit leaves some of a face's voxels out)."""
    n = len(pos)
    own = np.concatenate([p.rows for p in ps])
    lo = np.min([pos[p.rows[p.rows < n], :2].min(axis=0) for p in ps if np.any(p.rows < n)], axis=0) - _LOCAL_M
    hi = np.max([pos[p.rows[p.rows < n], :2].max(axis=0) for p in ps if np.any(p.rows < n)], axis=0) + _LOCAL_M
    cand = np.flatnonzero(np.all((pos[:, :2] > lo) & (pos[:, :2] < hi), axis=1) & ~np.isin(kind_cls, _KEEP))
    xy = pos[cand, :2]
    on = np.zeros(len(cand), bool)
    for p in ps:  # one iteration per piece of the line
        along = xy @ np.array([-p.normal[1], p.normal[0]])
        near = (along > p.u[0] - _LOCAL_M) & (along < p.u[1] + _LOCAL_M)
        on |= near & (np.abs(xy @ p.normal + p.offset) < thr)
    # not far past the pieces' ends along the line (there other walls cross its plane)
    t = np.array([-ps[0].normal[1], ps[0].normal[0]])
    u_own = pos[own[own < n], :2] @ t
    u = xy[on] @ t
    extra = cand[on][(u >= u_own.min() - _END_M) & (u <= u_own.max() + _END_M)]
    return np.union1d(own[own < n], extra)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _band_share(occ: np.ndarray, cell: float, band: tuple[float, float]) -> np.ndarray:
    a = round(band[0] / cell)
    b = max(round(band[1] / cell), a + 1)
    b = min(b, occ.shape[1])
    if a >= b:
        return np.full(occ.shape[0], np.nan)
    return occ[:, a:b].mean(axis=1)


def _local_line(xy: np.ndarray, normal: np.ndarray, max_deg: float) -> tuple[np.ndarray, float]:
    """The line through wall points (their principal direction, its normal turned like `normal`); the line of
    `normal` through their median where that turns more than `max_deg` (a corner's other wall among them)."""
    centre = np.median(xy, axis=0)
    n = normal
    if len(xy) >= 3:
        _, vec = np.linalg.eigh(np.cov((xy - xy.mean(axis=0)).T))
        if abs(vec[:, 0] @ normal) > np.cos(np.radians(max_deg)):
            n = vec[:, 0] if vec[:, 0] @ normal >= 0 else -vec[:, 0]
            centre = xy.mean(axis=0)
    return n, float(-n @ centre)


def find_openings(model: StructureModel, vmap: VoxelMap, sight: Sightlines) -> list[Opening]:
    """Every opening in the model's confirmed walls (see the module docstring)."""
    cfg = model.cfg
    n = min(model.n, sight.n)
    if not cfg.openings or not model.has_floor or n == 0 or model.outdoor:
        return []
    pos = vmap.positions[:n]
    origin = sight.origins[:n].astype(np.float64)
    known = np.asarray(np.isfinite(origin).all(axis=1))
    found: list[Opening] = []
    for line in _lines(model):  # one iteration per wall line
        ps = _face_pieces([model.pieces[i] for i in line], pos, origin, known, cfg.plane_threshold_m)
        rows = _face_rows(ps, pos, model.kind_cls[:n], cfg.plane_threshold_m)
        if len(rows) < cfg.wall_piece_min_voxels:
            continue
        big = max(ps, key=lambda p: len(p.rows))
        normal = big.normal
        t = np.array([-normal[1], normal[0]])
        xy = pos[rows, :2]
        storey = model.storey(xy.mean(axis=0), float(np.median(model.sensor_z[rows])))
        if storey is None:
            continue
        zf = storey[0]
        u = xy @ t
        h = pos[rows, 2] - zf
        top = min(float(np.percentile(h, 99)), storey[1] - zf)
        cell = cfg.opening_cell_m
        u0 = float(u.min())
        nu, nh = int(np.floor((u.max() - u0) / cell + 1e-6)) + 1, max(int(top / cell), 1)  # as the cells below
        ok = (h >= 0) & (h < nh * cell)
        occ = np.zeros((nu, nh), bool)
        occ[np.floor((u[ok] - u0) / cell + 1e-6).astype(np.int64), np.floor(h[ok] / cell + 1e-6).astype(np.int64)] = (
            True
        )
        occ[:, 1:-1] |= occ[:, :-2] & occ[:, 2:]  # a scan line's gap between two lines of the wall
        low = _band_share(occ, cell, _LOW_BAND)
        high = _band_share(occ, cell, (_HIGH_BAND[0], min(_HIGH_BAND[1], top)))
        if np.isnan(high).all() or np.isnan(low).all():
            continue
        if top < _HIGH_BAND[1]:
            continue  # a face seen no higher than furniture (a desk's side, a shelf's back)
        walled = high >= _WALL_SHARE
        walled[1:-1] |= walled[:-2] & walled[2:]  # one column between scan lines or cells
        for a, b in _runs(~walled):  # one iteration per gap in the wall's upper part
            if a < _BOUND_CELLS or b + _BOUND_CELLS > nu or np.mean(high[a:b]) >= _EMPTY_SHARE:
                continue
            if not (walled[a - _BOUND_CELLS : a].all() and walled[b : b + _BOUND_CELLS].all()):
                continue  # bounded by wall on both sides (not by another wall crossing the line past its end)
            beside = np.r_[a - _BOUND_CELLS : a, b : b + _BOUND_CELLS]
            tops = (nh - 1 - np.argmax(occ[beside, ::-1], axis=1)) * cell  # the faces' highest cells
            if float(np.median(tops)) < top - _BESIDE_TOP_M:
                continue  # the faces beside it stop short of the wall's top: furniture side by side, not a wall
            sill = bool(np.median(low[a:b]) >= _WALL_SHARE)  # wall under it: a window
            span = (u0 + a * cell, u0 + b * cell)
            op = _opening(model, pos, origin, known, rows, u, h, span, sill, zf, top, normal)
            if op is not None:
                found.append(op)
    return found


def _opening(
    model: StructureModel,
    pos: np.ndarray,
    origin: np.ndarray,
    known: np.ndarray,
    rows: np.ndarray,
    u: np.ndarray,
    h: np.ndarray,
    span: tuple[float, float],
    sill: bool,
    zf: float,
    top: float,
    line_normal: np.ndarray,
) -> Opening | None:
    """The gap `span` along a line as an opening, if the sensor saw through it, else None. A window where wall
    stands under it (`sill`) or where the sensor saw through it only above a sill height (the wall under a
    window is often hidden by a desk), else a door."""
    cfg = model.cfg
    ua, ub = span
    margin = cfg.opening_cell_m
    inside = (u >= ua) & (u < ub)
    over = h[inside & (h > _HIGH_BAND[1])]
    z1 = float(np.percentile(over, 10)) if len(over) >= 3 else top  # the wall's underside over it
    # the face of the gap: the line of the wall's voxels just beside it
    near = rows[((u > ua - _LOCAL_M) & (u < ua)) | ((u >= ub) & (u < ub + _LOCAL_M))]
    normal, offset = _local_line(pos[near, :2], line_normal, cfg.wall_merge_deg)
    t = np.array([-normal[1], normal[0]])
    side = np.sign(np.median(origin[near[known[near]], :2] @ normal + offset)) if known[near].any() else 0.0
    if side == 0:
        return None
    d = side * (pos[:, :2] @ normal + offset)  # > 0 on the side the wall was seen from
    ds = side * (origin[:, :2] @ normal + offset)
    uu = pos[:, :2] @ t
    hh = pos[:, 2] - zf
    # seen through: rays whose return lies behind the face and that crossed it inside the gap
    idx = np.flatnonzero(known & (d < -cfg.plane_threshold_m) & (ds > 0))
    f = ds[idx] / (ds[idx] - d[idx])
    cross = origin[idx] + f[:, None] * (pos[idx] - origin[idx])
    cu, ch = cross[:, :2] @ t, cross[:, 2] - zf
    hit = (cu > ua + margin) & (cu < ub - margin) & (ch > margin) & (ch < z1 - margin)
    cols = round((ub - ua) / margin)
    if cols < 1 or not hit.any():
        return None
    seen = len(np.unique(np.clip(((cu[hit] - ua) / margin).astype(np.int64), 0, cols - 1))) / cols
    if seen < cfg.opening_min_seen:
        return None  # a shadow on the wall, not a hole in it
    through = ch[hit]
    if sill:
        under = h[inside & (h < _HIGH_BAND[0])]
        z0 = float(np.percentile(under, 90)) if len(under) else float(np.percentile(through, 5))
        if z0 < cfg.sill_min_m:
            return None  # a low wall (a broken wall's stump, a parapet), not an opening
    else:  # the lowest rays through a door to the room beyond pass under any sill (a sensor at 1 m sees its floor)
        beyond = hit & (d[idx] < -_BEYOND_M)
        low = len(np.flatnonzero(beyond)) >= 3 and float(np.percentile(ch[beyond], 5)) < cfg.sill_min_m
        z0 = 0.0 if low else float(np.percentile(through, 5))
        if not low and z0 < cfg.sill_min_m:
            return None  # seen through low down only in the reveal (a face drifted behind the line): unsure
    kind = Kind.DOOR if z0 < cfg.sill_min_m else Kind.WINDOW
    lo_w, hi_w = (
        (cfg.door_min_width_m, cfg.door_max_width_m)
        if kind is Kind.DOOR
        else (cfg.window_min_width_m, cfg.window_max_width_m)
    )
    if not lo_w <= ub - ua <= hi_w or z0 > cfg.sill_max_m or z1 - z0 < cfg.opening_min_height_m:
        return None
    if kind is Kind.DOOR and z1 < min(cfg.door_min_height_m, top - margin):
        return None  # a gap under a head lower than a door's: between furniture, under a shelf
    inner = (hh > z0 + margin) & (hh < z1 - margin) & (uu > ua + margin) & (uu < ub - margin)
    face = np.flatnonzero(inner & (d > -cfg.plane_threshold_m) & (d < _FRONT_M))
    if len(face):  # a face across the gap (the wall's, drifted from the line beside it): no hole in it
        cells = np.unique(np.floor(np.c_[uu[face], hh[face]] / margin).astype(np.int64), axis=0)
        if len(cells) > _FACE_MAX_SHARE * cols * max((z1 - z0) / margin - 2, 1):
            return None
    # its voxels: near the face inside it and at its edges (frames, glass, a closed leaf), and a door's open
    # leaf beside a jamb
    box = (hh > z0 - margin) & (hh < z1 + margin)
    reach = _JAMB_M if kind is Kind.DOOR else margin
    mine = box & (uu > ua - reach) & (uu < ub + reach) & (d > -cfg.opening_depth_m) & (d < _FRONT_M)
    if kind is Kind.WINDOW:
        # a window's frame and glass are set in the wall's reveal: the face around the hole (its jambs, head,
        # the sill's edge) is the wall's own surface
        mine &= np.abs(d) > cfg.plane_threshold_m
    if kind is Kind.DOOR:
        mine |= _leaf(model, pos, np.flatnonzero(box & (np.abs(d) > _FRONT_M)), uu, d, hh, (ua, ub))
    out = np.flatnonzero(mine)
    out = out[~np.isin(model.kind_cls[out], _KEEP)]  # floors, ceilings and columns stay what they are
    return Opening(model._new_id(), kind, normal, offset, (ua, ub), (zf + z0, zf + z1), seen, out)


def _leaf(
    model: StructureModel,
    pos: np.ndarray,
    cand: np.ndarray,
    uu: np.ndarray,
    d: np.ndarray,
    hh: np.ndarray,
    span: tuple[float, float],
) -> np.ndarray:
    """A door's open leaf: a thin upright panel from one of its jambs, swung out to either side (a mask over
    the map). Of the tall cells (of one voxel, standing `_LEAF_TALL_M` high at least) within the door's width of
    a jamb, those along one direction from it, in a strip no wider than `_LEAF_THICK_M` (a column or a cabinet
    beside a door is wide, a leaf is not)."""
    out = np.zeros(len(pos), bool)
    ua, ub = span
    width = ub - ua + 2 * _JAMB_M + _LEAF_EXTRA_M
    cand = cand[~np.isin(model.kind_cls[cand], _KEEP)]
    cand = cand[~np.isin(model.elem[cand], _wide_wall_pieces(model, width + _LEAF_REACH_M))]  # a wall at a corner
    for jamb, sign in ((ua - _JAMB_M / 2, 1.0), (ub + _JAMB_M / 2, -1.0)):  # one iteration per jamb
        for side in (1.0, -1.0):  # and per side of the wall
            du, dd = sign * (uu[cand] - jamb), side * d[cand]
            r = np.hypot(du, dd)
            near = cand[(dd > 0) & (r < width) & (du > -_LEAF_REACH_M) & (du < _LEAF_REACH_M)]
            if len(near) < _LEAF_MIN_VOXELS:
                continue
            cell = np.floor(pos[near, :2] / model.voxel).astype(np.int64)
            keys, inv = np.unique(cell, axis=0, return_inverse=True)
            inv = inv.ravel()
            lo, hi = np.full(len(keys), np.inf), np.full(len(keys), -np.inf)
            np.minimum.at(lo, inv, hh[near])
            np.maximum.at(hi, inv, hh[near])
            tall = near[(hi - lo)[inv] >= _LEAF_TALL_M]
            if len(tall) < _LEAF_MIN_VOXELS:
                continue
            du_t, dd_t = sign * (uu[tall] - jamb), side * d[tall]
            angle = np.arctan2(dd_t, du_t)
            a = float(np.median(angle))
            across = -np.sin(a) * du_t + np.cos(a) * dd_t  # off the leaf's line through the jamb
            on = np.abs(across) < _LEAF_THICK_M
            if on.mean() < _LEAF_ON_SHARE or np.ptp(np.hypot(du_t, dd_t)[on]) < 0.5 * (ub - ua):
                continue  # not one thin panel reaching across most of the door's width
            out[tall[on]] = True
    return out


def _wide_wall_pieces(model: StructureModel, width: float) -> np.ndarray:
    """Ids of the pieces of confirmed walls wider than `width` (a leaf may be taken for a narrow wall)."""
    lo: dict[int, float] = {}
    hi: dict[int, float] = {}
    for pid, wall in model.wall_of_piece.items():  # one iteration per wall piece
        p = model.pieces[pid]
        lo[wall], hi[wall] = min(lo.get(wall, np.inf), p.u[0]), max(hi.get(wall, -np.inf), p.u[1])
    wide = [pid for pid, wall in model.wall_of_piece.items() if hi[wall] - lo[wall] > width]
    return np.array(wide, np.int64)


_KEEP: Final = np.array(
    [SemanticClass.FLOOR, SemanticClass.CEILING, SemanticClass.COLUMN, SemanticClass.BEAM, SemanticClass.GROUND]
)


def leaf_columns(model: StructureModel, vmap: VoxelMap, openings: list[Opening]) -> dict[int, Opening]:
    """The columns that are a door's open leaf, by id, with their door: hung at a jamb (their near end within
    `_LEAF_REACH_M` of it, their far end within a leaf's width, `door_max_width_m`), standing square off the wall
    (deeper off it than wide along it) and no wider along it than a leaf seen edge-on. A column beside a doorway
    stands in or along the wall, not out of it from the jamb."""
    n = model.n
    ids = np.fromiter(model.columns, np.int64, len(model.columns))
    doors = [op for op in openings if op.kind is Kind.DOOR]
    if not len(ids) or not doors:
        return {}
    rows = np.flatnonzero(np.isin(model.elem[:n], ids))
    xy = vmap.positions[rows, :2].astype(np.float64)
    elem = model.elem[rows]
    out: dict[int, Opening] = {}
    for op in doors:  # one iteration per door
        t = np.array([-op.normal[1], op.normal[0]])
        uu, dd = xy @ t, xy @ op.normal + op.offset
        for jamb in op.u:  # one iteration per jamb
            r = np.hypot(uu - jamb, dd)
            for cid in np.unique(elem[r < model.cfg.door_max_width_m]).tolist():  # the columns near it
                mine = elem == cid
                wide, deep = np.ptp(uu[mine]), np.ptp(dd[mine])
                hung = r[mine].min() < _LEAF_REACH_M and r[mine].max() < model.cfg.door_max_width_m
                if hung and wide <= _LEAF_EDGE_M and deep > wide:
                    out.setdefault(int(cid), op)
    return out


def mark_openings(model: StructureModel, openings: list[Opening]) -> np.ndarray:
    """The openings' voxels take their class (over the wall's: frames and glass stand in its face). Returns
    the rows whose element changed."""
    changed = [np.zeros(0, np.int64)]
    for op in openings:  # one iteration per opening
        model.elem[op.rows] = op.id
        model.kind_cls[op.rows] = SemanticClass.WINDOW if op.kind is Kind.WINDOW else SemanticClass.DOOR
        changed.append(op.rows)
    return np.concatenate(changed)
