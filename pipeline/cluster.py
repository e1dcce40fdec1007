"""Clustering stage: incremental instance clustering over the voxel map (union–find by connected components).

Each new voxel links to its 26 neighbouring voxels (new ones of the same scan, and older ones that already
carry an instance) where the labeller's affinity says they agree (for MCPNet: cosine similarity of the
embeddings above β). Per connected group of links:
- no older instance in the group: a new instance;
- one: the new voxels join it;
- several: the group takes the smallest id and the others are merged into it everywhere in the map.
With `merge_beta` (labellers with embeddings), neighbouring instances also merge when their mean
embeddings agree: a voxel's embedding is noisy and single links stop short of an object's far parts, the
mean over an instance's voxels is not, so fragments of one object join once each has a few voxels.
With `absorb`, a small fragment that has stopped growing (an object still being scanned keeps growing)
joins the neighbouring instance it agrees with most, at a lower similarity.
Merges are recorded on the frame as `InstanceMerge`s, so the sinks can show them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from time import perf_counter

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.config import ClusterConfig
from aftershock.pipeline.types import Frame, InstanceMerge
from aftershock.pipeline.voxel_map import VoxelMap

Affinity = Callable[[VoxelMap, np.ndarray, np.ndarray], np.ndarray]


class InstanceClusterer:
    def __init__(
        self,
        affinity: Affinity,
        reach_voxels: int = 1,
        merge_beta: float | None = None,
        absorb: tuple[int, int, float] | None = None,
    ) -> None:
        self.affinity = affinity
        self.reach = reach_voxels
        self.merge_beta = merge_beta
        self.absorb = absorb  # (fewest voxels, scans without growth, similarity): see `_absorb_stale`
        self.size = np.zeros(0, np.int64)  # voxels per instance id
        self.last_grown = np.zeros(0, np.int64)  # scan in which each instance last gained a voxel
        self.next_id = 1  # 0 means "no object"
        self.sums = np.zeros((0, 0), np.float64)  # per instance id: sum of its voxels' embeddings

    @classmethod
    def from_config(cls, cfg: ClusterConfig, affinity: Affinity, embedding_dim: int) -> InstanceClusterer:
        """The clusterer for a labeller with `affinity`; the mean-embedding merge and the absorption of stale
        fragments need embeddings (`embedding_dim` > 0) and are off when `merge_beta` > 1 / `absorb_voxels` <= 1."""
        merge_beta = cfg.merge_beta if embedding_dim and cfg.merge_beta <= 1 else None
        absorb = None
        if merge_beta is not None and cfg.absorb_voxels > 1:
            absorb = (cfg.absorb_voxels, cfg.absorb_after_scans, cfg.absorb_beta)
        return cls(affinity, cfg.link_reach_voxels, merge_beta, absorb)

    def add(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Give the new rows instance ids, merging instances they bridge; returns the merges."""
        new_rows = np.asarray(new_rows, dtype=np.int64)
        k = len(new_rows)
        if not k:
            return []
        nb = vmap.neighbour_rows(new_rows, self.reach)
        a = np.repeat(np.arange(k), nb.shape[1])
        b = nb.ravel().astype(np.int64)
        keep = b >= 0
        a, b = a[keep], b[keep]
        order = np.argsort(new_rows)
        pos = np.searchsorted(new_rows, b, sorter=order).clip(max=k - 1)
        b_local = order[pos]
        b_is_new = new_rows[b_local] == b
        old_ids = vmap.instance_ids[b]
        # New-new pairs once each (the voxel itself excluded); new-old pairs only to labelled voxels.
        candidate = np.where(b_is_new, b_local > a, old_ids > 0)
        a, b, b_local = a[candidate], b[candidate], b_local[candidate]
        b_is_new, old_ids = b_is_new[candidate], old_ids[candidate]
        contact_a, contact_b = new_rows[a], b  # every neighbouring pair, linked or not
        linked = np.asarray(self.affinity(vmap, new_rows[a], b), bool)
        a, b_local, b_is_new, old_ids = a[linked], b_local[linked], b_is_new[linked], old_ids[linked]

        touched, old_node = np.unique(old_ids[~b_is_new], return_inverse=True)
        m = len(touched)
        src = np.r_[a[b_is_new], a[~b_is_new]]
        dst = np.r_[b_local[b_is_new], k + old_node.ravel()]
        graph = coo_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(k + m, k + m))
        ncomp, comp = connected_components(graph, directed=False)

        # Smallest older id per group; groups without one get fresh ids.
        none = np.iinfo(np.int64).max
        group_id = np.full(ncomp, none, np.int64)
        np.minimum.at(group_id, comp[k:], touched.astype(np.int64))
        fresh = group_id == none
        group_id[fresh] = self.next_id + np.arange(int(fresh.sum()))
        self.next_id += int(fresh.sum())
        vmap.instance_ids[new_rows] = group_id[comp[:k]]

        into = group_id[comp[k:]]
        merged = into != touched
        merges = self._merge(vmap, touched[merged], into[merged], seq)
        if self.merge_beta is not None and vmap.embeddings.shape[1]:
            self._add_embeddings(vmap, new_rows)
            merges += self._merge_similar(vmap, contact_a, contact_b, seq)
        if self.absorb is not None and len(self.sums):
            self._grow_counts(vmap, new_rows, seq)
            merges += self._absorb_stale(vmap, seq)
        return merges

    def _reserve(self, seq: int) -> None:
        """Room in the per-instance counts for every id handed out so far."""
        if len(self.size) < self.next_id:
            n = max(self.next_id, 2 * len(self.size), 1024)
            self.size = np.r_[self.size, np.zeros(n - len(self.size), np.int64)]
            self.last_grown = np.r_[self.last_grown, np.full(n - len(self.last_grown), seq, np.int64)]

    def _grow_counts(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int) -> None:
        self._reserve(seq)
        ids = vmap.instance_ids[new_rows].astype(np.int64)
        self.size += np.bincount(ids, minlength=len(self.size))[: len(self.size)]
        self.last_grown[ids] = seq

    def _absorb_stale(self, vmap: VoxelMap, seq: int) -> list[InstanceMerge]:
        """A fragment that stayed under `absorb[0]` voxels for `absorb[1]` scans (an object still being
        scanned keeps growing) joins the neighbouring instance whose mean embedding it agrees with most,
        if that similarity reaches `absorb[2]`. Each fragment gets this one chance."""
        assert self.absorb is not None
        min_voxels, wait, beta = self.absorb
        ids = np.arange(len(self.size))
        stale = ids[(self.size > 0) & (self.size < min_voxels) & (self.last_grown == seq - wait)]
        if not len(stale):
            return []
        rows = np.flatnonzero(np.isin(vmap.instance_ids, stale))
        nb = vmap.neighbour_rows(rows, self.reach)
        own = np.repeat(vmap.instance_ids[rows].astype(np.int64), nb.shape[1])
        other = np.where(nb.ravel() >= 0, vmap.instance_ids[np.maximum(nb.ravel(), 0)], 0).astype(np.int64)
        ok = (other > 0) & (other != own) & (self.size[other] >= min_voxels)
        pairs = np.unique(np.c_[own[ok], other[ok]], axis=0)
        if not len(pairs):
            return []
        sim = self._mean_similarity(pairs)
        good = sim >= beta
        pairs, sim = pairs[good], sim[good]
        order = np.lexsort((-sim, pairs[:, 0]))
        first = order[np.r_[True, pairs[order][1:, 0] != pairs[order][:-1, 0]]] if len(order) else order
        return self._merge(vmap, pairs[first, 0], pairs[first, 1], seq)

    def _merge(self, vmap: VoxelMap, gone: np.ndarray, into: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Instances `gone` become `into` everywhere in the map (and in the embedding sums)."""
        if not len(gone):
            return []
        lut = np.arange(self.next_id, dtype=np.uint32)
        lut[gone] = into
        ids = vmap.instance_ids
        ids[:] = lut[ids]
        if len(self.sums):
            np.add.at(self.sums, into, self.sums[gone])
            self.sums[gone] = 0.0
        if self.absorb is not None:
            self._reserve(seq)
            np.add.at(self.size, into, self.size[gone])
            self.size[gone] = 0
            np.maximum.at(self.last_grown, into, self.last_grown[gone])
        return [
            InstanceMerge(int(target), tuple(int(g) for g in gone[into == target]), seq) for target in np.unique(into)
        ]

    def _add_embeddings(self, vmap: VoxelMap, new_rows: np.ndarray) -> None:
        if len(self.sums) < self.next_id:
            grown = np.zeros((max(self.next_id, 2 * len(self.sums), 1024), vmap.embeddings.shape[1]))
            if len(self.sums):
                grown[: len(self.sums)] = self.sums
            self.sums = grown
        np.add.at(self.sums, vmap.instance_ids[new_rows].astype(np.int64), vmap.embeddings[new_rows])

    def _mean_similarity(self, pairs: np.ndarray) -> np.ndarray:
        """Cosine similarity of the mean embeddings of each pair of instance ids (P, 2)."""
        sums = self.sums[pairs]
        mean = sums / np.maximum(np.linalg.norm(sums, axis=2, keepdims=True), 1e-12)
        return np.einsum("ij,ij->i", mean[:, 0], mean[:, 1])

    def _merge_similar(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Merge neighbouring instances whose mean embeddings' cosine similarity exceeds `merge_beta`."""
        ia = vmap.instance_ids[rows_a].astype(np.int64)
        ib = vmap.instance_ids[rows_b].astype(np.int64)
        pairs = np.unique(np.sort(np.c_[ia, ib][(ia != ib) & (ia > 0) & (ib > 0)], axis=1), axis=0)
        if not len(pairs):
            return []
        pairs = pairs[self._mean_similarity(pairs) > self.merge_beta]
        if not len(pairs):
            return []
        nodes, inv = np.unique(pairs, return_inverse=True)
        inv = inv.reshape(-1, 2)
        graph = coo_matrix((np.ones(len(pairs), np.int8), (inv[:, 0], inv[:, 1])), shape=(len(nodes), len(nodes)))
        _, comp = connected_components(graph, directed=False)
        target = np.full(comp.max() + 1, np.iinfo(np.int64).max, np.int64)
        np.minimum.at(target, comp, nodes)
        into = target[comp]
        keep = into != nodes
        return self._merge(vmap, nodes[keep], into[keep], seq)


def cluster_frame(frame: Frame, vmap: VoxelMap, clusterer: InstanceClusterer) -> Frame:
    if frame.new_voxel_points is not None and len(frame.new_voxel_points):
        new_rows = vmap.lookup_points(frame.world_points[frame.new_voxel_points])
        merges = clusterer.add(vmap, new_rows, frame.seq)
        frame.merges.extend(merges)
        frame.counts["merges"] = len(merges)
    if frame.labels is not None and frame.keep is not None and frame.keep.any():
        idx = np.flatnonzero(frame.keep)
        frame.labels.instance_ids[idx] = vmap.instance_ids[vmap.lookup_points(frame.world_points[idx])]
    frame.counts["instances_opened"] = clusterer.next_id - 1
    return frame


def cluster_stage(frames: Iterable[Frame], vmap: VoxelMap, clusterer: InstanceClusterer) -> Iterator[Frame]:
    for frame in frames:
        t0 = perf_counter()
        cluster_frame(frame, vmap, clusterer)
        frame.timings_ms["cluster"] = (perf_counter() - t0) * 1e3
        yield frame
