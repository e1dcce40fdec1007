"""The structure model: a building's slabs, walls, columns and beams (the ground outdoors) found from geometry
and gravity in the levelled voxel map as it grows, and the labels they decide.

Geometry decides what geometry can (issue #28): a voxel on a confirmed element takes the element's class unless
the network is confident of something that lies on it (debris on a floor, a board on a wall); the rest keep
the network's label, checked against the structure (no ceiling below the sensor, no floor above it, a ceiling
needs an overhead slab; outdoors there is ground, never floor or ceiling).

Incremental and amortised:
- story slabs: a height histogram of the map, updated with each scan's new voxels; its density bands are the
  one slab test of `pipeline.damage.drift` (`bands_of_counts`), and a band's plane is refitted (RANSAC) only
  when the band grew by a share (`slab_refit_growth`);
- walls, columns and beams: per square tile of the map (`tile_m`); a tile is refitted when it gained
  `min_new_voxels`, at most `tiles_per_scan` tiles a scan (the most changed first), every changed tile at
  `finish()`. Walls are vertical RANSAC planes per tile, merged across tiles into walls (coplanar, touching);
  columns are compact footprints occupied over most of the story's height, or runs proud of a wall's plane
  (engaged); beams are elongated footprints occupied just under a ceiling, open below, off the walls
  (`pipeline/structure/columns.py`);
- new voxels are checked against the elements found so far as they arrive (a vectorised test per element).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.classes import NETWORK_CLASSES, UNLABELLED, SemanticClass
from aftershock.pipeline.config import Environment, StructureConfig
from aftershock.pipeline.damage.drift import bands_of_counts, ransac_plane
from aftershock.pipeline.structure.columns import fit_beams, fit_columns
from aftershock.pipeline.structure.debris import fit_debris
from aftershock.pipeline.structure.elements import CLASS_OF, Element, Kind
from aftershock.pipeline.structure.lookup import member, sorted_union
from aftershock.pipeline.structure.openings import (
    Opening,
    Sightlines,
    find_openings,
    leaf_columns,
    mark_openings,
)
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import KeyTable, VoxelMap, pack_keys

log = logging.getLogger(__name__)

_HIST_BINS: Final = 1 << 13  # height histogram: enough bins for +-200 m at 5 cm
_SLAB_SAMPLE: Final = 2000  # a slab plane is fitted on at most this many voxels of its band
_SLAB_ITERATIONS: Final = 100  # a slab is the largest plane of its thin band
_WALL_ITERATIONS: Final = 80  # a tile's few thousand voxels hold a handful of walls
_LINE_SCORE_POINTS: Final = 1000
_CREDIT_SCANS: Final = 10  # unspent refit time carries over for at most this many scans
_WALL_PLANES: Final = 6  # vertical planes tried per tile
_WALL_GAP_M: Final = 0.5  # a wall's piece in a tile leaves gaps no wider than this ...
_WALL_JOIN_GAP_M: Final = 1.5  # ... and its pieces on one line, gaps no wider than this (a door, a cabinet hiding it)
_SURFACE_CELL_M: Final = 0.2  # a slab's voxels fill the cells of this size they cover ...
_MIN_INTERIOR: Final = 0.25  # ... at least this share of them inside the surface (not on its outline)
_FACE_CELL_M: Final = 0.5  # a wall (seen by scan lines far apart on it) fills the cells of this size ...
_MIN_FACE_FILL: Final = 0.4  # ... of its extent at least this share (a strip through furniture or the ground does not)
_CROSS_CELL_M: Final = 0.2  # a face's points with the map on both sides in cells of this size (or 2 voxels) ...
_MAX_CROSSING: Final = 0.5  # ... more than this share of them: a cut through clutter (pipeline.planecheck's rule)
_WALL_Z_GAP_M: Final = (
    0.8  # a wall piece's voxels leave no vertical gap wider than this (rings of 2 deg at 4 m: 0.14 m)
)
_WALL_HEAD_M: Final = 0.5  # a face stopping this far under the ceiling with the ceiling seen ...
_CEILING_SIDE_M: Final = 1.0  # ... within this on both sides of it stands in the room
_WALL_LINE_DEG: Final = 15.0  # a short stretch's direction is measured this badly (1.5 m of a wall seen from 3 m)
_COPLANAR_M: Final = 0.15  # stretches of one face: the shorter's middle this close to the longer's line
_FURNITURE_M: Final = (0.15, 0.6)  # a face this far in front of a wall (a bookcase 0.3-0.42 m deep, a cabinet) ...
_FURNITURE_WIDTH_M: Final = 3.0  # ... at most this wide, beside or before that wall, seen from its side: furniture
_WALL_OBJECT_M: Final = 2.5  # a wall object spans this far along its line at least (bookcases stand 0.8-1.4 m wide)
_OVER_M: Final = 1.0  # rays crossing a face's plane up to this far over its top, within its width ...
_OVER_BEYOND_M: Final = 0.25  # ... to returns this far behind it ...
_OVER_SHARE: Final = 0.5  # ... in this share of its (0.5 m) cells: it stops under the ceiling, furniture
_FACADE_RELIEF_M: Final = 0.5  # outdoors a facade's recesses, balconies and pilasters stand this far off its plane
_FACADE_DEG: Final = 30.0  # ... and a slanted line RANSAC drew through that relief turns this far from it at most
_SLAB_FITS_PER_SCAN: Final = 2  # a floor and a ceiling band in the same scan
_MIN_SLAB_SHARE: Final = 0.1  # a slab holds at least this share of the largest slab's voxels (not a table top)
_SLAB_XY_MARGIN_M: Final = 1.0  # new voxels join a slab within this of its extent (it grows as it is seen)
NON_STRUCTURAL: Final = np.ones(1 << 16, bool)  # per class id: may lie on an element (table, debris, board ...)
NON_STRUCTURAL[[c.value for c in CLASS_OF.values()]] = False
NON_STRUCTURAL[UNLABELLED] = False
# per class id: an element of this class is one object (a story's slab, a column, a beam: one true instance each in
# the simulator); a wall piece's voxel takes its wall's object instead (`wall_object`: one per wall line, both faces)
OBJECT_CLASSES: Final = np.zeros(1 << 16, bool)
OBJECT_CLASSES[[SemanticClass.FLOOR, SemanticClass.CEILING, SemanticClass.COLUMN, SemanticClass.BEAM]] = True


@dataclass(slots=True)
class _Slab:
    id: int
    kind: Kind
    band: tuple[float, float]
    plane: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    fitted_count: int  # voxels in its band when last fitted
    voxels: int = 0  # on its plane when fitted
    mid_z: float = field(init=False)  # the middle of its extent in height (its height for the story rules)

    def __post_init__(self) -> None:
        self.mid_z = float(np.median([self.lo[2], self.hi[2]]))

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        return -(xy @ self.plane[:2] + self.plane[3]) / self.plane[2]


@dataclass(slots=True)
class _Piece:
    """A wall's piece in one tile: a vertical plane and the voxels on it."""

    id: int
    tile: int
    normal: np.ndarray  # (2,) horizontal unit normal
    offset: float  # n . xy + offset = 0
    u: tuple[float, float]  # extent along the wall direction (-n_y, n_x)
    z: tuple[float, float]
    rows: np.ndarray
    moments: np.ndarray  # (6,) count, sum x, sum y, sum xx, sum xy, sum yy of its voxels: its wall's line


@dataclass(slots=True, frozen=True)
class _PieceLines:
    """Confirmed pieces as `_join_pieces` measures them: line (normal, offset), direction, heights, extent along
    the line, their tiles' cells and ids."""

    normal: np.ndarray
    offset: np.ndarray
    direction: np.ndarray
    z: np.ndarray
    u: np.ndarray
    tile_xy: np.ndarray
    pids: np.ndarray


@dataclass(slots=True)
class _Tile:
    chunks: list[np.ndarray] = field(default_factory=list)
    pending: int = 0  # voxels added since the last fit
    elements: list[int] = field(default_factory=list)  # column and beam ids found in it
    pieces: list[int] = field(default_factory=list)

    def rows(self) -> np.ndarray:
        if len(self.chunks) > 1:
            self.chunks = [np.concatenate(self.chunks)]
        return self.chunks[0] if self.chunks else np.zeros(0, np.int64)


def _interior_share(xy: np.ndarray, cell_m: float = _SURFACE_CELL_M) -> float:
    """Share of the occupied cells (of `cell_m`) of points whose four neighbours are occupied too: a surface
    seen whole is mostly interior, lines (scan rings, a wall's foot) have none."""
    if not len(xy):
        return 0.0
    c = np.floor(xy / cell_m).astype(np.int64)
    c -= c.min(axis=0)
    shape = c.max(axis=0) + 1
    grid = np.zeros(shape + 2, bool)
    grid[c[:, 0] + 1, c[:, 1] + 1] = True
    inner = grid[1:-1, 1:-1] & grid[:-2, 1:-1] & grid[2:, 1:-1] & grid[1:-1, :-2] & grid[1:-1, 2:]
    return float(inner.sum() / max(grid.sum(), 1))


def _fill_share(uv: np.ndarray, cell_m: float) -> float:
    """Share of the cells (of `cell_m`) in the extent of points that hold any."""
    c = np.floor(uv / cell_m).astype(np.int64)
    c -= c.min(axis=0)
    shape = c.max(axis=0) + 1
    return float(len(np.unique(c[:, 0] * shape[1] + c[:, 1])) / (shape[0] * shape[1]))


def _crossing_share(face: np.ndarray, around: np.ndarray, line: np.ndarray, threshold_m: float, cell_m: float) -> float:
    """Share of a vertical face's points (`face`, on `line`) with map points `around` just off it on both sides
    next to them: a line RANSAC drew through furniture or a cluttered corner has the map on both sides, a wall's
    face has space in front and nothing behind (the test of pipeline.planecheck, the yardstick's own)."""
    if not len(face) or not len(around):
        return 0.0
    direction = np.array([-line[1], line[0]])
    side = around[:, :2] @ line[:2] + line[2]
    reach = 3 * cell_m / 2
    near = (np.abs(side) > 1.5 * threshold_m) & (np.abs(side) < reach)
    around, side = around[near], side[near]

    def cells(p: np.ndarray) -> np.ndarray:
        return np.floor(np.column_stack([p[:, :2] @ direction, p[:, 2]]) / cell_m).astype(np.int64)

    # which of the face's cells the map holds on each side: grids over the face's cells (in place of sets)
    own = cells(face)
    lo = own.min(axis=0)
    own -= lo
    shape = own.max(axis=0) + 1
    seen = []
    for c in (cells(around[side > 0]) - lo, cells(around[side < 0]) - lo):  # in front, behind
        c = c[np.all((c >= 0) & (c < shape), axis=1)]
        grid = np.zeros(shape, bool)
        grid[c[:, 0], c[:, 1]] = True
        seen.append(grid[own[:, 0], own[:, 1]])
    return float(np.mean(seen[0] & seen[1]))


