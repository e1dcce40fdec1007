"""Columns and beams of the structure model, found in a tile's block of the levelled map after its walls.

- Free-standing columns: compact footprints occupied over most of the story's height, with nothing tall
  around them but wall planes (a column a hand's width from a wall is still free).
- Engaged columns (built into a wall or against it, issue #28): a vertical prism proud of a wall's plane, a
  narrow run along the wall where the surface seen stands off the plane toward the side the sensor saw it from
  (the far face of a thin wall is behind the near one), over most of the story's height, with a flat face
  parallel to the wall, open in front of it, and the wall one clean plane on both sides (a wall seen twice by a
  drifting registration is not).
- Beams: elongated footprints hanging just under a ceiling slab, open below, with a flat underside, not
  along a wall's plane (a wall's head seen without its lower part is not a beam), and built up to the slab:
  where the sensor saw the slab through the space over a candidate, it hangs free (a row of pendant lamps).

Every voxel inside a column's box takes column (also those a wall piece took: the wall's plane runs behind an
engaged column, what is seen there is the column).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final

import numpy as np
from scipy import ndimage

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.structure.elements import Element, Kind
from aftershock.pipeline.structure.lookup import member

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel, _Piece
    from aftershock.pipeline.voxel_map import VoxelMap

_FLOOR_MARGIN_M: Final = 0.15  # a column's occupancy is counted from this far above the floor (not the floor)
_RING_CELLS: Final = 2  # a column stands free: the cells this far around its footprint are mostly empty ...
_RING_MAX_SHARE: Final = 0.35  # ... (wall planes left out)
_LINE_MAX_M: Final = 0.6  # a footprint on one line (one face seen) longer than this is a wall stub
_STRIP_M: Final = 0.45  # a footprint this thin across a wall's line, on it, is the wall's (an end, a stub)
_WALL_END_M: Final = 0.5  # a footprint on a wall's line within this past its ends is the wall's end
_ONE_SIDED_FACE: Final = 0.9  # ... (or, `engaged_one_sided`, on one side with this share on its face)
_BESIDE_M: Final = 0.5  # beside an engaged column, this far along the wall, the wall is one clean plane ...
_MIN_BESIDE_FLAT: Final = 0.7  # ... holding this share of the voxels in front of it up to the column's face ...
_MIN_BESIDE_VOXELS: Final = 5  # ... and at least this many, on each side seen (one at least)
_LONG_WALL_M: Final = 1.5  # a wall piece this long is a wall: its line separates what stands beside it ...
_CUT_CELLS: Final = 2  # ... over this many cells either side (a wall seen twice is thicker than it is)
_PANEL_M: Final = 0.2  # a footprint this thin (and longer than _LINE_MAX_M) is a panel: a door leaf, a board ...
_PANEL_RATIO: Final = 2.0  # ... and so is one this many times longer than thick (a column's is about square) ...
_PANEL_LONG_M: Final = 0.8  # ... longer than this, or shorter but ...
_SQUARE_COS: Final = 0.35  # ... and square off a wall (the cosine of its axis with the wall's, at most) ...
_TOUCH_M: Final = 0.25  # ... touching the wall's line within this (a door leaf's hinge)
_MAX_ON_WALLS: Final = 0.7  # a footprint with this share of its cells on wall lines is the walls' (a corner)
_SEEN_OVER_SHARE: Final = 0.3  # the slab seen through the space over a beam along this share of its length: a
# fixture hanging under the ceiling (a pendant lamp, a duct on hangers), not a beam built up to the slab
_OVER_SAMPLES: Final = 8  # heights along a ray at which it is looked at in that space
_OPEN_M: Final = 0.4  # the space this deep in front of an engaged column's face is open ...
_MAX_AHEAD: Final = 0.2  # ... holding at most this share of the column's voxels


def _storey_reach(model: StructureModel, storey: tuple[float, float]) -> float:
    """How high above the floor (from `_FLOOR_MARGIN_M`) a column is looked at: the story's height, or as high
    as a column must reach at least (a scanner close to the floor sees a column's head only from far away)."""
    zf, zc = storey
    return min(zc - zf - 2 * _FLOOR_MARGIN_M, model.cfg.column_min_height_m)


def _wall_of(model: StructureModel, rows: np.ndarray) -> np.ndarray:
    """The confirmed wall each row lies on (-1: none)."""
    lookup = np.full(model.next_id + 1, -1, np.int64)
    if model.wall_of_piece:
        pids = np.fromiter(model.wall_of_piece, np.int64, len(model.wall_of_piece))
        lookup[pids] = np.fromiter(model.wall_of_piece.values(), np.int64, len(pids))
    elem = model.elem[rows]
    return np.where(elem >= 0, lookup[np.clip(elem, 0, None)], -1)


def _slab_rows(model: StructureModel, rows: np.ndarray) -> np.ndarray:
    return member(model.elem[rows], [s.id for s in model.slabs], model.next_id)


def _column_rows(model: StructureModel, rows: np.ndarray) -> np.ndarray:
    return member(model.elem[rows], model.columns.keys(), model.next_id)


def _open_rows(model: StructureModel, rows: np.ndarray) -> np.ndarray:
    """Whether each row may take a column: on no slab and in no column found already."""
    return ~member(model.elem[rows], [s.id for s in model.slabs] + list(model.columns), model.next_id)


def _box_rows(model: StructureModel, vmap: VoxelMap, rows: np.ndarray, e: Element) -> np.ndarray:
    """The rows inside a column's box (within the plane threshold), wall pieces' included."""
    thr = model.cfg.plane_threshold_m
    pos = vmap.positions[rows]
    inside = np.all((pos >= e.lo - thr) & (pos <= e.hi + thr), axis=1) & _open_rows(model, rows)
    return rows[inside]


def _add_column(model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, e: Element, on: np.ndarray) -> None:
    """Register column `e` of tile `i`; the rows `on` (of `block`) take column."""
    model.columns[e.id] = e
    model.tiles[i].elements.append(e.id)
    model.elem[on] = e.id
    model.kind_cls[on] = SemanticClass.COLUMN


def _owned(model: StructureModel, i: int, centre: np.ndarray) -> bool:
    """The tile its centre lies in owns an element."""
    return bool(np.array_equal(np.floor(centre / model.cfg.tile_m).astype(np.int64), model.tile_xy[i]))


def fit_columns(model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]) -> None:
    """Columns of tile `i` (free-standing, then engaged in the walls of the block)."""
    fit_free_columns(model, vmap, i, block, storey)
    fit_engaged_columns(model, vmap, i, block, storey)


