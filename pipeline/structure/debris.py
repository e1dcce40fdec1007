"""Debris of the structure model: masses lying on a confirmed floor slab that no furniture is shaped like, found
in a tile's block of the levelled map after its walls, columns and beams (issue #28: the networks never call
debris in rooms they have not seen).

Candidates are the voxels of the block on no element, standing on the story's floor slab up to
`debris_max_height_m`; they are cut into connected components (26-neighbourhood of voxels). A component whose
voxels reach higher (95th percentile) is part of something standing (furniture, a wall not found): not debris.
Two shapes are debris:

- a *layer*: everything within `debris_layer_m` of the floor over at least `debris_layer_cells` footprint
  cells, its median `debris_layer_min_m` above the floor around it at least (fallen ceiling panels, roof sheets,
  strewn rubble: no furniture lies that flat that low; the floor seen off its slab's plane, where the map drifted,
  lies level with the floor around it);
- a *mound*: at most `debris_mound_m` high and `debris_mound_min_m` across at least (a heap, not a box), its
  surface made of many small faces at random angles (a share `debris_min_oblique` of its voxels' local normals
  neither vertical nor horizontal), and no large flat top (at most `debris_max_flat_top` of its footprint's top
  cells at one height: a seat, a table top, a cabinet).

Each is one element (a box, `Kind.DEBRIS`); its voxels take debris, fused like every element's class (a
confident non-structural class of the network stays: `structure.keep_confidence`).
"""

from __future__ import annotations

from itertools import pairwise
from typing import TYPE_CHECKING, Final

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.structure.elements import Element, Kind

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel
    from aftershock.pipeline.voxel_map import VoxelMap

_NORMAL_K: Final = 16  # local normals: PCA over this many nearest candidates ...
_NORMAL_RADIUS_M: Final = 0.3  # ... within this (the faces of a few broken pieces)
_OBLIQUE: Final = (0.3, 0.9)  # |n_z| between these: a face neither upright nor level
_FLAT_TOP_MIN_M: Final = 0.2  # a flat top is looked for above this (a seat, a table top, a shelf) ...
_FLAT_TOP_BIN_M: Final = 0.05  # ... as the most common top height, in bins of this
_MIN_VOXELS: Final = 15  # a component this small says nothing about its shape
_RING_CELLS: Final = 3  # a layer's floor is measured in a ring this many cells (of one voxel) around it
_TRIM_M: Final = 0.03  # a layer's voxels lower than this above the floor around it are the floor's


def _floor_height(model: StructureModel, pos: np.ndarray, sensor_z: float) -> np.ndarray:
    """Height of each point above the highest floor slab under it that lies below the sensor (NaN: none)."""
    out = np.full(len(pos), np.nan)
    for s in model.floors:  # one iteration per floor slab
        zf = s.height_at(pos[:, :2])
        above = pos[:, 2] - zf
        ok = (zf < sensor_z) & (above > -model.cfg.plane_threshold_m) & ~(above >= out)
        out[ok] = above[ok]
    return out


def _oblique_share(pos: np.ndarray) -> np.ndarray:
    """Per point, whether its local normal (PCA of its neighbours) is neither vertical nor horizontal."""
    nz = _normal_z(pos)
    return (nz > _OBLIQUE[0]) & (nz < _OBLIQUE[1])


def _normal_z(pos: np.ndarray) -> np.ndarray:
    """Per point, |n_z| of its local normal (PCA of its neighbours among `pos`; NaN with fewer than 3)."""
    n = len(pos)
    if n < 3:
        return np.full(n, np.nan)
    k = min(_NORMAL_K, n)
    dist, idx = cKDTree(pos).query(pos, k=k)
    nb = pos[idx.reshape(n, k)]
    w = (dist.reshape(n, k) <= _NORMAL_RADIUS_M)[..., None].astype(np.float64)
    count = np.maximum(w.sum(axis=1), 1.0)
    mean = (nb * w).sum(axis=1) / count
    centred = (nb - mean[:, None, :]) * w
    cov = np.einsum("bki,bkj->bij", centred, centred) / count[:, :, None]
    _, vec = np.linalg.eigh(cov)
    return np.where(w.sum(axis=(1, 2)) >= 3, np.abs(vec[:, 2, 0]), np.nan)


def _flat_top(cells: np.ndarray, height: np.ndarray) -> float:
    """Share of a footprint's cells whose top lies at its most common top height above `_FLAT_TOP_MIN_M`."""
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    uniq, inv = np.unique(key, return_inverse=True)
    top = np.full(len(uniq), -np.inf)
    np.maximum.at(top, inv.ravel(), height)
    high = np.round(top[top > _FLAT_TOP_MIN_M] / _FLAT_TOP_BIN_M).astype(np.int64)
    if not len(high):
        return 0.0
    return float(np.unique(high, return_counts=True)[1].max() / len(uniq))


