"""The global lookup table of the online method: one stored point per voxel, and its results.

A voxel keeps the first point that falls in it (as in the study); only voxels never seen before are new
work for the labeller. Keys are the voxel's integer coordinates packed into one int64, held in a numpy
open-addressing hash table (linear probing, Fibonacci hashing) that is probed for whole batches at once,
so there is no Python dict and no per-point loop. Memory grows with the number of occupied voxels (the
size of the site), not with the number of scans.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.config import MapConfig
from aftershock.pipeline.types import LabelledCloud

_BITS: Final = 21  # per axis: ±2^20 voxels, about ±105 km at 0.1 m
_OFFSET: Final = 1 << (_BITS - 1)
_EMPTY: Final = -1
_GOLDEN: Final = np.uint64(0x9E3779B97F4A7C15)
_MAX_LOAD: Final = 0.5
_MIN_ROWS: Final = 4096


def pack_keys(coords: np.ndarray) -> np.ndarray:
    """(N, 3) integer voxel coordinates -> (N,) int64 keys; neighbours differ by `pack_offsets`."""
    c = np.asarray(coords, dtype=np.int64) + _OFFSET
    return (c[:, 0] << (2 * _BITS)) | (c[:, 1] << _BITS) | c[:, 2]


def unpack_keys(keys: np.ndarray) -> np.ndarray:
    mask = (1 << _BITS) - 1
    k = np.asarray(keys, dtype=np.int64)
    return np.stack([(k >> (2 * _BITS)) & mask, (k >> _BITS) & mask, k & mask], axis=1) - _OFFSET


def pack_offsets(radius: int) -> np.ndarray:
    """Key differences to every voxel in the (2r+1)^3 block around a voxel, the voxel itself in the middle."""
    r = np.arange(-radius, radius + 1, dtype=np.int64)
    dx, dy, dz = np.meshgrid(r, r, r, indexing="ij")
    return (dx.ravel() << (2 * _BITS)) + (dy.ravel() << _BITS) + dz.ravel()


class KeyTable:
    """int64 key -> int32 value, open addressing with linear probing; every operation takes whole arrays."""

    def __init__(self, capacity: int = 1 << 14) -> None:
        cap = 1 << max(4, int(np.ceil(np.log2(max(capacity, 16)))))
        self._keys = np.full(cap, _EMPTY, np.int64)
        self._vals = np.full(cap, -1, np.int32)
        self._bits = cap.bit_length() - 1
        self.size = 0

    @property
    def capacity(self) -> int:
        return len(self._keys)

    @property
    def nbytes(self) -> int:
        return self._keys.nbytes + self._vals.nbytes

    def _slots(self, keys: np.ndarray) -> np.ndarray:
        h = keys.astype(np.uint64) * _GOLDEN  # wraps modulo 2^64 on purpose
        return (h >> np.uint64(64 - self._bits)).astype(np.int64)

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Value of every key, -1 where absent."""
        keys = np.asarray(keys, dtype=np.int64).ravel()
        out = np.full(len(keys), -1, np.int32)
        active = np.arange(len(keys))
        slots = self._slots(keys)
        mask = self.capacity - 1
        while len(active):
            stored = self._keys[slots]
            hit = stored == keys[active]
            out[active[hit]] = self._vals[slots[hit]]
            go_on = ~hit & (stored != _EMPTY)
            active, slots = active[go_on], (slots[go_on] + 1) & mask
        return out

    def insert(self, keys: np.ndarray, values: np.ndarray) -> None:
        """Add keys that are unique and not yet present."""
        keys = np.asarray(keys, dtype=np.int64).ravel()
        values = np.asarray(values, dtype=np.int32).ravel()
        if self.size + len(keys) > _MAX_LOAD * self.capacity:
            self._grow(self.size + len(keys))
        self._place(keys, values)
        self.size += len(keys)

    def _place(self, keys: np.ndarray, values: np.ndarray) -> None:
        slots = self._slots(keys)
        mask = self.capacity - 1
        while len(keys):
            free = np.flatnonzero(self._keys[slots] == _EMPTY)
            # Several keys may reach the same free slot in one round: the first takes it, the rest probe on.
            _, first = np.unique(slots[free], return_index=True)
            won = free[first]
            self._keys[slots[won]] = keys[won]
            self._vals[slots[won]] = values[won]
            rest = np.ones(len(keys), bool)
            rest[won] = False
            keys, values, slots = keys[rest], values[rest], (slots[rest] + 1) & mask

    def _grow(self, needed: int) -> None:
        cap = self.capacity
        while needed > _MAX_LOAD * cap:
            cap *= 2
        used = self._keys != _EMPTY
        keys, vals = self._keys[used], self._vals[used]
        self._keys = np.full(cap, _EMPTY, np.int64)
        self._vals = np.full(cap, -1, np.int32)
        self._bits = cap.bit_length() - 1
        self._place(keys, vals)