def fit_free_columns(
    model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]
) -> None:
    cfg, voxel = model.cfg, model.voxel
    zf, zc = storey
    reach = _storey_reach(model, storey)
    full = max(1.0, reach / voxel)
    z0 = zf + _FLOOR_MARGIN_M
    pos = vmap.positions[block]
    sel = (pos[:, 2] >= z0) & (pos[:, 2] < z0 + reach) & _open_rows(model, block)
    if not sel.any():
        return
    cell = np.floor(pos[sel, :2] / voxel).astype(np.int64)
    origin = cell.min(axis=0)
    cell -= origin
    shape = cell.max(axis=0) + 1
    flat = cell[:, 0] * shape[1] + cell[:, 1]
    # tall cells counted over every voxel but the slabs' (a wall piece may have taken a column's face) ...
    tall = (np.bincount(flat, minlength=int(shape.prod())).reshape(shape) / full) >= cfg.column_min_cover
    pieces = [model.pieces[p] for p in model._block_pieces(i)]
    tall &= ~_on_long_walls(pieces, origin, shape, voxel)  # cut apart what stands beside a wall
    labels, num = ndimage.label(tall, structure=np.ones((3, 3)))
    if not num:
        return
    # ... what stands around a column over the voxels on no element (wall planes left out)
    free = model.elem[block[sel]] < 0
    cover_free = np.bincount(flat[free], minlength=int(shape.prod())).reshape(shape) / full
    occupied = ndimage.binary_dilation(cover_free >= 0.25)
    max_cells = cfg.column_max_width_m / voxel
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):  # one iteration per candidate footprint
        mask = labels[sl] == k
        size = np.array(mask.shape)
        if size.max() > max_cells or mask.sum() < 2:
            continue
        cells = (np.argwhere(mask) + np.array([sl[0].start, sl[1].start]) + origin + 0.5) * voxel
        if _panel(cells, voxel, pieces):
            continue  # one line of cells: a wall stub seen edge-on, a door leaf
        ring_sl = tuple(slice(max(s.start - _RING_CELLS, 0), s.stop + _RING_CELLS) for s in sl)
        ring = occupied[ring_sl].copy()
        inner = np.zeros_like(ring)
        inner[tuple(slice(s.start - r.start, s.stop - r.start) for s, r in zip(sl, ring_sl, strict=True))] = mask
        grown = ndimage.binary_dilation(inner, iterations=1)
        around = ndimage.binary_dilation(inner, iterations=_RING_CELLS) & ~grown
        if around.sum() and ring[around].mean() > _RING_MAX_SHARE:
            continue  # attached to something tall (a wall between openings): not free-standing
        lo_cell = np.array([sl[0].start, sl[1].start]) + origin
        hi_cell = np.array([sl[0].stop, sl[1].stop]) + origin
        centre = (lo_cell + hi_cell) / 2 * voxel
        if on_wall_line(cells, voxel, pieces):
            continue  # a wall's end or the piece between two openings, not a column
        if not _owned(model, i, centre):
            continue
        e = Element(
            model._new_id(),
            Kind.COLUMN,
            np.r_[lo_cell * voxel, zf],
            np.r_[hi_cell * voxel, zc],
            axis=np.array([0.0, 0.0, 1.0]),
        )
        on = _box_rows(model, vmap, block, e)
        _add_column(model, vmap, i, block, e, on)