def _stands_in_room(face: np.ndarray, overhead: np.ndarray, line: np.ndarray, ceiling_z: float) -> bool:
    """Whether a vertical face stops well under the ceiling and the ceiling is seen on both sides of its line over
    most of its width: a wall reaching up would hide the ceiling beyond it, so this face stands in the room
    (a bookcase, a partition, a cabinet's front), not a wall bounding it."""
    top = float(np.percentile(face[:, 2], 99))
    if not len(overhead) or ceiling_z - top < _WALL_HEAD_M:
        return False
    direction = np.array([-line[1], line[0]])
    side = overhead[:, :2] @ line[:2] + line[2]
    near = np.abs(side) < _CEILING_SIDE_M
    u = np.floor(overhead[near, :2] @ direction / _FACE_CELL_M).astype(np.int64)
    cells = np.unique(np.floor(face[:, :2] @ direction / _FACE_CELL_M).astype(np.int64))
    both = np.isin(cells, u[side[near] > 0]) & np.isin(cells, u[side[near] < 0])
    return bool(both.mean() > 0.5)


def ransac_line(
    xy: np.ndarray,
    threshold_m: float,
    iterations: int,
    rng: np.random.Generator,
    context: np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray]:
    """The line (unit normal, offset: n . xy + offset = 0) most points lie within `threshold_m` of, and that
    mask: a vertical plane of the levelled map, seen from above. All hypotheses scored at once on a sample, the
    best refined by a principal direction of its inliers among `xy` and `context` (points around, on which a
    short piece's direction is measured along the whole wall)."""
    n = len(xy)
    i, j = rng.integers(0, n, size=(2, iterations))
    d = xy[j] - xy[i]
    length = np.hypot(d[:, 0], d[:, 1])
    good = length > 2 * threshold_m
    if not good.any():
        return None, np.zeros(n, bool)
    normal = np.stack([-d[good, 1], d[good, 0]], axis=1) / length[good, None]
    offset = -np.einsum("ij,ij->i", normal, xy[i[good]])
    sample = xy[rng.choice(n, size=min(n, _LINE_SCORE_POINTS), replace=False)]
    score = sample @ normal.T  # (points, hypotheses), worked in place: one temporary
    score += offset
    np.abs(score, out=score)
    best = int(np.argmax((score < threshold_m).sum(axis=0)))
    nb, ob = normal[best], float(offset[best])
    every = xy if context is None or not len(context) else np.concatenate([xy, context])
    before = None
    for _ in range(3):  # refine on the inliers
        on = np.abs(every @ nb + ob) < threshold_m
        if on.sum() < 3 or (before is not None and np.array_equal(on, before)):
            break  # too few, or the same inliers as the line was fitted on: it would come out the same
        before = on
        inliers = every[on]
        centre = inliers.mean(axis=0)
        _, vec = np.linalg.eigh(_cov2(inliers - centre))
        nb = vec[:, 0]
        ob = float(-nb @ centre)
    return np.append(nb, ob), np.abs(xy @ nb + ob) < threshold_m


def _longest_run(order: np.ndarray, values: np.ndarray, gap: float) -> np.ndarray:
    """The longest stretch of `order` (the first of the longest) whose sorted `values` leave no gap over `gap`."""
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(values) > gap) + 1, [len(order)]])
    k = int(np.argmax(np.diff(bounds)))
    return order[bounds[k] : bounds[k + 1]]


def _cov2(pts: np.ndarray) -> np.ndarray:
    """`np.cov(pts.T)` of (N, 2) points, its steps as numpy takes them (the same bits) without its checks."""
    x = np.array(pts.T, ndmin=2, dtype=np.float64)
    x -= x.mean(axis=1)[:, None]
    c = np.dot(x, x.T.conj())
    c *= np.true_divide(1, x.shape[1] - 1)
    return c