class _CellIndex:
    """Coarse cells (e.g. 0.3 m) -> the rows stored in them, as a fixed-width member table."""

    def __init__(self, voxel_size: float, cell_m: float) -> None:
        ratio = cell_m / voxel_size
        self.cell_m = cell_m
        # With an integer ratio a cell holds whole voxels, so it can hold at most ratio^3 stored points.
        self.per_voxel = abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1
        self.ratio = round(ratio) if self.per_voxel else 0
        self.width = self.ratio**3 if self.per_voxel else (int(np.ceil(ratio)) + 1) ** 3
        self.table = KeyTable()
        self.members = np.full((256, self.width), -1, np.int32)
        self.counts = np.zeros(256, np.int32)
        self.num_cells = 0
        self.indexed = 0  # rows [0, indexed) are in the index

    def cell_coords(self, vmap: VoxelMap, rows: np.ndarray) -> np.ndarray:
        if self.per_voxel:
            return np.floor_divide(unpack_keys(vmap.keys[rows]), self.ratio)
        return np.floor(vmap.positions[rows] / self.cell_m).astype(np.int64)

    def update(self, vmap: VoxelMap) -> None:
        rows = np.arange(self.indexed, len(vmap), dtype=np.int32)
        self.indexed = len(vmap)
        if not len(rows):
            return
        ckeys = pack_keys(self.cell_coords(vmap, rows))
        uniq, inverse = np.unique(ckeys, return_inverse=True)
        cells = self.table.find(uniq)
        new = cells < 0
        cells[new] = np.arange(self.num_cells, self.num_cells + new.sum(), dtype=np.int32)
        self.table.insert(uniq[new], cells[new])
        self.num_cells += int(new.sum())
        if self.num_cells > len(self.counts):
            cap = max(self.num_cells, 2 * len(self.counts))
            members = np.full((cap, self.width), -1, np.int32)
            members[: len(self.members)] = self.members
            counts = np.zeros(cap, np.int32)
            counts[: len(self.counts)] = self.counts
            self.members, self.counts = members, counts
        cell_of_row = cells[inverse.ravel()]
        order = np.argsort(cell_of_row, kind="stable")
        sorted_cells = cell_of_row[order]
        start = np.r_[0, np.flatnonzero(np.diff(sorted_cells)) + 1]
        rank = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
        slot = self.counts[sorted_cells] + rank
        fits = slot < self.width  # only for non-integer ratios can a cell overflow; extra points are left out
        self.members[sorted_cells[fits], slot[fits]] = rows[order][fits]
        np.add.at(self.counts, sorted_cells[fits], 1)