def _on_long_walls(pieces: list[_Piece], origin: np.ndarray, shape: np.ndarray, voxel: float) -> np.ndarray:
    """Cells of a grid (of one voxel, from `origin`) on the line of a wall piece longer than `_LONG_WALL_M`."""
    gx, gy = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    xy = (np.c_[gx.ravel(), gy.ravel()] + origin + 0.5) * voxel
    out = np.zeros(len(xy), bool)
    for p in pieces:  # one iteration per wall piece nearby
        if p.u[1] - p.u[0] < _LONG_WALL_M:
            continue
        along = xy @ np.array([-p.normal[1], p.normal[0]])
        out |= (np.abs(xy @ p.normal + p.offset) < _CUT_CELLS * voxel) & (along > p.u[0]) & (along < p.u[1])
    return out.reshape(shape)


def _panel(cells: np.ndarray, voxel: float, pieces: list[_Piece]) -> bool:
    """Whether footprint cells are a panel: one thin line longer than a column's face (a wall stub seen edge-on),
    or an elongated footprint standing square off a wall from its end (a door leaf open, a partition's end)."""
    if len(cells) < 3:
        return False
    centred = cells - cells.mean(axis=0)
    _, vec = np.linalg.eigh(centred.T @ centred)
    thick = float(np.ptp(centred @ vec[:, 0])) + voxel
    length = float(np.ptp(centred @ vec[:, 1])) + voxel
    if length <= _LINE_MAX_M:
        return False
    if thick <= _PANEL_M:
        return True
    if length < _PANEL_RATIO * thick:
        return False
    if length > _PANEL_LONG_M:
        return True  # longer than two faces of a column seen from its corner
    for p in pieces:  # one iteration per wall piece nearby
        across = abs(float(vec[:, 1] @ np.array([-p.normal[1], p.normal[0]]))) < _SQUARE_COS
        along = cells @ np.array([-p.normal[1], p.normal[0]])
        touch = (
            (np.abs(cells @ p.normal + p.offset) < _TOUCH_M)
            & (along > p.u[0] - _WALL_END_M)
            & (along < p.u[1] + _WALL_END_M)
        )
        if across and p.u[1] - p.u[0] >= _LONG_WALL_M and touch.any():
            return True
    return False