def _narrow(cells: np.ndarray, voxel: float) -> float:
    """A footprint's extent across its long axis (PCA of its cells), in metres."""
    xy = cells.astype(np.float64)
    centred = xy - xy.mean(axis=0)
    _, vec = np.linalg.eigh(centred.T @ centred + 1e-9 * np.eye(2))
    return float(np.ptp(centred @ vec[:, 0]) + 1) * voxel


def _components(cell: np.ndarray, members: np.ndarray) -> list[np.ndarray]:
    """`members` (indices into `cell`, voxel cells from 0) cut into 26-connected components of `_MIN_VOXELS` at
    least."""
    if len(members) < _MIN_VOXELS:
        return []
    c = cell[members]
    c0 = c.min(axis=0)
    grid = np.zeros(c.max(axis=0) - c0 + 1, bool)
    grid[tuple((c - c0).T)] = True
    labels, _ = ndimage.label(grid, structure=np.ones((3, 3, 3)))
    comp = labels[tuple((c - c0).T)]
    order = np.argsort(comp, kind="stable")
    bounds = np.r_[0, np.flatnonzero(np.diff(comp[order])) + 1, len(order)]
    return [members[order[a:b]] for a, b in pairwise(bounds) if b - a >= _MIN_VOXELS]


def _ring_height(cells: np.ndarray, low_cells: np.ndarray, low_h: np.ndarray) -> float:
    """Median height of the low voxels (`low_cells`, `low_h`) in a ring `_RING_CELLS` wide around a footprint's
    cells (0 where nothing was seen there)."""
    lo = cells.min(axis=0) - _RING_CELLS
    shape = cells.max(axis=0) - lo + 1 + _RING_CELLS
    grid = np.zeros(shape, bool)
    grid[tuple((cells - lo).T)] = True
    ring = ndimage.binary_dilation(grid, iterations=_RING_CELLS) & ~grid
    c = low_cells - lo
    inside = np.all((c >= 0) & (c < shape), axis=1)
    hit = np.zeros(len(c), bool)
    hit[inside] = ring[c[inside, 0], c[inside, 1]]
    return float(np.median(low_h[hit])) if hit.any() else 0.0


def fit_debris(
    model: StructureModel, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float], sensor_z: float
) -> None:
    """Debris of tile `i` (components of its block's free voxels whose centre lies in the tile)."""
    cfg, voxel = model.cfg, model.voxel
    every = vmap.positions[block]
    h_every = _floor_height(model, every, sensor_z)
    sel = (model.elem[block] < 0) & (h_every > 0) & (h_every < storey[1] - storey[0] - cfg.plane_threshold_m)
    rows, pos, h = block[sel], every[sel], h_every[sel]  # NaN (no floor under it) is never selected
    if len(rows) < _MIN_VOXELS:
        return
    low = (h_every > -cfg.plane_threshold_m) & (h_every < cfg.debris_layer_m)
    low_cells = np.floor(every[low, :2] / voxel).astype(np.int64)  # the floor around a layer, and what lies there
    low_h = h_every[low]
    cell = np.floor(pos / voxel).astype(np.int64)
    corner = cell.min(axis=0)
    cell -= corner
    for mine in _components(cell, np.arange(len(rows))):  # one iteration per component
        hh = h[mine]
        top = float(np.percentile(hh, 95))
        if top > cfg.debris_max_height_m:
            continue  # part of something standing (furniture, a wall not found), or a heap against it
        p = pos[mine]
        centre = (p[:, :2].min(axis=0) + p[:, :2].max(axis=0)) / 2
        if not np.array_equal(np.floor(centre / cfg.tile_m).astype(np.int64), model.tile_xy[i]):
            continue  # another tile's
        footprint = cell[mine, :2]
        cells = len(np.unique(footprint[:, 0] * (int(footprint[:, 1].max()) + 1) + footprint[:, 1]))
        layer = top <= cfg.debris_layer_m and cells >= cfg.debris_layer_cells
        if layer:  # above the floor around it: not the floor itself seen off its plane (a drifted map, a step)
            ring = _ring_height(footprint + corner[:2], low_cells, low_h)
            layer = float(np.median(hh)) - ring >= cfg.debris_layer_min_m
            if layer:  # its voxels lower than that are the floor's
                mine = mine[hh - ring >= _TRIM_M]
                p = pos[mine]
        if not layer:
            if top > cfg.debris_mound_m or _narrow(footprint, voxel) < cfg.debris_mound_min_m:
                continue  # too high, or too small for a heap (a box, a bag)
            if _flat_top(footprint, hh) > cfg.debris_max_flat_top:
                continue
            if float(np.mean(_oblique_share(p))) < cfg.debris_min_oblique:
                continue  # faces upright and level: furniture, a box, a fallen door
        on = rows[mine]
        e = Element(model._new_id(), Kind.DEBRIS, p.min(axis=0), p.max(axis=0))
        model.debris[e.id] = e
        model.tiles[i].elements.append(e.id)
        model.elem[on] = e.id
        model.kind_cls[on] = SemanticClass.DEBRIS