class VoxelMap:
    """Hash from voxel coordinates to one stored point and its results; see the module docstring.

    Per-row arrays (views of the first `len(map)` rows): `positions` (float64, 3), `colors` (uint8, 3),
    `normals` (float32, 3), `class_ids` (uint16, UNLABELLED until labelled), `instance_ids` (uint32, 0 = none),
    `embeddings` (float32, D), `first_seq` (int32, the scan that opened the voxel), `scores` (float32, the
    labeller's confidence in the class the voxel carries now: for MCPNet its softmax probability of that class),
    `keys` (int64 packed voxel coordinates) and, when the log has ground truth, `true_class_ids` and
    `true_instance_ids` of the stored point.
    """

    _FIELDS: Final = (
        ("positions", np.float64, 3, 0),
        ("colors", np.uint8, 3, 0),
        ("normals", np.float32, 3, 0),
        ("class_ids", np.uint16, 0, UNLABELLED),
        ("instance_ids", np.uint32, 0, 0),
        ("first_seq", np.int32, 0, -1),
        ("scores", np.float32, 0, 0),
        ("keys", np.int64, 0, _EMPTY),
        ("true_class_ids", np.uint16, 0, UNLABELLED),
        ("true_instance_ids", np.uint32, 0, 0),
    )

    def __init__(self, voxel_size: float, embedding_dim: int = 0) -> None:
        if voxel_size <= 0:
            raise ValueError("voxel_size must be positive")
        self.voxel_size = float(voxel_size)
        self.embedding_dim = int(embedding_dim)
        self.has_truth = False
        self.has_color = False  # some scan brought colour (else the stored grey stands for none)
        self._n = 0
        self._table = KeyTable()
        self._data: dict[str, np.ndarray] = {}
        self._allocate(_MIN_ROWS)
        self._cells: dict[float, _CellIndex] = {}

    @classmethod
    def from_config(cls, cfg: MapConfig, embedding_dim: int = 0) -> VoxelMap:
        """The run's map at `cfg.voxel_size_m`, holding embeddings of `embedding_dim` (0 = none) per voxel."""
        return cls(cfg.voxel_size_m, embedding_dim)

    def _allocate(self, rows: int) -> None:
        for name, dtype, width, fill in self._FIELDS:
            shape = (rows, width) if width else (rows,)
            arr = np.full(shape, fill, dtype)
            if name in self._data:
                arr[: self._n] = self._data[name][: self._n]
            self._data[name] = arr
        emb = np.zeros((rows, self.embedding_dim), np.float32)
        if "embeddings" in self._data:
            emb[: self._n] = self._data["embeddings"][: self._n]
        self._data["embeddings"] = emb

    def __len__(self) -> int:
        return self._n

    # Views of the filled rows; writing into them writes into the map.
    @property
    def positions(self) -> np.ndarray:
        return self._data["positions"][: self._n]

    @property
    def colors(self) -> np.ndarray:
        return self._data["colors"][: self._n]

    @property
    def normals(self) -> np.ndarray:
        return self._data["normals"][: self._n]

    @property
    def class_ids(self) -> np.ndarray:
        return self._data["class_ids"][: self._n]

    @property
    def instance_ids(self) -> np.ndarray:
        return self._data["instance_ids"][: self._n]

    @property
    def embeddings(self) -> np.ndarray:
        return self._data["embeddings"][: self._n]

    @property
    def first_seq(self) -> np.ndarray:
        return self._data["first_seq"][: self._n]

    @property
    def scores(self) -> np.ndarray:
        return self._data["scores"][: self._n]

    @property
    def keys(self) -> np.ndarray:
        return self._data["keys"][: self._n]

    @property
    def true_class_ids(self) -> np.ndarray:
        return self._data["true_class_ids"][: self._n]

    @property
    def true_instance_ids(self) -> np.ndarray:
        return self._data["true_instance_ids"][: self._n]

    @property
    def capacity(self) -> int:
        return len(self._data["positions"])

    @property
    def nbytes(self) -> int:
        cells = sum(c.members.nbytes + c.counts.nbytes + c.table.nbytes for c in self._cells.values())
        return sum(a.nbytes for a in self._data.values()) + self._table.nbytes + cells

    def voxel_coords(self, points: np.ndarray) -> np.ndarray:
        return np.floor(np.asarray(points, dtype=np.float64) / self.voxel_size).astype(np.int64)

    def keys_of(self, points: np.ndarray) -> np.ndarray:
        return pack_keys(self.voxel_coords(points))

    def insert(
        self,
        points_world: np.ndarray,
        colors: np.ndarray | None = None,
        seq: int = 0,
        true_class_ids: np.ndarray | None = None,
        true_instance_ids: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Store the first point of every voxel not seen before.

        Returns (rows of the newly opened voxels, in first-point order; the row of every input point).
        """
        pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        if not len(pts):
            return np.zeros(0, np.int32), np.zeros(0, np.int32)
        keys = self.keys_of(pts)
        uniq, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        rows = self._table.find(uniq)
        new = np.flatnonzero(rows < 0)
        new = new[np.argsort(first[new], kind="stable")]  # rows follow the order points arrived in
        new_rows = np.arange(self._n, self._n + len(new), dtype=np.int32)
        rows[new] = new_rows
        if len(new):
            self._table.insert(uniq[new], new_rows)
            if self._n + len(new) > self.capacity:
                self._allocate(max(self._n + len(new), int(self.capacity * 1.5)))
            src = first[new]
            d = self._data
            d["positions"][new_rows] = pts[src]
            if colors is not None:
                d["colors"][new_rows] = np.asarray(colors)[src]
                self.has_color = True
            else:
                d["colors"][new_rows] = 200
            d["keys"][new_rows] = uniq[new]
            d["first_seq"][new_rows] = seq
            if true_class_ids is not None:
                self.has_truth = True
                d["true_class_ids"][new_rows] = np.asarray(true_class_ids)[src]
            if true_instance_ids is not None:
                d["true_instance_ids"][new_rows] = np.asarray(true_instance_ids)[src]
            self._n += len(new)
        return new_rows, rows[inverse.ravel()]

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Rows of packed voxel keys (-1 where the voxel is empty)."""
        return self._table.find(keys)

    def lookup_points(self, points: np.ndarray) -> np.ndarray:
        """Rows of the voxels the points fall in (-1 where empty)."""
        return self._table.find(self.keys_of(points))

    def neighbour_rows(self, rows: np.ndarray, radius_voxels: int = 1) -> np.ndarray:
        """(K, (2r+1)^3) rows of the voxels around each row's voxel, the row itself in the middle column;
        -1 where a voxel is empty."""
        rows = np.asarray(rows, dtype=np.int64)
        offsets = pack_offsets(radius_voxels)
        keys = self._data["keys"][rows][:, None] + offsets[None, :]
        return self._table.find(keys.ravel()).reshape(len(rows), len(offsets))

    def context_rows(
        self,
        points: np.ndarray,
        cell_m: float = 0.3,
        num: int = 50,
        rng: np.random.Generator | None = None,
        uniform: np.ndarray | None = None,
    ) -> np.ndarray:
        """(K, num) rows drawn with replacement from the stored points in the 3 x 3 x 3 block of `cell_m`
        cells around each point (MCPNet's context); -1 in rows with no stored point nearby.
        `uniform` (K, num) numbers in [0, 1) replace the draws from `rng` (e.g. hashed from each point's
        voxel, so that a point's context does not depend on the other points asked about with it)."""
        rng = rng or np.random.default_rng(0)
        index = self._cells.get(cell_m)
        if index is None:
            index = self._cells[cell_m] = _CellIndex(self.voxel_size, cell_m)
        index.update(self)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        k = len(pts)
        if index.per_voxel:
            coords = np.floor_divide(self.voxel_coords(pts), index.ratio)
        else:
            coords = np.floor(pts / cell_m).astype(np.int64)
        cells = index.table.find((pack_keys(coords)[:, None] + pack_offsets(1)[None, :]).ravel()).reshape(k, 27)
        counts = np.where(cells >= 0, index.counts[np.maximum(cells, 0)], 0)
        cum = np.cumsum(counts, axis=1)
        total = cum[:, -1]
        u = rng.random((k, num)) if uniform is None else np.asarray(uniform, dtype=np.float64).reshape(k, num)
        draw = np.minimum((u * total[:, None]).astype(np.int64), np.maximum(total[:, None] - 1, 0))
        which = (draw[:, :, None] >= cum[:, None, :]).sum(axis=2)  # (K, num) index of the cell among the 27
        which = np.minimum(which, 26)
        before = np.take_along_axis(cum - counts, which, axis=1)
        chosen_cells = np.take_along_axis(cells, which, axis=1)
        out = index.members[np.maximum(chosen_cells, 0), draw - before]
        out[total == 0] = -1
        return out

    def to_cloud(self) -> LabelledCloud:
        """The map as a labelled cloud (copies, safe to keep while the map grows)."""
        return LabelledCloud(
            self.positions.copy(),
            self.colors.copy(),
            None,
            self.class_ids.copy(),
            self.instance_ids.copy(),
            self.normals.copy(),
            self.scores.copy(),
        )

    def truth_cloud(self) -> LabelledCloud:
        """The stored points with their true labels (for evaluation)."""
        return LabelledCloud(
            self.positions.copy(), self.colors.copy(), None, self.true_class_ids.copy(), self.true_instance_ids.copy()
        )