def on_wall_line(cells: np.ndarray, voxel: float, pieces: list[_Piece]) -> bool:
    """Whether a footprint (its cells' centres) is a strip on the line of a wall piece, within its extent or just
    past its ends: thin across the line (a column with a face in line with a wall is not)."""
    centre = cells.mean(axis=0)
    on_any = np.zeros(len(cells), bool)
    for p in pieces:  # one iteration per wall piece nearby
        off = cells @ p.normal + p.offset
        thick = float(np.ptp(off)) + voxel
        along = cells @ np.array([-p.normal[1], p.normal[0]])
        within = (along > p.u[0] - _WALL_END_M) & (along < p.u[1] + _WALL_END_M)
        on_line = thick <= _STRIP_M and abs(float(off.mean())) < 0.5 * thick + 0.1
        if on_line and within[np.argmin(np.abs(along - centre @ np.array([-p.normal[1], p.normal[0]])))]:
            return True
        on_any |= within & (np.abs(off) < 2 * voxel)
    return bool(on_any.mean() >= _MAX_ON_WALLS)  # a corner: strips along two walls


def _block_walls(model: StructureModel, i: int) -> dict[int, list[_Piece]]:
    """Confirmed walls with a piece in tile `i`'s block: wall id -> all its pieces."""
    near = {model.wall_of_piece[p] for p in model._block_pieces(i)}
    walls: dict[int, list[_Piece]] = {}
    for pid, wall in model.wall_of_piece.items():
        if wall in near:
            walls.setdefault(wall, []).append(model.pieces[pid])
    return walls


def _clean_wall(
    near: np.ndarray, on_plane: np.ndarray, u: np.ndarray, depth: np.ndarray, lo: float, hi: float, front: float
) -> bool | None:
    """Whether the wall is one clean plane between `lo` and `hi` along it: most voxels in front of it, up to
    `front`, lie on its plane. None where nothing at all was seen there, on either side of the plane (the wall
    ends at the column, an opening beside it, or the column hid it from the sensor)."""
    if not (near & (u >= lo) & (u < hi)).any():
        return None
    there = near & (u >= lo) & (u < hi) & (depth < front)
    flat = on_plane[there]
    return bool(flat.sum() >= _MIN_BESIDE_VOXELS and flat.mean() >= _MIN_BESIDE_FLAT)


