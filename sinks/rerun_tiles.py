"""The map cut into square tiles, and which tiles changed since the last update (no Rerun here).

The accumulated map is voxel-downsampled, cut into tiles of `tile_m` by x and y, and each tile signed by its
point count, an order-free hash of its positions and one of its positions with labels. Between two updates
only the tiles whose signature changed need logging again; a tile whose points stayed (map rows only append)
needs only its labels again, and a tile that emptied is cleared.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.geometry import voxel_downsample
from aftershock.pipeline.types import LabelledCloud

Signature = tuple[int, int, int]  # (points, position hash, label hash)


def tile_name(ix: int, iy: int) -> str:
    """The tile's entity name: x{ix}y{iy}, minus signs written as m."""
    return f"x{ix}y{iy}".replace("-", "m")


def content_hash(points: np.ndarray, class_ids: np.ndarray, instance_ids: np.ndarray) -> np.ndarray:
    """A 64-bit hash per point of its position (mm) and labels; summing them gives an order-free tile hash."""
    mm = np.round(points * 1000.0).astype(np.int64).view(np.uint64)
    h = mm[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    h ^= mm[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= mm[:, 2] * np.uint64(0x165667B19E3779F9)
    h ^= class_ids.astype(np.uint64) * np.uint64(0x27D4EB2F165667C5)
    h ^= instance_ids.astype(np.uint64) * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(29))


@dataclass(frozen=True, slots=True)
class TileChange:
    """One tile to log again: its points are `sel` (indices into the update's arrays)."""

    name: str
    sel: np.ndarray
    labels_only: bool  # the same points in the same order as before: only their labels are new


@dataclass(slots=True)
class TileUpdate:
    """The downsampled map of one update and what changed in it, tile by tile."""

    points: np.ndarray  # (M, 3) float64, one per voxel
    class_ids: np.ndarray  # (M,) uint16 (UNLABELLED where the cloud has none)
    instance_ids: np.ndarray  # (M,) uint32
    colors: np.ndarray | None  # (M, 3) uint8: only for a cloud without classes (drawn by colour then)
    confidence: np.ndarray | None  # (M,) float32, the labeller's probability for the class (None: not known)
    changed: list[TileChange] = field(default_factory=list)
    gone: list[str] = field(default_factory=list)  # tiles that emptied


class MapTiles:
    """The signatures of the tiles last logged; `update` says what to log for a new state of the map."""

    def __init__(self, voxel_m: float, tile_m: float) -> None:
        self.voxel_m = voxel_m
        self.tile_m = tile_m
        self.signatures: dict[str, Signature] = {}
        self.bounds: tuple[np.ndarray, np.ndarray] | None = None  # of the last map that had points

    def update(self, cloud: LabelledCloud) -> TileUpdate | None:
        """What to log for this map (None for an empty one, which changes nothing)."""
        if len(cloud) == 0:
            return None
        keep, _ = voxel_downsample(cloud.points, self.voxel_m)
        pts = cloud.points[keep]
        n = len(pts)
        cls = cloud.class_ids[keep] if cloud.class_ids is not None else np.full(n, UNLABELLED, np.uint16)
        inst = cloud.instance_ids[keep] if cloud.instance_ids is not None else np.zeros(n, np.uint32)
        colors = cloud.colors[keep] if cloud.class_ids is None and cloud.colors is not None else None
        conf = cloud.confidence[keep] if cloud.confidence is not None else None
        self.bounds = (pts.min(axis=0), pts.max(axis=0))
        out = TileUpdate(pts, cls, inst, colors, conf)

        cell = np.floor(pts[:, :2] / self.tile_m).astype(np.int64)
        packed = (cell[:, 0] << 32) + cell[:, 1]  # one sortable key per tile (tile indices stay far below 2^31)
        order = np.argsort(packed, kind="stable")
        sorted_keys = packed[order]
        starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
        counts = np.diff(np.r_[starts, n])
        tiles = cell[order[starts]]
        zeros = np.zeros(n, np.uint16)
        where_hash = np.add.reduceat(content_hash(pts, zeros, zeros.astype(np.uint32))[order], starts)
        label_hash = np.add.reduceat(content_hash(pts, cls, inst)[order], starts)
        if conf is not None:  # a confidence that moved by a percent is a change of the tile's labels
            percent = np.round(conf * 100).astype(np.uint16)
            label_hash += np.add.reduceat(content_hash(pts, percent, zeros.astype(np.uint32))[order], starts)
        seen: set[str] = set()
        for t, (ix, iy) in enumerate(tiles):
            name = tile_name(int(ix), int(iy))
            seen.add(name)
            signature = (int(counts[t]), int(where_hash[t]), int(label_hash[t]))
            before = self.signatures.get(name)
            if before == signature:
                continue
            self.signatures[name] = signature
            sel = order[starts[t] : starts[t] + counts[t]]
            labels_only = before is not None and before[:2] == signature[:2] and colors is None
            out.changed.append(TileChange(name, sel, labels_only))
        for gone in sorted(set(self.signatures) - seen):
            del self.signatures[gone]
            out.gone.append(gone)
        return out
