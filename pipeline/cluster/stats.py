"""Per-instance statistics of the clustering and the plane cache built on them.

Per instance id: its voxel count, the scan it last grew in, the sums of its voxels' embeddings, positions and
position products (so its mean embedding and its covariance come without visiting its voxels), and the votes
of the classes the labeller gave them. From the covariance, each instance's plane (planar or not, unit normal,
centroid) is computed once per change of the instance and cached; `Geometry` says when pieces are one surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from aftershock.pipeline.classes import NUM_CLASSES, SemanticClass
from aftershock.pipeline.config import ClusterConfig, settings_from
from aftershock.pipeline.voxel_map import VoxelMap

_PLANE_CLASSES: Final = np.isin(
    np.arange(NUM_CLASSES), [SemanticClass.CEILING, SemanticClass.FLOOR, SemanticClass.WALL]
)
_PRODUCTS: Final = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the columns of `pp`


@dataclass(frozen=True, slots=True)
class Geometry:
    """When two pieces are one surface: planar pieces (thin, and wide in two directions) must share a plane."""

    plane_min_voxels: int = 15  # fewer voxels: the piece's shape is not known yet, no geometric test
    plane_thickness: float = 0.2  # planar: smallest spread (std) at most this share of the middle one
    plane_min_spread_m: float = 0.1  # ... and the middle spread (std) at least this
    plane_angle_deg: float = 20.0  # normals of two planar pieces within this angle
    plane_offset_m: float = 0.2  # ... and each one's centroid within this of the other's plane
    plane_wide_m: float = 0.3  # any thin piece whose middle spread (std) reaches this is planar, whatever its class

    @classmethod
    def from_config(cls, cfg: ClusterConfig) -> Geometry:
        return settings_from(cfg, cls)


class InstanceStats:
    """The per-instance sums and plane cache; `same_class`: pieces whose majority classes differ never fit."""

    def __init__(self, geometry: Geometry, same_class: bool = False) -> None:
        self.geometry = geometry
        self.same_class = same_class
        self.size: np.ndarray = np.zeros(0, np.int64)  # voxels per instance id
        self.last_grown = np.zeros(0, np.int64)  # scan in which each instance last gained a voxel
        self.sums: np.ndarray = np.zeros((0, 0), np.float64)  # per instance id: sum of its voxels' embeddings
        self.psum: np.ndarray = np.zeros((0, 3), np.float64)  # ... of their positions
        self.pp: np.ndarray = np.zeros((0, 6), np.float64)  # ... of xx, xy, xz, yy, yz, zz
        self.votes: np.ndarray = np.zeros((0, NUM_CLASSES), np.int64)  # ... of the classes the labeller first gave them
        self.plane_known = np.zeros(0, bool)  # per instance id: the cached plane below is current
        self.plane_planar = np.zeros(0, bool)
        self.plane_normal = np.zeros((0, 3))
        self.plane_centroid = np.zeros((0, 3))

    def reserve(self, next_id: int) -> None:
        """Room in the per-instance arrays for every id below `next_id`."""
        if len(self.size) >= next_id:
            return
        n = max(next_id, 2 * len(self.size), 1024)

        def grow(arr: np.ndarray, fill: float = 0) -> np.ndarray:
            out = np.full((n, *arr.shape[1:]), fill, arr.dtype)
            out[: len(arr)] = arr
            return out

        self.size, self.last_grown = grow(self.size), grow(self.last_grown, -1)
        self.psum, self.pp, self.votes = grow(self.psum), grow(self.pp), grow(self.votes)
        if self.sums.shape[1]:
            self.sums = grow(self.sums)

    def grow(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int, next_id: int) -> None:
        """Add the new rows (their instance ids already set in the map) to their instances' sums."""
        if self.sums.shape[1] != vmap.embeddings.shape[1]:
            self.sums = np.zeros((len(self.size), vmap.embeddings.shape[1]))
        self.reserve(next_id)
        ids = vmap.instance_ids[new_rows].astype(np.int64)
        n = len(self.size)
        self.size += np.bincount(ids, minlength=n)[:n]
        grown = np.unique(ids)
        self.last_grown[grown] = seq
        self.plane_known[grown[grown < len(self.plane_known)]] = False
        p = vmap.positions[new_rows]
        for j in range(3):
            self.psum[:, j] += np.bincount(ids, weights=p[:, j], minlength=n)[:n]
        for j, (c0, c1) in enumerate(_PRODUCTS):
            self.pp[:, j] += np.bincount(ids, weights=p[:, c0] * p[:, c1], minlength=n)[:n]
        cls = vmap.class_ids[new_rows].astype(np.int64)
        known = cls < NUM_CLASSES
        np.add.at(self.votes, (ids[known], cls[known]), 1)
        if self.sums.shape[1]:
            np.add.at(self.sums, ids, vmap.embeddings[new_rows])

    def shrink(self, vmap: VoxelMap, rows: np.ndarray) -> None:
        """Take rows out of their instances' sums (before they move to another instance); a row's class vote
        is taken back where its current class still holds one (the labeller may have changed it since)."""
        ids = vmap.instance_ids[rows].astype(np.int64)
        keep = (ids > 0) & (ids < len(self.size))
        rows, ids = rows[keep], ids[keep]
        if not len(rows):
            return
        n = len(self.size)
        self.size -= np.bincount(ids, minlength=n)[:n]
        p = vmap.positions[rows]
        for j in range(3):
            self.psum[:, j] -= np.bincount(ids, weights=p[:, j], minlength=n)[:n]
        for j, (c0, c1) in enumerate(_PRODUCTS):
            self.pp[:, j] -= np.bincount(ids, weights=p[:, c0] * p[:, c1], minlength=n)[:n]
        cls = vmap.class_ids[rows].astype(np.int64)
        known = cls < NUM_CLASSES
        np.subtract.at(self.votes, (ids[known], cls[known]), 1)
        np.maximum(self.votes, 0, out=self.votes)
        if self.sums.shape[1]:
            np.subtract.at(self.sums, ids, vmap.embeddings[rows])
        changed = np.unique(ids)
        self.plane_known[changed[changed < len(self.plane_known)]] = False

    def merge(self, gone: np.ndarray, into: np.ndarray) -> None:
        """The sums of instances `gone` move to `into` (room reserved by the caller)."""
        for arr in (self.size, self.psum, self.pp, self.votes, self.sums):
            if arr.ndim == 1 or arr.shape[1]:
                np.add.at(arr, into, arr[gone])
                arr[gone] = 0
        np.maximum.at(self.last_grown, into, self.last_grown[gone])
        changed = np.r_[gone, into]
        self.plane_known[changed[changed < len(self.plane_known)]] = False

    # ------------------------------------------------------------------------------------------ planes

    def planes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(planar (M,) bool, unit normal (M, 3), centroid (M, 3)) of instances, computed once per change
        of an instance (cached until it grows or merges)."""
        ids = np.asarray(ids, dtype=np.int64)
        if len(self.plane_known) < len(self.size):
            n = len(self.size)
            self.plane_known = np.zeros(n, bool)  # a resize follows the per-instance arrays: recompute all
            self.plane_planar = np.zeros(n, bool)
            self.plane_normal = np.zeros((n, 3))
            self.plane_centroid = np.zeros((n, 3))
        todo = np.unique(ids[~self.plane_known[ids]])
        if len(todo):
            planar, normal, centroid = self._fit_planes(todo)
            self.plane_planar[todo], self.plane_normal[todo], self.plane_centroid[todo] = planar, normal, centroid
            self.plane_known[todo] = True
        return self.plane_planar[ids], self.plane_normal[ids], self.plane_centroid[ids]

    def _fit_planes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = np.maximum(self.size[ids], 1).astype(np.float64)
        c = self.psum[ids] / n[:, None]
        m = self.pp[ids] / n[:, None]
        cov = np.empty((len(ids), 3, 3))
        for j, (c0, c1) in enumerate(_PRODUCTS):
            cov[:, c0, c1] = cov[:, c1, c0] = m[:, j] - c[:, c0] * c[:, c1]
        w, vec = np.linalg.eigh(cov)  # ascending
        w = np.maximum(w, 0.0)
        g = self.geometry
        votes = self.votes[ids]
        # Only structure (floor, ceiling, walls) is held to its plane: furniture is made of planes at angles.
        thin = (self.size[ids] >= g.plane_min_voxels) & (np.sqrt(w[:, 0]) <= g.plane_thickness * np.sqrt(w[:, 1]))
        structure = _PLANE_CLASSES[votes.argmax(1)] & (votes.sum(1) > 0)
        # A piece the network calls structure is held to its plane once it is a little wide; any thin piece
        # once it is as wide as a wall (the network confuses walls with columns, boards, bookcases).
        planar = thin & (
            (structure & (np.sqrt(w[:, 1]) >= g.plane_min_spread_m)) | (np.sqrt(w[:, 1]) >= g.plane_wide_m)
        )
        return planar, vec[:, :, 0], c

    def on_plane(self, ids: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Per (instance, point): the instance is not planar, or the point lies on its plane."""
        if not len(ids):
            return np.zeros(0, bool)
        uniq, inv = np.unique(ids, return_inverse=True)
        planar, normal, centroid = self.planes(uniq)
        inv = inv.ravel()
        dist = np.abs(np.einsum("ij,ij->i", points - centroid[inv], normal[inv]))
        return ~planar[inv] | (dist <= self.geometry.plane_offset_m)

    def compatible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Pairs of instances whose geometry (and, if asked, majority class) allows them to be one object."""
        return self.fit(a, b)[0]

    def fit(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(compatible, one plane): pairs that may be one object, and pairs of planar pieces of one plane."""
        pa, na, ca = self.planes(a)
        pb, nb, cb = self.planes(b)
        g = self.geometry
        parallel = np.abs(np.einsum("ij,ij->i", na, nb)) >= np.cos(np.radians(g.plane_angle_deg))
        d = cb - ca
        coplanar = (np.abs(np.einsum("ij,ij->i", d, na)) <= g.plane_offset_m) & (
            np.abs(np.einsum("ij,ij->i", d, nb)) <= g.plane_offset_m
        )
        ok = ~(pa & pb) | (parallel & coplanar)
        # One planar piece and a non-planar one: the non-planar piece must not stand off the plane entirely.
        one = pa ^ pb
        if one.any():
            plane_n = np.where(pa[:, None], na, nb)
            plane_c = np.where(pa[:, None], ca, cb)
            other_c = np.where(pa[:, None], cb, ca)
            near = np.abs(np.einsum("ij,ij->i", other_c - plane_c, plane_n)) <= 2 * g.plane_offset_m
            ok &= ~one | near
        if self.same_class:
            va, vb = self.votes[a], self.votes[b]
            known = (va.sum(1) > 0) & (vb.sum(1) > 0)
            ok &= ~known | (va.argmax(1) == vb.argmax(1))
        return ok, ok & pa & pb

    def similarity(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Cosine similarity of the mean embeddings of instances a and b (pairwise)."""
        sa, sb = self.sums[a], self.sums[b]
        na = np.maximum(np.linalg.norm(sa, axis=1), 1e-12)
        nb = np.maximum(np.linalg.norm(sb, axis=1), 1e-12)
        return np.einsum("ij,ij->i", sa, sb) / (na * nb)