def _runs(mask: np.ndarray, max_gap: int) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in `mask`, gaps up to `max_gap` cells bridged."""
    idx = np.flatnonzero(mask)
    if not len(idx):
        return []
    cuts = np.flatnonzero(np.diff(idx) > max_gap + 1)
    starts = np.r_[idx[0], idx[cuts + 1]]
    stops = np.r_[idx[cuts], idx[-1]] + 1
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def fit_engaged_columns(
    model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]
) -> None:
    """Columns built into or against a wall: per wall of the block and per side of its plane, the runs along
    the wall (cells of one voxel) where voxels stand proud of the plane over most of the story's height."""
    cfg, voxel = model.cfg, model.voxel
    zf, zc = storey
    reach = _storey_reach(model, storey)
    z0 = zf + _FLOOR_MARGIN_M
    full = max(1.0, reach / voxel)
    thr = cfg.plane_threshold_m
    pos_all = vmap.positions[block]
    keep = (pos_all[:, 2] >= z0) & (pos_all[:, 2] < z0 + reach) & ~_slab_rows(model, block)
    keep &= ~_column_rows(model, block)
    rows, pos = block[keep], pos_all[keep]
    if not len(rows):
        return
    owner_wall = _wall_of(model, rows)
    zbin = np.floor((pos[:, 2] - z0) / voxel).astype(np.int64)
    for wall, ps in _block_walls(model, i).items():  # one iteration per wall near the tile
        big = max(ps, key=lambda p: len(p.rows))
        n, o = big.normal, big.offset
        d = np.array([-n[1], n[0]])
        ends = np.array([[p.u[0], p.u[1]] for p in ps])
        mids = (ends[:, 0] + ends[:, 1]) / 2
        # each piece's extent in the big piece's direction
        centres = d[None, :] * mids[:, None] - n[None, :] * np.array([p.offset for p in ps])[:, None]
        half = (ends[:, 1] - ends[:, 0]) / 2
        cu = centres @ d
        u_lo, u_hi = float((cu - half).min()), float((cu + half).max())
        s = pos[:, :2] @ n + o
        u = pos[:, :2] @ d
        near = (u > u_lo - _WALL_END_M) & (u < u_hi + _WALL_END_M) & (np.abs(s) < cfg.column_max_proud_m + _OPEN_M)
        near &= (owner_wall < 0) | (owner_wall == wall)  # another wall's voxels are that wall's
        near &= ~_column_rows(model, rows)  # nor those of a column found already
        on_plane = near & (np.abs(s) <= thr)
        for side in (1.0, -1.0):  # one iteration per side of the wall
            proud = near & (side * s > thr) & (side * s < cfg.column_max_proud_m + thr)
            if proud.sum() < 4:
                continue
            pu = np.floor((u[proud] - u_lo + _WALL_END_M) / voxel).astype(np.int64)
            ncell = int(pu.max()) + 1
            key = np.unique(pu * (int(zbin.max()) + 1) + zbin[proud])
            cover = np.bincount(key // (int(zbin.max()) + 1), minlength=ncell) / full
            tall = cover >= cfg.column_min_cover
            for a, b in _runs(tall, 1):  # one iteration per candidate run
                width = (b - a) * voxel
                if width < cfg.column_min_width_m or width > cfg.engaged_max_width_m:
                    continue
                ua = u_lo - _WALL_END_M + a * voxel
                ub = u_lo - _WALL_END_M + b * voxel
                inrun = proud & (u >= ua) & (u < ub)
                ua, ub = float(u[inrun].min()), float(u[inrun].max())  # the run's ends, not its cells'
                seen = model.sight.of(rows[inrun])[:, :2] @ n + o  # the sensor's side of the plane
                known = np.isfinite(seen)
                if known.any() and np.mean(side * seen[known] > side * s[inrun][known]) < cfg.engaged_min_face:
                    continue  # seen from behind: the far face of a thin wall, not something proud of this face
                depth = side * s[inrun]
                front = float(np.percentile(depth, 75))
                if np.mean(np.abs(depth - front) < thr) < cfg.engaged_min_face:
                    continue  # no flat face parallel to the wall: furniture against it
                ahead = near & (u >= ua) & (u < ub) & (side * s > front + 2 * thr) & (side * s < front + _OPEN_M)
                if ahead.sum() > _MAX_AHEAD * inrun.sum():
                    continue  # something goes on past the face (a door leaf, a wall across): not a column's face
                # the wall's plane beside the run (the column stands in or against this wall)
                if front < cfg.engaged_min_proud_m:
                    continue  # within what a wall seen twice (drift) or bent stands off its plane
                beside = [
                    _clean_wall(near, on_plane, u, side * s, lo, hi, front + thr)
                    for lo, hi in ((ua - _BESIDE_M, ua - thr), (ub + thr, ub + _BESIDE_M))
                ]
                if False in beside or True not in beside:
                    continue  # no clean wall plane on every side seen (a wall seen twice, furniture in a row) ...
                # ... or on none: a column at a wall's end or by an opening has the wall's plane on one side, and
                # then shows its own flat face (a wall's end seen from its side, a partition's stub, does not);
                # off by default (`engaged_one_sided`): a wall's end seen thick passes it too
                if None in beside and (
                    not cfg.engaged_one_sided or np.mean(np.abs(depth - front) < thr) < _ONE_SIDED_FACE
                ):
                    continue
                corners_us = np.array([[ua, -thr], [ub, -thr], [ua, front + thr], [ub, front + thr]])
                corners = corners_us[:, :1] * d + (side * corners_us[:, 1:] - o) * n
                e = Element(
                    model._new_id(),
                    Kind.COLUMN,
                    np.r_[corners.min(axis=0), zf],
                    np.r_[corners.max(axis=0), zc],
                    axis=np.array([0.0, 0.0, 1.0]),
                )
                # the voxels in its box (oriented along the wall), those on this wall's plane included
                bpos = vmap.positions[block]
                bs, bu = side * (bpos[:, :2] @ n + o), bpos[:, :2] @ d
                inside = (bu >= ua - thr) & (bu <= ub + thr) & (bs > -thr) & (bs < front + thr)
                inside &= (bpos[:, 2] > zf - thr) & (bpos[:, 2] < zc + thr) & ~_slab_rows(model, block)
                inside &= ~_column_rows(model, block)
                _add_column(model, vmap, i, block, e, block[inside])


def along_wall(model: StructureModel, i: int, xy: np.ndarray, reach_m: float) -> float:
    """Share of the points `xy` (a beam's footprint) within `reach_m` of the line of a confirmed wall piece of
    tile `i`'s block whose extent it overlaps or continues: a wall's head, where the wall's lower part is hidden
    or was never seen (the wall piece then ends where its lower part was last seen)."""
    best = np.zeros(len(xy), bool)
    for p in (model.pieces[q] for q in model._block_pieces(i)):  # one iteration per wall piece nearby
        along = xy @ np.array([-p.normal[1], p.normal[0]])
        if along.max() < p.u[0] - _WALL_END_M or along.min() > p.u[1] + _WALL_END_M:
            continue
        best |= np.abs(xy @ p.normal + p.offset) < reach_m
    return float(best.mean()) if len(xy) else 0.0


def _slab_seen_over(
    model: StructureModel,
    vmap: VoxelMap,
    block: np.ndarray,
    centre: np.ndarray,
    axis: np.ndarray,
    length: float,
    width: float,
    bottom: float,
    zc: float,
) -> float:
    """Share of a beam candidate's length (its footprint: `centre`, `axis`, `length`, `width`; from `bottom` up
    to the ceiling at `zc`) over which the sensor saw the ceiling through the space the beam would fill: rays to
    ceiling voxels that pass over its middle, under the slab. A beam is built up to the slab (the slab over it
    is hidden); a fixture hanging from it leaves a gap the rays see through. 0 where no ray is known."""
    cfg, voxel = model.cfg, model.voxel
    rows = block[model.kind_cls[block] == SemanticClass.CEILING]
    if not len(rows):
        return 0.0
    pos = vmap.positions[rows].astype(np.float64)
    t = np.array([-axis[1], axis[0]])
    rel = pos[:, :2] - centre
    near = (np.abs(rel @ axis) < length / 2 + 1.0) & (np.abs(rel @ t) < width / 2 + 1.0)
    rows, pos = rows[near], pos[near]
    origin = model.sight.of(rows).astype(np.float64)
    known = np.isfinite(origin).all(axis=1) & (origin[:, 2] < bottom)
    pos, origin = pos[known], origin[known]
    if not len(pos):
        return 0.0
    # the ray at heights between the candidate's underside and just under the slab
    h = np.linspace(bottom + cfg.plane_threshold_m, zc - 2 * cfg.plane_threshold_m, _OVER_SAMPLES)
    f = (h[None, :] - origin[:, 2:3]) / (pos[:, 2:3] - origin[:, 2:3])
    xy = origin[:, None, :2] + f[..., None] * (pos[:, None, :2] - origin[:, None, :2])
    along, across = (xy - centre) @ axis, (xy - centre) @ t
    inner = max(width / 2 - voxel, voxel / 2)  # its middle, clear of the voxels at its faces
    through = (np.abs(across) < inner) & (np.abs(along) < length / 2) & (f > 0) & (f < 1)
    bins = np.unique(np.floor((along[through] + length / 2) / voxel).astype(np.int64))
    return min(len(bins) / max(length / voxel, 1.0), 1.0)


def fit_beams(model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]) -> None:
    cfg, voxel = model.cfg, model.voxel
    zf, zc = storey
    if not any(s.kind is Kind.CEILING for s in model.slabs):
        return  # a beam hangs under a slab
    hang, origin, rows, cell = model._footprints(vmap, block, zc - cfg.beam_max_depth_m, zc - cfg.plane_threshold_m)
    if not len(rows):
        return
    z_top = zc - cfg.beam_max_depth_m
    below, b_origin, _, _ = model._footprints(vmap, block, zf + _FLOOR_MARGIN_M, z_top, free_only=False)
    full = max(1.0, (z_top - zf - _FLOOR_MARGIN_M) / voxel)
    support = np.zeros(hang.shape, np.float64)
    if below.size:  # the same cells in the grid of what stands below (a wall's head is not a beam)
        off = b_origin - origin
        xs, ys = np.nonzero(below)
        xs, ys = xs + off[0], ys + off[1]
        ok = (xs >= 0) & (ys >= 0) & (xs < hang.shape[0]) & (ys < hang.shape[1])
        support[xs[ok], ys[ok]] = below[xs[ok] - off[0], ys[ok] - off[1]] / full
    cand = (hang > 0) & (support < 0.3)
    labels, _ = ndimage.label(cand, structure=np.ones((3, 3)))
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):  # one iteration per candidate footprint
        xs, ys = np.nonzero(labels[sl] == k)
        if len(xs) < 3:
            continue
        pts = np.c_[xs + sl[0].start, ys + sl[1].start].astype(np.float64) * voxel
        mean = pts.mean(axis=0)
        _, vec = np.linalg.eigh(np.cov((pts - mean).T) + 1e-9 * np.eye(2))
        axis = vec[:, 1]
        along, across = (pts - mean) @ axis, (pts - mean) @ vec[:, 0]
        length, width = np.ptp(along) + voxel, np.ptp(across) + voxel
        if length < cfg.beam_min_length_m or width > cfg.beam_max_width_m:
            continue
        if len(xs) * voxel**2 < 0.5 * length * width:
            continue  # not a bar: the corner where two walls meet the ceiling, a lamp's outline
        centre = mean + origin * voxel
        if not _owned(model, i, centre):
            continue
        if along_wall(model, i, pts + (origin + 0.5) * voxel, cfg.beam_wall_reach_m) > 0.5:
            continue  # along a wall's plane: the wall's head (its lower part hidden or not yet seen)
        members = np.isin(
            cell[:, 0] * hang.shape[1] + cell[:, 1], (xs + sl[0].start) * hang.shape[1] + ys + sl[1].start
        )
        on = rows[members]
        if not len(on):
            continue
        pos = vmap.positions[on]
        underside = float(pos[:, 2].min())
        seen_over = _slab_seen_over(model, vmap, block, centre + 0.5 * voxel, axis, length, width, underside, zc)
        if seen_over > _SEEN_OVER_SHARE:
            continue  # rays reached the slab through where the beam would stand: it hangs free of the slab
        # a beam shows its underside: a flat bottom across most of its footprint (a wall's head does not)
        bottom = pos[:, 2] < pos[:, 2].min() + 2 * cfg.plane_threshold_m
        under_cells = len(np.unique(cell[members][bottom], axis=0))
        if under_cells < 0.5 * len(xs):
            continue
        e = Element(
            model._new_id(),
            Kind.BEAM,
            np.r_[pos[:, :2].min(axis=0), pos[:, 2].min()],
            np.r_[pos[:, :2].max(axis=0), zc],
            axis=np.r_[axis, 0.0],
        )
        model.beams[e.id] = e
        model.tiles[i].elements.append(e.id)
        model.elem[on] = e.id
        model.kind_cls[on] = SemanticClass.BEAM