class StructureModel:
    """See the module docstring. `update(vmap, sensor)` after each scan's labelling; `finish(vmap)` at the end."""

    def __init__(self, cfg: StructureConfig, environment: Environment, voxel_size: float) -> None:
        self.cfg = cfg
        self.outdoor = environment is Environment.OUTDOOR
        self.voxel = float(voxel_size)
        self.n = 0
        cap = 4096
        self.net_cls = np.full(cap, UNLABELLED, np.uint16)  # the network's class and score when the voxel opened
        self.net_score = np.zeros(cap, np.float32)
        self.sensor_z = np.zeros(cap, np.float32)  # height of the sensor that opened the voxel
        self.tile_of = np.zeros(cap, np.int32)
        self.zbin = np.zeros(cap, np.int32)
        self.elem = np.full(cap, -1, np.int32)  # element (slab, wall piece, column, beam) the voxel lies on
        self.kind_cls = np.full(cap, UNLABELLED, np.uint16)  # that element's class (UNLABELLED: none)
        self.fused = np.full(cap, UNLABELLED, np.uint16)  # the class the structure gives (UNLABELLED: no say)
        self.fused_score = np.zeros(cap, np.float32)  # the confidence of that class (see `_fuse`)
        self.has_net = np.ones(cap, bool)  # the network labelled the voxel (False: an element explained it on arrival)
        self.lab_cls = np.full(cap, UNLABELLED, np.uint16)  # the labeller's latest class and score of the voxel
        self.lab_score = np.zeros(cap, np.float32)  # (written back where the structure no longer has a say)
        self.shown_cls = np.full(cap, UNLABELLED, np.uint16)  # what `apply` last wrote (UNLABELLED: the labeller's)
        self.shown_score = np.zeros(cap, np.float32)
        self.hist = np.zeros(_HIST_BINS, np.int64)
        self.hist_base: int | None = None
        self.slabs: list[_Slab] = []
        self.slab_search_n = 0
        self.tiles: list[_Tile] = []
        self.tile_keys = KeyTable()
        self.tile_xy = np.zeros((0, 2), np.int64)
        self.around_of: dict[int, tuple[int, list[int]]] = {}  # tile -> (tiles then, `_around`): see there
        self.pieces: dict[int, _Piece] = {}
        self.wall_of_piece: dict[int, int] = {}  # piece id -> wall id (confirmed walls only)
        self.piece_span: dict[int, np.ndarray] = {}  # confirmed piece id -> its extent along its wall's line
        self.wall_line: dict[int, np.ndarray] = {}  # wall id -> its line (normal, offset) over all its pieces, z range
        self.piece_lines: dict[tuple[tuple[int, ...], bool], _PieceLines] = {}  # `_piece_lines`, until walls change
        self.wall_object: dict[int, int] = {}  # wall id -> the wall object it is part of (none: furniture's face)
        self.columns: dict[int, Element] = {}
        self.beams: dict[int, Element] = {}
        self.debris: dict[int, Element] = {}  # masses on a floor slab (pipeline/structure/debris.py)
        self.ground_keys = KeyTable()
        self.ground_min = np.zeros(0, np.float64)
        self.next_id = 1
        self.arrived = 0  # voxels taken so far, and how many of them lay on an element already (the share a
        self.explained = 0  # network could skip)
        self.final = False  # finish() ran: every slab band and tile was looked at
        self.credit = 0  # voxels the refits of this scan may still go through (amortised budget)
        self.refit_voxels = 0  # voxels the refits went through so far
        self.refits = 0  # tiles refitted so far (a test reads which, `last_tiles`)
        self.last_tiles: list[tuple[int, int]] = []
        self.updated = 0  # rows up to here went through `update` (those up to `n` through `take`)
        self.emb_of: dict[int, np.ndarray] = {}  # element id -> the mean embedding of its network-labelled voxels
        self.applied = 0  # rows up to here were written by `apply`
        self.dirty: list[np.ndarray] = []  # rows fused since the last `apply`
        self.last_applied = 0  # rows the last `apply` wrote
        self.support_counts: np.ndarray | None = None  # voxels per element id at the last fusion (see `_support`)
        self.sight = Sightlines()  # where the sensor stood for each voxel (`observe`), for the openings
        self.openings: list[Opening] = []
        self.leaf_rows: dict[int, np.ndarray] = {}  # per column found to be a door's open leaf: its voxels

    # ------------------------------------------------------------------------------------------ bookkeeping

    def _new_id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def _grow(self, n: int) -> None:
        if n <= len(self.net_cls):
            return
        cap = max(n, 2 * len(self.net_cls))
        names = ("net_cls", "net_score", "sensor_z", "tile_of", "zbin", "elem", "kind_cls", "fused", "fused_score")
        for name in (*names, "has_net", "lab_cls", "lab_score", "shown_cls", "shown_score"):
            old = getattr(self, name)
            fills = {"net_cls": UNLABELLED, "elem": -1, "kind_cls": UNLABELLED, "fused": UNLABELLED, "has_net": 1}
            fills.update(lab_cls=UNLABELLED, shown_cls=UNLABELLED)
            fill = fills.get(name, 0)
            arr = np.full(cap, fill, old.dtype)
            arr[: len(old)] = old
            setattr(self, name, arr)

    @property
    def floors(self) -> list[_Slab]:
        return [s for s in self.slabs if s.kind is Kind.FLOOR]

    @property
    def has_floor(self) -> bool:
        """Indoors a floor slab, outdoors ground cells: without either the network labels alone."""
        return bool(len(self.ground_min)) if self.outdoor else bool(self.floors)

    # ------------------------------------------------------------------------------------------ per scan

    def take(self, vmap: VoxelMap, sensor_z: float) -> np.ndarray:
        """The voxels opened since the last call into their tiles and the slab histogram, and onto the elements
        found so far. Returns those on an element where the structure has a say (a floor found): `explain`
        labels them, the network need not."""
        first, n = self.n, len(vmap)
        self._grow(n)
        new = np.arange(first, n, dtype=np.int64)
        if not len(new):
            return new
        self.sensor_z[new] = sensor_z
        self._add_rows(vmap, new)
        self.n = n
        if self.outdoor:
            self._ground_rows(vmap, new)
        else:
            self._join_elements(vmap, new)
        on = new[self.kind_cls[new] != UNLABELLED]
        self.arrived += len(new)
        self.explained += len(on)
        return on if self.has_floor else new[:0]

    def explain(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> np.ndarray:
        """Before the network: the scan's new voxels taken (`take`); those on a confirmed element get its class,
        its confidence (its support) and its embedding (the mean of its voxels the network saw: an element is one
        object for the clustering). Returns those rows: the network skips them (with colour only where
        `skip_with_colour` says so)."""
        assert frame.pose is not None, "a frame is registered before it is labelled"
        given = self.take(vmap, float(frame.pose[2, 3]))
        colour = frame.scan.colors is not None
        if not self.cfg.skip_explained or (colour and not self.cfg.skip_with_colour) or not len(given):
            return given[:0]
        given = given[self.kind_cls[given] < NETWORK_CLASSES]  # the ground outdoors is no network's class: not skipped
        emb, known = self._element_embeddings(vmap, given)
        if vmap.embedding_dim:  # an element no network-labelled voxel is known on yet: its voxels go to the network
            given, emb = given[known], emb[known]
        vmap.class_ids[given] = self.kind_cls[given]
        # the support as of the last scan's fusion (the fusion after the network gives them the current one)
        vmap.scores[given] = self._support(given, self.support_counts)
        if vmap.embedding_dim:
            vmap.embeddings[given] = emb
        self.has_net[given] = False
        self.net_cls[given] = UNLABELLED  # no network label: a confident one cannot keep (see `_fuse`)
        self.net_score[given] = 0.0
        return given

    def _element_embeddings(self, vmap: VoxelMap, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, E) unit mean embeddings of the network-labelled voxels of the element each row lies on, and whether
        it has any. Computed once per element, on the voxels of the tiles the rows lie in (ids never return)."""
        e = vmap.embedding_dim
        elem = self.elem[rows]
        uniq, inv = np.unique(elem, return_inverse=True)
        missing = np.array([int(u) for u in uniq if int(u) not in self.emb_of], np.int64)
        if e and len(missing):
            cand = self._rows_of_tiles(np.unique(self.tile_of[rows[np.isin(elem, missing)]]))
            cand = cand[self.has_net[cand] & np.isin(self.elem[cand], missing)]
            owner = self.elem[cand]
            order = np.argsort(owner, kind="stable")
            ids, start = np.unique(owner[order], return_index=True)
            if len(ids):
                sums = np.add.reduceat(vmap.embeddings[cand[order]].astype(np.float64), start, axis=0)
                norm = np.linalg.norm(sums, axis=1)
                for j in np.flatnonzero(norm > 0):  # one iteration per element first seen this scan
                    self.emb_of[int(ids[j])] = (sums[j] / norm[j]).astype(np.float32)
        out = np.zeros((len(uniq), max(e, 1)), np.float32)
        known = np.zeros(len(uniq), bool)
        for k, u in enumerate(uniq.tolist()):  # one iteration per element the scan's voxels lie on
            vec = self.emb_of.get(u)
            if vec is not None:
                out[k, :e] = vec
                known[k] = True
        return out[inv.ravel(), :e], known[inv.ravel()]

    def _rows_of_tiles(self, tiles: np.ndarray) -> np.ndarray:
        chunks = [self.tiles[int(t)].rows() for t in tiles]
        return np.concatenate(chunks) if chunks else np.zeros(0, np.int64)

    def update(self, vmap: VoxelMap, sensor_z: float, finishing: bool = False) -> np.ndarray:
        """After the network labelled the scan's new voxels (those `take` or `explain` did not take are taken
        now): refit what changed within the budget, and return the rows whose structure class may have changed."""
        self.take(vmap, sensor_z)
        new = np.arange(self.updated, self.n, dtype=np.int64)
        self.updated = self.n
        changed = [new]
        if len(new):
            net = new[self.has_net[new]]
            self.net_cls[net] = vmap.class_ids[net]
            self.net_score[net] = vmap.scores[net]
        changed.append(self._update_slabs(vmap, finishing))
        changed.extend(self._refit_tiles(vmap, finishing))
        more = [c for c in changed[1:] if len(c)]
        rows = sorted_union(self.n, new, *more) if more else new  # `new` alone is sorted and distinct
        self._fuse(vmap, rows)
        return rows

    def finish(self, vmap: VoxelMap) -> None:
        """End of run: every changed slab band and tile refitted, whatever the budget, and every voxel fused."""
        self.slab_search_n = 0
        self.final = True
        self.update(vmap, float(np.median(self.sensor_z[: self.n])) if self.n else 0.0, finishing=True)
        self._refit_debris(vmap)
        self._drop_wall_heads(vmap)
        self._find_openings(vmap)
        self.wall_object = self._wall_objects(vmap)
        self._fuse(vmap, np.arange(self.n, dtype=np.int64))

    def apply(self, vmap: VoxelMap, rewritten: np.ndarray | None = None) -> None:
        """Write the fused classes and their confidence into the map where they changed, and the labeller's own
        back where the structure no longer has a say. `rewritten`: the older rows the labeller wrote since the
        last call (its instance votes; the new rows it labelled are known); None: it cannot say, every row is
        compared with what was last written here."""
        n = self.n
        new = np.arange(self.applied, n, dtype=np.int64)
        self.applied = n
        if rewritten is None:  # the labeller's values: wherever the map no longer holds what was written here
            old = np.arange(n - len(new), dtype=np.int64)
            ours = (self.shown_cls[old] != UNLABELLED) & (vmap.class_ids[old] == self.shown_cls[old])
            ours &= vmap.scores[old] == self.shown_score[old]
            wrote = np.concatenate([old[~ours], new])
        else:
            wrote = np.concatenate([np.asarray(rewritten, np.int64), new])
        self.lab_cls[wrote] = vmap.class_ids[wrote]
        self.lab_score[wrote] = vmap.scores[wrote]
        rows = sorted_union(n, wrote, *self.dirty)
        self.dirty = []
        self.last_applied = len(rows)
        fused = self.fused[rows]
        on = fused != UNLABELLED
        vmap.class_ids[rows] = np.where(on, fused, self.lab_cls[rows])
        vmap.scores[rows] = np.where(on, self.fused_score[rows], self.lab_score[rows])
        self.shown_cls[rows] = fused
        self.shown_score[rows] = np.where(on, self.fused_score[rows], 0.0)

    def observe(self, vmap: VoxelMap, origin: np.ndarray) -> None:
        """The voxels opened since the last call were seen from a sensor at `origin` (levelled map frame)."""
        self.sight.observe(len(vmap), origin)

    def _refit_debris(self, vmap: VoxelMap) -> None:
        """Debris looked for again in every tile once every tile was refitted: a tile refitted before the tiles
        around it found their walls saw a pile against a wall as one thing with the wall, standing."""
        if self.outdoor or not self.cfg.debris or not self.floors:
            return
        # all of them forgotten first: a tile's debris found before cut the parts of things around it apart
        self._forget(set(self.debris))
        self.debris = {}
        for i, tile in enumerate(self.tiles):  # one iteration per tile of the map
            rows = tile.rows()
            if not len(rows):
                continue
            centre = (self.tile_xy[i] + 0.5) * self.cfg.tile_m
            zs = float(np.median(self.sensor_z[rows]))
            storey = self.storey(centre, zs)
            if storey is not None:
                fit_debris(self, vmap, i, self._tile_block(i), storey, zs)

    def _drop_wall_heads(self, vmap: VoxelMap) -> None:
        """Beams along a wall found since their tile was fitted (a beam is fitted with its tile, before the tiles
        around have their walls): that wall's head, a cornice on it. Dropped, their voxels on no element (the
        fusion's rules then decide them)."""
        if not self.cfg.beams_recheck_walls or not self.beams:
            return
        rows = np.flatnonzero(np.isin(self.elem[: self.n], np.fromiter(self.beams, np.int64, len(self.beams))))
        cells = np.floor(vmap.positions[rows, :2] / self.voxel).astype(np.int64)
        gone: set[int] = set()
        for bid in list(self.beams):  # one iteration per beam
            xy = (np.unique(cells[self.elem[rows] == bid], axis=0) + 0.5) * self.voxel  # its footprint
            if len(xy) and self._near_wall(xy, self.cfg.beam_wall_reach_m).mean() > 0.5:
                gone.add(bid)
                del self.beams[bid]
        self._forget(gone)

    def _forget(self, ids: set[int]) -> None:
        """Elements dropped: their voxels on no element, and out of their tiles' lists."""
        if not ids:
            return
        stale = np.flatnonzero(np.isin(self.elem[: self.n], np.fromiter(ids, np.int64, len(ids))))
        self.elem[stale] = -1
        self.kind_cls[stale] = UNLABELLED
        for tile in self.tiles:  # one iteration per tile of the map
            tile.elements = [e for e in tile.elements if e not in ids]

    def _find_openings(self, vmap: VoxelMap) -> None:
        """Windows and doors in the walls found (pipeline.structure.openings), their voxels taking their class."""
        for op in self.openings:  # one iteration per opening found before
            mine = op.rows[self.elem[op.rows] == op.id]
            self.elem[mine] = -1
            self.kind_cls[mine] = UNLABELLED
        self.openings = find_openings(self, vmap, self.sight)
        leaves = leaf_columns(self, vmap, self.openings) if self.cfg.door_leaf_columns else {}
        self.leaf_rows = {}
        for cid, door in leaves.items():  # a door's open leaf taken for a column: its voxels go to the door
            self.columns.pop(cid, None)
            rows = np.flatnonzero(self.elem[: self.n] == cid)
            door.rows = np.union1d(door.rows, rows)
            self.leaf_rows[cid] = rows  # still one object (a leaf is one panel)
        if leaves:
            for tile in self.tiles:  # one iteration per tile of the map
                tile.elements = [e for e in tile.elements if e not in leaves]
        mark_openings(self, self.openings)

    def _add_rows(self, vmap: VoxelMap, rows: np.ndarray) -> None:
        pos = vmap.positions[rows]
        zb = np.floor(pos[:, 2] / self.cfg.slab_bin_m).astype(np.int64)
        if self.hist_base is None:
            self.hist_base = int(np.median(zb)) - _HIST_BINS // 2
        zb = np.minimum(np.maximum(zb - self.hist_base, 0), _HIST_BINS - 1)
        self.zbin[rows] = zb
        self.hist += np.bincount(zb, minlength=_HIST_BINS)
        txy = np.floor(pos[:, :2] / self.cfg.tile_m).astype(np.int64)
        keys = pack_keys(np.column_stack([txy, np.zeros(len(txy), np.int64)]))
        uniq, inv = np.unique(keys, return_inverse=True)
        idx = self.tile_keys.find(uniq)
        fresh = idx < 0
        if fresh.any():
            idx[fresh] = np.arange(len(self.tiles), len(self.tiles) + fresh.sum())
            self.tile_keys.insert(uniq[fresh], idx[fresh])
            first_of = np.unique(inv, return_index=True)[1]
            self.tile_xy = np.concatenate([self.tile_xy, txy[first_of][fresh]])
            self.tiles.extend(_Tile() for _ in range(int(fresh.sum())))
        tile = idx[inv.ravel()]
        self.tile_of[rows] = tile
        order = np.argsort(tile, kind="stable")
        bounds = np.concatenate([[0], np.flatnonzero(np.diff(tile[order])) + 1, [len(order)]])
        for a, b in pairwise(bounds):  # one iteration per tile touched
            t = self.tiles[int(tile[order[a]])]
            t.chunks.append(rows[order[a:b]])
            t.pending += int(b - a)
        if self.outdoor:
            gkeys = self._ground_keys(pos)
            uniq, inv = np.unique(gkeys, return_inverse=True)
            gidx = self.ground_keys.find(uniq)
            fresh = gidx < 0
            gidx[fresh] = np.arange(len(self.ground_min), len(self.ground_min) + fresh.sum())
            self.ground_keys.insert(uniq[fresh], gidx[fresh])
            self.ground_min = np.r_[self.ground_min, np.full(int(fresh.sum()), np.inf)]
            np.minimum.at(self.ground_min, gidx[inv.ravel()], pos[:, 2])

    # ------------------------------------------------------------------------------------------ slabs

    def _update_slabs(self, vmap: VoxelMap, finishing: bool) -> np.ndarray:
        cfg = self.cfg
        if self.outdoor or self.n < cfg.slab_min_voxels or self.hist_base is None:
            return np.zeros(0, np.int64)
        if not finishing and self.n < 1.25 * self.slab_search_n:
            return np.zeros(0, np.int64)  # the histogram has hardly changed since the last look
        self.slab_search_n = self.n
        used = np.flatnonzero(self.hist)
        lo, hi = int(used[0]), int(used[-1]) + 1
        edges = (self.hist_base + np.arange(lo, hi + 1)) * cfg.slab_bin_m
        bands = bands_of_counts(
            self.hist[lo:hi], edges, cfg.slab_density_ratio, cfg.slab_neighbourhood_bins, cfg.slab_merge_m
        )
        changed: list[np.ndarray] = [np.zeros(0, np.int64)]
        refits = 0
        for band in bands:  # one iteration per slab band (a handful)
            b0 = int(np.floor(band[0] / cfg.slab_bin_m)) - self.hist_base
            b1 = int(np.ceil(band[1] / cfg.slab_bin_m)) - self.hist_base
            count = int(self.hist[max(b0, 0) : b1].sum())
            old = [s for s in self.slabs if s.band[0] < band[1] and band[0] < s.band[1]]
            if old and count < (1 + cfg.slab_refit_growth) * max(s.fitted_count for s in old):
                continue
            if refits >= _SLAB_FITS_PER_SCAN and not finishing:
                break  # the rest wait their turn
            refits += 1
            for s in old:
                changed.append(self._drop_slab(s))
            changed.append(self._fit_band(vmap, band, b0, b1, count, fresh=not old))
        if self.slabs:  # a slab covers a floor: a small horizontal patch (a table top, a bed) is not one
            sizes = {s.id: s.voxels for s in self.slabs}
            largest = max(sizes.values())
            for s in [s for s in self.slabs if sizes[s.id] < _MIN_SLAB_SHARE * largest]:
                changed.append(self._drop_slab(s))
            # nor is a floor less than a story above another (desks in rows make a dense band of their own)
            heights = {s.id: s.mid_z for s in self.floors}
            for s in self.floors:
                if any(0 < heights[s.id] - h < cfg.min_story_m for h in heights.values()):
                    changed.append(self._drop_slab(s))
        return np.concatenate(changed)

    def _drop_slab(self, slab: _Slab) -> np.ndarray:
        rows = np.flatnonzero(self.elem[: self.n] == slab.id)
        self.elem[rows] = -1
        self.kind_cls[rows] = UNLABELLED
        self.slabs.remove(slab)
        return rows

    def _fit_band(
        self, vmap: VoxelMap, band: tuple[float, float], b0: int, b1: int, count: int, fresh: bool = False
    ) -> np.ndarray:
        """Up to two horizontal planes (a slab's top and underside) in a density band; each is a floor or a
        ceiling by where the sensors that saw it were. A `fresh` band (no slab there before) is a new storey
        bound for the tiles it covers: they are refitted."""
        cfg = self.cfg
        pad = max(1, round(0.15 / cfg.slab_bin_m))
        zb = self.zbin[: self.n]
        rows = np.flatnonzero((zb >= b0 - pad) & (zb < b1 + pad))
        # a ceiling's plane is the ceiling's even where a wall found first reaches it (the corner of a wall's head
        # and the ceiling): wall pieces give way there, slabs, columns and beams keep theirs
        rows = rows[(self.elem[rows] < 0) | self._on_piece(rows)]
        rng = np.random.default_rng(len(rows))
        out: list[np.ndarray] = [np.zeros(0, np.int64)]
        first = 0
        for _ in range(2):  # a slab's two faces at most
            if len(rows) < cfg.slab_min_voxels:
                break
            sample = rows if len(rows) <= _SLAB_SAMPLE else rng.choice(rows, _SLAB_SAMPLE, replace=False)
            plane, _ = ransac_plane(vmap.positions[sample], cfg.plane_threshold_m, _SLAB_ITERATIONS, rng)
            if abs(plane[2]) < np.cos(np.radians(cfg.max_slab_tilt_deg)):
                break
            on = np.abs(vmap.positions[rows] @ plane[:3] + plane[3]) < cfg.plane_threshold_m
            inliers = rows[on]
            if len(inliers) < cfg.slab_min_voxels or len(inliers) < 0.2 * first:
                break
            first = first or len(inliers)
            rows = rows[~on]
            pos = vmap.positions[inliers]
            if _interior_share(pos[:, :2]) < _MIN_INTERIOR:
                continue  # lines, not a surface: a spinning scanner's rings on the walls all at one height
            height = float(np.median(pos[:, 2]))
            below = float(np.median(self.sensor_z[inliers])) - height
            if abs(below) < cfg.sensor_margin_m:
                continue  # at the sensor's height: a table top seen edge-on, not a slab
            kind = Kind.FLOOR if below > 0 else Kind.CEILING
            if kind is Kind.FLOOR:  # a wall's foot stays the wall's (it stands on the floor, the simulator agrees)
                inliers = inliers[~self._on_piece(inliers)]
                pos = vmap.positions[inliers]
            lo, hi = np.percentile(pos, 1, axis=0), np.percentile(pos, 99, axis=0)
            slab = _Slab(self._new_id(), kind, band, plane, lo, hi, count, len(inliers))
            self.slabs.append(slab)
            self.elem[inliers] = slab.id
            self.kind_cls[inliers] = CLASS_OF[kind]
            out.append(inliers)
            for t in np.unique(self.tile_of[inliers]) if fresh else ():  # one iteration per tile under a new slab
                tile = self.tiles[int(t)]
                tile.pending = max(tile.pending, cfg.min_new_voxels)
        return np.concatenate(out)

    def _on_piece(self, rows: np.ndarray) -> np.ndarray:
        """Whether each row lies on a wall piece (not on a slab, column or beam)."""
        if not self.pieces:
            return np.zeros(len(rows), bool)
        return member(self.elem[rows], self.pieces.keys(), self.next_id)

    def storey(self, xy: np.ndarray, z: float) -> tuple[float, float] | None:
        """(floor, ceiling) heights at `xy` of the story a sensor at height `z` stands in; None without a floor.
        Without a ceiling the story is `default_story_m` high."""
        floors = [(float(s.height_at(xy)), s) for s in self.slabs if s.kind is Kind.FLOOR]
        floors = [f for f in floors if f[0] < z]
        if not floors:
            return None
        zf = max(f[0] for f in floors)
        ceilings = [float(s.height_at(xy)) for s in self.slabs if s.kind is Kind.CEILING]
        ceilings = [c for c in ceilings if c > z]
        zc = min(ceilings) if ceilings else zf + self.cfg.default_story_m
        return zf, zc

    def _ceiling_heights(self) -> np.ndarray:
        return np.array([s.mid_z for s in self.slabs if s.kind is Kind.CEILING])

    # ------------------------------------------------------------------------------------------ new voxels

    def _join_elements(self, vmap: VoxelMap, rows: np.ndarray) -> np.ndarray:
        """New voxels on the slabs, walls, columns and beams found so far (until their tile is refitted)."""
        if not len(rows):
            return rows
        pos = vmap.positions[rows]
        free = self.elem[rows] < 0
        thr = self.cfg.plane_threshold_m
        for s in self.slabs:  # one iteration per slab
            on = free & (np.abs(pos @ s.plane[:3] + s.plane[3]) < thr)
            on &= np.all((pos[:, :2] > s.lo[:2] - _SLAB_XY_MARGIN_M) & (pos[:, :2] < s.hi[:2] + _SLAB_XY_MARGIN_M), 1)
            self.elem[rows[on]] = s.id
            self.kind_cls[rows[on]] = CLASS_OF[s.kind]
            free &= ~on
        for e in (*self.columns.values(), *self.beams.values()):  # one iteration per column or beam
            on = free & np.all((pos >= e.lo - thr) & (pos <= e.hi + thr), 1)
            self.elem[rows[on]] = e.id
            self.kind_cls[rows[on]] = e.class_id
            free &= ~on
        if self.wall_of_piece and free.any():  # a voxel can only lie on a piece of its own tile
            f = np.flatnonzero(free)
            tiles = self.tile_of[rows[f]]
            order = np.argsort(tiles, kind="stable")
            bounds = np.concatenate([[0], np.flatnonzero(np.diff(tiles[order])) + 1, [len(order)]])
            for lo, hi in pairwise(bounds):  # one iteration per tile touched
                pids = [p for p in self.tiles[int(tiles[order[lo]])].pieces if p in self.wall_of_piece]
                if pids:
                    self._join_pieces(vmap, rows[f[order[lo:hi]]], pids, own_tile=True)
        return rows

    def _piece_lines(self, pids: list[int], whole: bool) -> _PieceLines:
        """The lines `_join_pieces` measures pieces by, kept until the walls change (`_merge_walls`)."""
        key = (tuple(pids), whole)
        got = self.piece_lines.get(key)
        if got is not None:
            return got
        ps = [self.pieces[i] for i in pids]
        # a confirmed piece is measured as its wall: the wall's line, and (`whole`, at a refit of the block) its
        # height over all its pieces (a facade seen in pieces: a tile's piece may hold only its lower storey); a
        # voxel arriving joins within its piece's own height, until its tile is refitted
        own = [self.wall_line.get(self.wall_of_piece.get(i, -1)) for i in pids]
        lines = np.array(
            [np.r_[p.normal, p.offset, p.z, p.u] if line is None else line for line, p in zip(own, ps, strict=True)]
        )
        normal = lines[:, :2]
        z = lines[:, 3:5] if whole else np.array([p.z for p in ps])
        # along the wall, a voxel joins within its piece's extent (a wall's gaps are doors, or what stands there)
        u = np.array([self.piece_span.get(i, q[5:7]) for i, q in zip(pids, lines, strict=True)])
        direction = np.c_[-normal[:, 1], normal[:, 0]]
        got = _PieceLines(normal, lines[:, 2], direction, z, u, self.tile_xy[[p.tile for p in ps]], np.array(pids))
        self.piece_lines[key] = got
        return got

    def _join_pieces(
        self, vmap: VoxelMap, rows: np.ndarray, pids: list[int], whole: bool = False, own_tile: bool = False
    ) -> None:
        """Free `rows` onto the confirmed pieces `pids` (`own_tile`: all of the rows' own tile)."""
        lines = self._piece_lines(pids, whole)
        normal, offset, z, u = lines.normal, lines.offset, lines.z, lines.u
        pos = vmap.positions[rows]
        d = np.abs(pos[:, :2] @ normal.T + offset)  # (F, P): off its wall's line
        along = pos[:, :2] @ lines.direction.T
        inside = (along > u[:, 0] - 0.2) & (along < u[:, 1] + 0.2)
        inside &= (pos[:, 2:3] > z[:, 0] - 0.2) & (pos[:, 2:3] < z[:, 1] + 0.2)
        # a voxel joins a piece of its own tile or the next (a refit forgets its pieces' voxels in its 3 x 3 block)
        if not own_tile:
            apart = np.abs(self.tile_xy[self.tile_of[rows]][:, None, :] - lines.tile_xy[None])
            inside &= apart.max(axis=2) <= 1
        score = np.where(inside & (d < self.cfg.plane_threshold_m), d, np.inf)
        best = np.argmin(score, axis=1)
        hit = np.isfinite(score[np.arange(len(rows)), best])
        self.elem[rows[hit]] = lines.pids[best[hit]]
        self.kind_cls[rows[hit]] = SemanticClass.WALL

    # ------------------------------------------------------------------------------------------ tiles

    def _refit_tiles(self, vmap: VoxelMap, finishing: bool) -> list[np.ndarray]:
        pending = np.array([t.pending for t in self.tiles], np.int64)
        need = 1 if finishing else self.cfg.min_new_voxels
        order = np.argsort(-pending, kind="stable")
        order = order[pending[order] >= need]
        # The budget is counted in voxels, not milliseconds, so that a run's labels never depend on how busy the
        # machine was (a refit costs about the same per voxel of its 3 x 3 tile block).
        budget = self.cfg.budget_voxels
        self.credit = min(self.credit + budget, budget * _CREDIT_SCANS)
        if not finishing:
            order = order[: self.cfg.tiles_per_scan]
        self.last_tiles = []
        out: list[np.ndarray] = []
        for i in order:  # one iteration per tile refitted (the budget)
            if not finishing and self.credit <= 0:
                break
            cost = self._block_size(int(i))
            out.append(self._refit_tile(vmap, int(i)))
            self.refit_voxels += cost
            if not finishing:
                self.credit -= cost
            self.last_tiles.append((int(self.tile_xy[i, 0]), int(self.tile_xy[i, 1])))
        return out

    def _around(self, i: int) -> list[int]:
        """Tile `i` and those of the 8 around it that exist, in a fixed order (kept until a tile is added)."""
        known = self.around_of.get(i)
        if known is not None and known[0] == len(self.tiles):
            return known[1]
        x, y = self.tile_xy[i]
        ox, oy = np.meshgrid(np.arange(-1, 2), np.arange(-1, 2), indexing="ij")
        found = self.tile_keys.find(pack_keys(np.c_[x + ox.ravel(), y + oy.ravel(), np.zeros(9, np.int64)]))
        tiles = [int(j) for j in found if j >= 0]
        self.around_of[i] = (len(self.tiles), tiles)
        return tiles

    def _block_size(self, i: int) -> int:
        return sum(sum(len(c) for c in self.tiles[j].chunks) for j in self._around(i))

    def _tile_block(self, i: int) -> np.ndarray:
        """Rows of tile `i` and the 8 tiles around it."""
        return np.concatenate([self.tiles[j].rows() for j in self._around(i)])

    def _refit_tile(self, vmap: VoxelMap, i: int) -> np.ndarray:
        tile = self.tiles[i]
        tile.pending = 0
        self.refits += 1
        rows = tile.rows()
        old = set(tile.elements) | set(tile.pieces)
        for e in tile.elements:
            self.columns.pop(e, None)
            self.beams.pop(e, None)
            self.debris.pop(e, None)
        block = self._tile_block(i)
        # forget this tile's columns and beams (they may reach into the tiles around) and wall pieces
        stale = block[member(self.elem[block], old, self.next_id)] if old else block[:0]
        self.elem[stale] = -1
        self.kind_cls[stale] = UNLABELLED
        for p in tile.pieces:
            self.pieces.pop(p, None)
        self.piece_lines = {}
        tile.elements, tile.pieces = [], []
        if self.outdoor:  # walls first: a facade's foot is wall, not ground
            was_ground = rows[self.elem[rows] == 0]
            self.elem[was_ground] = -1
            self.kind_cls[was_ground] = UNLABELLED
            self._fit_walls(vmap, i, None, block)
            walls = self._merge_walls()
            self._join_block_walls(vmap, i, block)
            return np.concatenate([stale, walls, self._ground_rows(vmap, block), block])
        centre = (self.tile_xy[i] + 0.5) * self.cfg.tile_m
        zs = float(np.median(self.sensor_z[rows])) if len(rows) else 0.0
        storey = self.storey(centre, zs)
        # walls first: what stands or hangs free of them is a column or a beam
        self._fit_walls(vmap, i, storey, block)
        walls = self._merge_walls()
        self._join_block_walls(vmap, i, block)
        if storey is not None:
            self._fit_columns(vmap, i, block, storey)
            self._fit_beams(vmap, i, block, storey)
            if self.cfg.debris:  # what is left on the floor after the structure
                fit_debris(self, vmap, i, block, storey, zs)
        return np.concatenate([stale, walls, block])

    def _block_pieces(self, i: int) -> list[int]:
        """Confirmed wall pieces of tile `i` and the 8 tiles around it."""
        return [p for j in self._around(i) for p in self.tiles[j].pieces if p in self.wall_of_piece]

    def _join_block_walls(self, vmap: VoxelMap, i: int, block: np.ndarray) -> None:
        """Free voxels of the tiles around on a wall found in any of them (a wall's piece in one tile can miss
        its voxels near the tile's edge, or near the ceiling)."""
        pids = self._block_pieces(i)
        free = block[self.elem[block] < 0]
        if pids and len(free):
            self._join_pieces(vmap, free, pids, whole=True)

    def _footprints(
        self, vmap: VoxelMap, rows: np.ndarray, z0: float, z1: float, free_only: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Occupancy grid (cells of one voxel) of rows (free ones only: on no element) with z in [z0, z1):
        counts, origin cell, and the rows with their cells."""
        pos = vmap.positions[rows]
        sel = ((self.elem[rows] < 0) | (not free_only)) & (pos[:, 2] >= z0) & (pos[:, 2] < z1)
        rows, pos = rows[sel], pos[sel]
        if not len(rows):
            return np.zeros((0, 0), np.int64), np.zeros(2, np.int64), rows, np.zeros((0, 2), np.int64)
        cell = np.floor(pos[:, :2] / self.voxel).astype(np.int64)
        origin = cell.min(axis=0)
        cell -= origin
        shape = cell.max(axis=0) + 1
        counts = np.bincount(cell[:, 0] * shape[1] + cell[:, 1], minlength=int(shape[0] * shape[1]))
        return counts.reshape(shape), origin, rows, cell

    def _fit_columns(self, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]) -> None:
        fit_columns(self, vmap, i, block, storey)  # free-standing and engaged (pipeline/structure/columns.py)

    def _fit_beams(self, vmap: VoxelMap, i: int, block: np.ndarray, storey: tuple[float, float]) -> None:
        fit_beams(self, vmap, i, block, storey)  # under a slab, not a wall's head (pipeline/structure/columns.py)

    def _wall_rows(self, vmap: VoxelMap, rows: np.ndarray, storey: tuple[float, float] | None) -> np.ndarray:
        """The rows a wall may take: on no element but a wall piece, between the story's slabs."""
        rows = rows[(self.elem[rows] < 0) | self._on_piece(rows)]
        if storey is not None:  # the walls of this story, not the slabs' edges
            z = vmap.positions[rows, 2]
            rows = rows[(z > storey[0] + self.cfg.plane_threshold_m) & (z < storey[1] - self.cfg.plane_threshold_m)]
        return rows

    def _fit_walls(self, vmap: VoxelMap, i: int, storey: tuple[float, float] | None, block: np.ndarray) -> None:
        """Vertical planes of a tile, one after another (RANSAC); each a wall piece with its voxels. A piece's
        line is measured on the tiles around too (`block`), so that the pieces of one wall in neighbouring tiles
        lie on one line and merge (a tile holds a short stretch of a wall, whose direction it measures badly)."""
        cfg = self.cfg
        near = self._wall_rows(vmap, block, storey)
        rows = near[self.tile_of[near] == i]  # the tile's own, in its order (its rows are one run of `block`)
        rows = rows[self.elem[rows] < 0]
        rest = np.zeros(self.n, bool)  # the block's wall rows but the tile's free ones, in order
        rest[near] = True
        rest[rows] = False
        context = vmap.positions[np.flatnonzero(rest), :2]
        around = vmap.positions[block]
        overhead = around[self.kind_cls[block] == SemanticClass.CEILING]  # the ceiling slab's voxels around
        rng = np.random.default_rng(i)
        for _ in range(_WALL_PLANES):  # one iteration per plane tried
            if len(rows) < cfg.wall_piece_min_voxels:
                return
            pos = vmap.positions[rows]
            line, on = ransac_line(pos[:, :2], cfg.plane_threshold_m, _WALL_ITERATIONS, rng, context)
            if line is None or on.sum() < cfg.wall_piece_min_voxels:
                return
            keep_rows, rest = rows[on], rows[~on]
            rows = rest
            normal = line[:2]
            p = pos[on]
            offset = float(-np.median(p[:, :2] @ normal))
            along = p[:, :2] @ np.array([-normal[1], normal[0]])
            # the largest run along the wall without a gap wider than _WALL_GAP_M
            order = np.argsort(along)
            run = _longest_run(order, along[order], _WALL_GAP_M)
            # ... and its largest band in height without a gap wider than _WALL_Z_GAP_M: a face is seen whole
            # over its height, a line through furniture and a ceiling's fixtures leaves the storey's middle empty
            zorder = run[np.argsort(p[run, 2])]
            run = _longest_run(zorder, p[zorder, 2], _WALL_Z_GAP_M)
            left = np.ones(len(keep_rows), bool)  # the inliers off the run go back, in order
            left[run] = False
            if len(run) < cfg.wall_piece_min_voxels:
                rows = np.concatenate([rows, np.sort(keep_rows[left])])
                continue
            if _fill_share(np.c_[along[run], p[run, 2]], _FACE_CELL_M) < _MIN_FACE_FILL:
                continue  # a strip through furniture or the ground seen from above, not a face standing up
            cell = max(_CROSS_CELL_M, 2 * self.voxel)
            if _crossing_share(p[run], around, np.r_[normal, offset], cfg.plane_threshold_m, cell) > _MAX_CROSSING:
                continue  # a cut through clutter, not a surface
            if storey is not None and _stands_in_room(p[run], overhead, np.r_[normal, offset], storey[1]):
                continue  # furniture or a partition: the ceiling is seen over it on both sides
            zr = np.percentile(p[run, 2], [1, 99])
            x, y = p[run, 0], p[run, 1]
            moments = np.array([len(run), x.sum(), y.sum(), x @ x, x @ y, y @ y])
            piece = _Piece(
                self._new_id(), i, normal, offset, (float(along[run].min()), float(along[run].max())),
                (float(zr[0]), float(zr[1])), keep_rows[run], moments,
            )  # fmt: skip
            self.pieces[piece.id] = piece
            self.tiles[i].pieces.append(piece.id)
            rows = np.concatenate([rows, np.sort(keep_rows[left])])

    def _merge_walls(self) -> np.ndarray:
        """Pieces of every tile joined into walls (parallel, coplanar, touching along the wall); a wall is
        confirmed when it is `wall_min_width_m` wide and `wall_min_height_m` high. Returns the rows whose
        wall changed."""
        cfg = self.cfg
        before = dict(self.wall_of_piece)
        self.piece_lines = {}
        ids = np.array(list(self.pieces), np.int64)
        self.wall_of_piece = {}
        self.wall_line = {}
        self.piece_span = {}
        if len(ids):
            ps = [self.pieces[int(i)] for i in ids]
            normal = np.array([p.normal for p in ps])
            offset = np.array([p.offset for p in ps])
            u = np.array([p.u for p in ps])
            z = np.array([p.z for p in ps])
            direction = np.c_[-normal[:, 1], normal[:, 0]]
            mid = (u[:, 0] + u[:, 1]) / 2
            centre = direction * mid[:, None] - normal * offset[:, None]  # a point on each piece's line
            cos = np.abs(normal @ normal.T)
            dist = np.abs(centre @ normal.T + offset[None, :])  # piece i's centre from piece j's plane
            ends = np.stack(
                [centre + direction * (u[:, :1] - mid[:, None]), centre + direction * (u[:, 1:] - mid[:, None])], 1
            )
            proj = np.einsum("ikc,jc->ijk", ends, direction)  # i's ends along j's direction
            gap = np.maximum(proj.min(2) - u[None, :, 1], u[None, :, 0] - proj.max(2))
            link = (cos > np.cos(np.radians(cfg.wall_merge_deg))) & (dist < 2 * cfg.plane_threshold_m)
            link &= (2 * cfg.plane_threshold_m > dist.T) & (gap < _WALL_JOIN_GAP_M)
            a, b = np.nonzero(link)
            graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(ids), len(ids)))
            _, group = connected_components(graph, directed=False)
            # each wall's width along the direction of its largest piece, and its height (vectorised per group)
            size = np.array([len(p.rows) for p in ps])
            order = np.lexsort((-size, group))
            lead = np.full(group.max() + 1, -1, np.int64)
            lead[group[order[::-1]]] = order[::-1]  # the first of each group in `order`: its largest piece
            span = np.einsum("kjc,kc->kj", ends, direction[lead[group]])
            ng = group.max() + 1
            lo_u, hi_u = np.full(ng, np.inf), np.full(ng, -np.inf)
            lo_z, hi_z = np.full(ng, np.inf), np.full(ng, -np.inf)
            np.minimum.at(lo_u, group, span.min(1))
            np.maximum.at(hi_u, group, span.max(1))
            np.minimum.at(lo_z, group, z[:, 0])
            np.maximum.at(hi_z, group, z[:, 1])
            ok = (hi_u - lo_u >= cfg.wall_min_width_m) & (hi_z - lo_z >= cfg.wall_min_height_m)
            first_id = np.full(ng, np.iinfo(np.int64).max)
            np.minimum.at(first_id, group, ids)
            confirmed = ok[group]
            self.wall_of_piece = dict(zip(ids[confirmed].tolist(), first_id[group[confirmed]].tolist(), strict=True))
            self.piece_span = {}
            self.wall_line = self._wall_lines(
                ps, group, ok, first_id, normal[lead], np.c_[lo_z, hi_z], ends, self.piece_span
            )
        self.wall_object = self._wall_objects()
        out: list[np.ndarray] = [np.zeros(0, np.int64)]
        for pid in self.wall_of_piece.keys() - before.keys():  # newly confirmed: their voxels become wall
            rows = self.pieces[pid].rows
            free = rows[(self.elem[rows] < 0) | (self.elem[rows] == pid)]
            self.elem[free] = pid
            self.kind_cls[free] = SemanticClass.WALL
            out.append(free)
        for pid in before.keys() - self.wall_of_piece.keys():  # no longer a wall (or refitted away)
            if pid in self.pieces:
                rows = self.pieces[pid].rows
                mine = rows[self.elem[rows] == pid]
                self.elem[mine] = -1
                self.kind_cls[mine] = UNLABELLED
                out.append(mine)
        return np.concatenate(out)

    @staticmethod
    def _wall_lines(
        ps: list[_Piece],
        group: np.ndarray,
        ok: np.ndarray,
        first_id: np.ndarray,
        lead_normal: np.ndarray,
        z: np.ndarray,
        ends: np.ndarray,
        spans: dict[int, np.ndarray],
    ) -> dict[int, np.ndarray]:
        """Per confirmed wall: the line through all its pieces' voxels (least squares, from their moments), its
        height range `z` (per group) and its extent along that line (of its pieces' `ends`): (nx, ny, offset, z0,
        z1, u0, u1); and each piece's extent along its wall's line into `spans`. A wall seen in pieces is one
        plane, measured on all of it."""
        moments = np.zeros((len(ok), 6))
        np.add.at(moments, group, np.array([p.moments for p in ps]))
        out: dict[int, np.ndarray] = {}
        for g in np.flatnonzero(ok):  # one iteration per confirmed wall
            count, sx, sy, sxx, sxy, syy = moments[g]
            mx, my = sx / count, sy / count
            cov = np.array(
                [[sxx / count - mx * mx, sxy / count - mx * my], [sxy / count - mx * my, syy / count - my * my]]
            )
            _, vec = np.linalg.eigh(cov)
            nrm = vec[:, 0] if vec[:, 0] @ lead_normal[g] >= 0 else -vec[:, 0]
            members = np.flatnonzero(group == g)
            along = ends[members] @ np.array([-nrm[1], nrm[0]])  # (M, 2): each piece's ends along its wall
            out[int(first_id[g])] = np.r_[nrm, -(nrm @ np.array([mx, my])), z[g], along.min(), along.max()]
            for k, span in zip(members, np.sort(along, axis=1), strict=True):  # one iteration per piece
                spans[ps[k].id] = span
        return out

    def _sensor_side(self, wall: int, line: np.ndarray) -> float:
        """Which side of its line (+1, -1 along its normal) a wall was seen from (0: unknown): where the sensor
        stood when most of its voxels opened."""
        rows = np.concatenate([self.pieces[p].rows for p, w in self.wall_of_piece.items() if w == wall])
        origin = self.sight.of(rows[:: max(1, len(rows) // 200)])
        origin = origin[np.isfinite(origin[:, 0])]
        if not len(origin):
            return 0.0
        return float(np.sign(np.median(np.sign(origin[:, :2] @ line[:2] + line[2]))))

    def _seen_over(self, vmap: VoxelMap, lines: np.ndarray, side: np.ndarray) -> np.ndarray:
        """Per wall line (rows of `wall_line`, seen from `side`): the share of its 0.5 m cells along it over which
        a ray from the sensor crossed its plane within `_OVER_M` over its top and returned `_OVER_BEYOND_M` or more
        behind it (0 where no ray is known)."""
        out = np.zeros(len(lines))
        origin = self.sight.of(np.arange(self.n, dtype=np.int64)).astype(np.float64)
        known = np.isfinite(origin[:, 0])
        if not known.any():
            return out
        pos, origin = vmap.positions[: self.n][known], origin[known]
        for k, line in enumerate(lines):  # one iteration per wall
            if side[k] == 0:
                continue
            n, off, top, u0, u1 = line[:2], line[2], line[4], line[5], line[6]
            so = side[k] * (origin[:, :2] @ n + off)
            sp = side[k] * (pos[:, :2] @ n + off)
            far = (so > 0) & (sp < -_OVER_BEYOND_M)
            if not far.any():
                continue
            f = so[far] / (so[far] - sp[far])
            cross = origin[far] + f[:, None] * (pos[far] - origin[far])
            along = cross[:, :2] @ np.array([-n[1], n[0]])
            over = (cross[:, 2] > top + 0.05) & (cross[:, 2] < top + _OVER_M) & (along > u0) & (along < u1)
            cells = max(int(np.ceil((u1 - u0) / _FACE_CELL_M)), 1)
            hit = np.unique(np.minimum(((along[over] - u0) / _FACE_CELL_M).astype(np.int64), cells - 1))
            out[k] = len(hit) / cells
        return out

    def _wall_objects(self, vmap: VoxelMap | None = None) -> dict[int, int]:
        """Per confirmed wall, the wall object it is part of (the smallest wall id of its group), as the
        simulator's truth has one instance per wall across the building, both faces and its openings:
        - stretches of one face (parallel within `_WALL_LINE_DEG`, the shorter's middle within `_COPLANAR_M` of
          the longer's line, any gap along it: a door, a stretch hidden) are one wall;
        - so are the two faces of one wall: parallel, at most `wall_thickness_m` apart, each behind the other as
          seen from its own side (the sensor stood in neither's thickness);
        - a face at most `_FURNITURE_WIDTH_M` wide standing `_FURNITURE_M` in front of a longer wall beside or
          behind it, both seen from that side, is a bookcase's or a cabinet's front: no wall object (labels stay);
        - with the map (`vmap`, at the end of a run), so is a face the sensor saw over: rays crossing its plane just
          over its top, within its width, to returns behind it (`_seen_over`): a wall reaching the ceiling hides
          what stands behind it there, a bookcase standing free in a hall does not."""
        if not self.cfg.wall_objects or not self.wall_line:
            return {}
        ids = list(self.wall_line)
        ln = np.array([self.wall_line[w] for w in ids])
        normal, offset, z, u = ln[:, :2], ln[:, 2], ln[:, 3:5], ln[:, 5:7]
        side = np.array([self._sensor_side(w, ln[k]) for k, w in enumerate(ids)])  # one iteration per wall
        length = u[:, 1] - u[:, 0]
        direction = np.c_[-normal[:, 1], normal[:, 0]]
        centre = direction * u.mean(axis=1)[:, None] - normal * offset[:, None]
        d = centre @ normal.T + offset[None, :]  # d[i, j]: i's middle off j's line (along j's normal)
        longer = length[None, :] >= length[:, None]  # [i, j]: j is the longer (its direction measured better)
        parallel = np.abs(normal @ normal.T) > np.cos(np.radians(_WALL_LINE_DEG))
        z_overlap = (np.minimum(z[:, None, 1], z[None, :, 1]) - np.maximum(z[:, None, 0], z[None, :, 0])) > 0
        ends = np.stack(
            [
                centre + direction * (u[:, :1] - u.mean(1)[:, None]),
                centre + direction * (u[:, 1:] - u.mean(1)[:, None]),
            ],
            1,
        )
        proj = np.einsum("ikc,jc->ijk", ends, direction)  # i's ends along j's line
        gap = np.maximum(proj.min(2) - u[None, :, 1], u[None, :, 0] - proj.max(2))
        pair = parallel & z_overlap & longer  # [i, j], measured on j's line
        in_front = side[None, :] * d  # > 0: i stands on j's sensor side (0: unknown)
        behind = side[:, None] * d.T < 0  # j stands behind i as seen from i's sensor side
        front = pair & behind & (in_front > _FURNITURE_M[0]) & (in_front < _FURNITURE_M[1])
        front &= (
            (length[:, None] <= _FURNITURE_WIDTH_M) & (gap < _WALL_JOIN_GAP_M) & (length[None, :] > length[:, None])
        )
        furniture = front.any(axis=1)
        if vmap is not None:
            furniture |= self._seen_over(vmap, ln, side) > _OVER_SHARE
        coplanar = pair & (np.abs(d) < _COPLANAR_M)
        # each behind the other from its own side: i behind j from j's side, j behind i from i's
        faces = pair & behind & (in_front < 0) & (-in_front <= self.cfg.wall_thickness_m)
        link = (coplanar | faces) & ~furniture[:, None] & ~furniture[None, :]
        a, b = np.nonzero(link)
        n = len(ids)
        _, group = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
        key = np.full(group.max() + 1, np.iinfo(np.int64).max)
        np.minimum.at(key, group, np.array(ids, np.int64))
        # each group's span along its longest wall's line: short groups are furniture's faces, not walls
        lead = np.full(group.max() + 1, -1, np.int64)
        order = np.argsort(length)
        lead[group[order]] = order  # the longest last: it stays
        along = proj[np.arange(n), lead[group]]  # (n, 2): each wall's ends along its group's lead line
        lo, hi = np.full(len(lead), np.inf), np.full(len(lead), -np.inf)
        np.minimum.at(lo, group, along.min(axis=1))
        np.maximum.at(hi, group, along.max(axis=1))
        short = (hi - lo < _WALL_OBJECT_M)[group]
        return {w: int(key[g]) for w, g, f in zip(ids, group, furniture | short, strict=True) if not f}

    def _facades(self, walls: dict[int, list[_Piece]]) -> dict[int, list[_Piece]]:
        """Outdoors, walls joined into the facade they belong to (for their outline): a wall whose ends lie
        within `_FACADE_RELIEF_M` of a longer wall's line, turned at most `_FACADE_DEG` from it, and overlapping
        or continuing it along that line, is a recess, a balcony or a pilaster of it (a facade is one plane with
        relief, each relief face its own wall). The labels are not changed; the longest wall gives the id."""
        ids = list(walls)
        if len(ids) < 2:
            return walls
        lines = []
        for w in ids:  # one iteration per wall
            line = self.wall_line.get(w)
            if line is None:
                big = max(walls[w], key=lambda p: len(p.rows))
                line = np.r_[big.normal, big.offset, big.z, big.u]
            lines.append(line)
        ln = np.array(lines)
        normal, offset, u = ln[:, :2], ln[:, 2], ln[:, 5:7]
        direction = np.c_[-normal[:, 1], normal[:, 0]]
        ends = direction[:, None, :] * u[:, :, None] - (normal * offset[:, None])[:, None, :]  # (W, 2 ends, 2)
        off = np.abs(np.einsum("ikc,jc->ijk", ends, normal) + offset[None, :, None]).max(axis=2)  # i's ends off j
        proj = np.einsum("ikc,jc->ijk", ends, direction)  # i's ends along j's line
        gap = np.maximum(proj.min(2) - u[None, :, 1], u[None, :, 0] - proj.max(2))
        length = u[:, 1] - u[:, 0]
        cos = np.abs(normal @ normal.T)
        part = (off < _FACADE_RELIEF_M) & (cos > np.cos(np.radians(_FACADE_DEG))) & (gap < _WALL_JOIN_GAP_M)
        part &= length[:, None] <= length[None, :]  # i is part of the longer j
        a, b = np.nonzero(part)
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(ids), len(ids)))
        _, group = connected_components(graph, directed=False)
        out: dict[int, list[_Piece]] = {}
        for g in range(group.max() + 1):  # one iteration per facade
            members = np.flatnonzero(group == g)
            lead = ids[int(members[np.argmax(length[members])])]
            out[lead] = [p for k in members for p in walls[ids[int(k)]]]
        return out

    # ------------------------------------------------------------------------------------------ ground

    def _ground_keys(self, pos: np.ndarray) -> np.ndarray:
        c = np.floor(pos[:, :2] / self.cfg.ground_cell_m).astype(np.int64)
        return pack_keys(np.c_[c, np.zeros(len(c), np.int64)])

    def _ground_rows(self, vmap: VoxelMap, rows: np.ndarray) -> np.ndarray:
        """Outdoors: voxels just above their cell's lowest voxel, where that lowest voxel lies with its
        neighbours' (not a roof or a car's top) and below the sensor."""
        if not len(rows) or not len(self.ground_min):
            return rows[:0]
        cfg = self.cfg
        pos = vmap.positions[rows]
        c = np.floor(pos[:, :2] / cfg.ground_cell_m).astype(np.int64)
        o = np.stack(np.meshgrid(np.arange(-1, 2), np.arange(-1, 2), indexing="ij"), -1).reshape(9, 2)
        keys = pack_keys(np.c_[(c[:, None, :] + o[None]).reshape(-1, 2), np.zeros(9 * len(c), np.int64)])
        idx = self.ground_keys.find(keys).reshape(len(rows), 9)
        mins = np.where(idx >= 0, self.ground_min[np.maximum(idx, 0)], np.nan)
        own = mins[:, 4]
        around = np.nanmedian(mins, axis=1)
        ground = (pos[:, 2] - own < cfg.ground_band_m) & (own < around + 0.25)
        ground &= own < self.sensor_z[rows] - 0.5
        free = self.elem[rows] < 0
        # a wall's foot on the ground's surface is ground (the corner goes to the ground as indoors to the slab)
        foot = self._on_piece(rows) & (pos[:, 2] - own < cfg.plane_threshold_m)
        on = rows[ground & (free | foot | (self.kind_cls[rows] == SemanticClass.GROUND))]
        self.elem[on] = 0  # the ground is one element, id 0
        self.kind_cls[on] = SemanticClass.GROUND
        off = rows[~ground & (self.kind_cls[rows] == SemanticClass.GROUND)]
        self.elem[off] = -1
        self.kind_cls[off] = UNLABELLED
        return rows

    # ------------------------------------------------------------------------------------------ fusion

    def _fuse(self, vmap: VoxelMap, rows: np.ndarray) -> None:
        """The class the structure gives each row (UNLABELLED where the network's label stands)."""
        if not len(rows):
            return
        self.dirty.append(rows)  # `apply` writes them
        if not self.has_floor:
            self.fused[rows] = UNLABELLED  # no floor, no structure: the network alone (one warning says so)
            return
        s = self.kind_cls[rows]
        c = self.net_cls[rows]
        on = s != UNLABELLED
        keep = on & NON_STRUCTURAL[c] & (self.net_score[rows] >= self.cfg.keep_confidence)
        out = np.where(on & ~keep, s, UNLABELLED).astype(np.uint16)
        # An element's class is as sure as the network (its probability of that class, known where it is the
        # network's own class, else 0) or the geometry (the element's support) says: 1 - (1 - p)(1 - g).
        p = np.where(c == s, self.net_score[rows], 0.0)
        score = 1.0 - (1.0 - p) * (1.0 - self._support(rows))
        free = ~on
        z = vmap.positions[rows, 2]
        sz = self.sensor_z[rows]
        margin = self.cfg.sensor_margin_m
        C = SemanticClass
        if self.outdoor:  # outdoors there is ground, never floor or ceiling
            out[free & np.isin(c, [C.FLOOR, C.CEILING, C.BEAM])] = C.CLUTTER  # no slab overhead: no beam
        else:
            ceilings = self._ceiling_heights()
            # a ceiling needs an overhead slab: decided at the end, when every band was looked at
            no_slab = self.final and len(ceilings) == 0
            bad_ceiling = free & (c == C.CEILING) & ((z < sz + margin) | no_slab)
            bad_floor = free & (c == C.FLOOR) & (z > sz - margin)
            out[bad_ceiling | bad_floor] = C.CLUTTER
            if self.final and len(ceilings):  # a ceiling voxel lies on a ceiling slab: elsewhere it is a wall's head
                stray = np.flatnonzero(free & (c == C.CEILING) & ~bad_ceiling)
                pos = vmap.positions[rows[stray]]
                off = np.full(len(stray), np.inf)
                for slab in self.slabs:  # one iteration per slab
                    if slab.kind is Kind.CEILING:
                        off = np.minimum(off, np.abs(pos[:, 2] - slab.height_at(pos[:, :2])))
                far = off > 2 * self.cfg.plane_threshold_m
                out[stray[far]] = np.where(self._near_wall(pos[far]), C.WALL, C.CLUTTER)
            if len(ceilings):  # a beam hangs under a ceiling
                under = np.min(np.abs(z[:, None] - ceilings[None, :]), axis=1) < self.cfg.beam_max_depth_m
            else:
                under = np.zeros(len(rows), bool)
            out[free & (c == C.BEAM) & ~under] = C.CLUTTER
            if self.final:  # every band and tile looked at: a beam or column geometry did not find is none
                unfound = free & (out == UNLABELLED)
                unfound &= ((c == C.BEAM) & self.cfg.beams_need_element) | (
                    (c == C.COLUMN) & self.cfg.columns_need_element
                )
                hit = np.flatnonzero(unfound)
                out[hit] = np.where(self._near_wall(vmap.positions[rows[hit]]), C.WALL, C.CLUTTER)
        # A network label the structure rules out: the new class gets at most the probability left over.
        overruled = free & (out != UNLABELLED)
        score[overruled] = 1.0 - self.net_score[rows[overruled]]
        self.fused[rows] = out
        self.fused_score[rows] = np.where(out != UNLABELLED, score, 0.0)

    def _support(self, rows: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
        """Per row, the geometric support of the element it lies on (0 off any): the element's voxels (a wall's
        over all its pieces) over the voxels that confirm a slab (`slab_min_voxels`), capped at 1. `counts`: the
        voxels per element as counted before (`support_counts`), else counted now."""
        elem = self.elem[rows]
        g = np.zeros(len(rows))
        if not np.any(elem >= 0):
            return g
        if counts is None or len(counts) <= int(elem.max()):
            # voxels per element id (-1, none, counted in the first bin and left out)
            counts = np.bincount(self.elem[: self.n] + 1, minlength=self.next_id + 2)[1:].astype(np.float64)
            if self.wall_of_piece:  # a wall piece counts its whole wall
                pids = np.fromiter(self.wall_of_piece, np.int64, len(self.wall_of_piece))
                walls = np.fromiter(self.wall_of_piece.values(), np.int64, len(pids))
                per_wall = np.bincount(walls, weights=counts[pids], minlength=int(walls.max()) + 1)
                counts[pids] = per_wall[walls]
            self.support_counts = counts
        on = elem >= 0
        g[on] = np.minimum(counts[elem[on]] / self.cfg.slab_min_voxels, 1.0)
        return g

    def _near_wall(self, pos: np.ndarray, reach_m: float = 0.15) -> np.ndarray:
        """Whether points lie within `reach_m` of a confirmed wall piece's plane, beside or just past it."""
        near = np.zeros(len(pos), bool)
        if not len(pos):
            return near
        for pid in self.wall_of_piece:  # one iteration per wall piece
            p = self.pieces[pid]
            along = pos[:, :2] @ np.array([-p.normal[1], p.normal[0]])
            on_line = np.abs(pos[:, :2] @ p.normal + p.offset) < reach_m
            near |= on_line & (along > p.u[0] - 0.5) & (along < p.u[1] + 0.5)
        return near

    # ------------------------------------------------------------------------------------------ results

    def object_keys(self, n: int) -> np.ndarray:
        """Per map row below `n`: the element whose object the voxel takes (a slab, column or beam whose class
        the fusion gave it; a wall piece's wall object, `_wall_objects`), -1 where none (no floor found, outdoors,
        off the elements, an opening's or a furniture face's voxel, or the network's confident label stood)."""
        keys = np.full(n, -1, np.int64)
        if self.outdoor or not self.has_floor:
            return keys
        m = min(n, self.n)
        elem, cls = self.elem[:m], self.kind_cls[:m]
        on = (elem > 0) & OBJECT_CLASSES[cls] & (self.fused[:m] == cls)
        keys[:m][on] = elem[on]
        if self.wall_object:  # a wall piece's voxel shows its wall's object (an opening's own element is not one)
            lut = np.full(self.next_id + 1, -1, np.int64)
            pids = np.fromiter(self.wall_of_piece, np.int64, len(self.wall_of_piece))
            lut[pids] = [self.wall_object.get(w, -1) for w in self.wall_of_piece.values()]
            wall = (elem > 0) & (cls == SemanticClass.WALL) & (self.fused[:m] == cls)
            keys[:m][wall] = lut[np.minimum(elem[wall], self.next_id)]
        for cid, rows in self.leaf_rows.items():  # one iteration per door leaf once taken for a column
            r = rows[rows < m]
            keys[r[(cls[r] == SemanticClass.DOOR) & (self.fused[r] == SemanticClass.DOOR)]] = cid
        return keys

    def warning(self) -> str | None:
        """One line when no floor (ground outdoors) was found: the labels are then the network's alone."""
        if self.has_floor or not self.n:
            return None
        what = "ground" if self.outdoor else "floor slab"
        return (
            f"structure: no {what} found in the levelled map (a tilted or vertical mount?); "
            "labels are the network's alone"
        )

    def elements(self, vmap: VoxelMap | None = None, scans: bool = True) -> list[Element]:
        """Every element found, with its support (voxels, and with `scans` the scans that saw them)."""
        elem = self.elem[: self.n]
        out: list[Element] = []
        for s in self.slabs:
            out.append(Element(s.id, s.kind, s.lo.copy(), s.hi.copy(), plane=s.plane.copy()))
        walls: dict[int, list[_Piece]] = {}
        for pid, wall in self.wall_of_piece.items():
            walls.setdefault(wall, []).append(self.pieces[pid])
        if self.outdoor:
            walls = self._facades(walls)
        for wall, ps in walls.items():
            rows = np.concatenate([p.rows for p in ps])
            pos = vmap.positions[rows] if vmap is not None else None
            big = max(ps, key=lambda p: len(p.rows))
            if pos is None or not len(pos):
                continue
            line = self.wall_line.get(wall)
            if line is None:
                line = np.r_[big.normal, big.offset]
            plane = np.r_[line[:2], 0.0, line[2]]
            out.append(Element(wall, Kind.WALL, pos.min(axis=0), pos.max(axis=0), plane=plane))
        out.extend(
            Element(e.id, e.kind, e.lo, e.hi, axis=e.axis)
            for e in (*self.columns.values(), *self.beams.values(), *self.debris.values())
        )
        out.extend(op.element() for op in self.openings)
        if self.outdoor and np.any(self.kind_cls[: self.n] == SemanticClass.GROUND) and vmap is not None:
            g = vmap.positions[: self.n][self.kind_cls[: self.n] == SemanticClass.GROUND]
            out.append(Element(0, Kind.GROUND, g.min(axis=0), g.max(axis=0)))
        piece_wall = np.full(self.next_id + 1, -1, np.int64)
        for wall, ps in walls.items():
            piece_wall[[p.id for p in ps]] = wall
        owner = np.where(elem >= 0, elem, -1)
        wall_ids = piece_wall[np.clip(owner, 0, None)]
        owner = np.where(wall_ids >= 0, wall_ids, owner)
        counts = np.bincount(owner[owner >= 0], minlength=self.next_id + 1)
        for e in out:
            e.voxels = int(counts[e.id]) if e.id < len(counts) else 0
            if vmap is not None and e.voxels and scans:
                e.scans = len(np.unique(vmap.first_seq[: self.n][owner == e.id]))
        return [e for e in out if e.voxels]
