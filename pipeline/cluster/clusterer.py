"""The clusterer: instance ids for new voxels, and the instance merges (see the package docstring)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.cluster.pairs import PairTable, pack_ordered, unpack_pairs
from aftershock.pipeline.cluster.stats import Geometry, InstanceStats
from aftershock.pipeline.config import ClusterConfig
from aftershock.pipeline.geometry import group_pca
from aftershock.pipeline.types import InstanceMerge
from aftershock.pipeline.voxel_map import VoxelMap

Affinity = Callable[[VoxelMap, np.ndarray, np.ndarray], np.ndarray]
# Per map row (the first n): the structural element whose object the voxel takes, -1 for none (see `claim`)
Owner = Callable[[int], np.ndarray]

_MAX_FINAL_ROUNDS: Final = 50
_FLAT_CURVATURE: Final = 0.05  # λ0 / (λ0 + λ1 + λ2) of a voxel's neighbourhood at most this: a flat surface


class InstanceClusterer:
    """Instance ids for the voxels of the map as they arrive (see the package docstring), with the rules of
    `cfg`, for a labeller with this affinity and embedding width (0 = none: the rules on mean embeddings are off).
    """

    def __init__(self, cfg: ClusterConfig, affinity: Affinity, embedding_dim: int = 0) -> None:
        self.affinity = affinity
        self.reach = cfg.link_reach_voxels
        self.merge_beta = cfg.merge_beta if embedding_dim and cfg.merge_beta <= 1 else None
        # (fewest voxels, scans without growth, similarity): see `_absorb_stale`
        self.absorb: tuple[int, int, float] | None = None
        if self.merge_beta is not None and cfg.absorb_voxels > 1:
            self.absorb = (cfg.absorb_voxels, cfg.absorb_after_scans, cfg.absorb_beta)
        self.min_contacts = cfg.merge_min_contacts
        self.normal_links = cfg.normal_links  # "off" | "agree" | "strict": see `_normals_agree`
        self.contact_beta, self.contact_ratio = cfg.contact_beta, cfg.contact_ratio
        self.plane_beta = cfg.plane_beta  # mean-embedding similarity enough for two pieces of one plane
        min_links = cfg.merge_links
        self.min_links = max(min_links, 1) if min_links > 0 else np.iinfo(np.int64).max  # 0 = never by links
        self.min_object_voxels = cfg.min_object_voxels
        # fragments under min_object_voxels join a neighbour this similar at the end
        self.final_beta = cfg.final_beta if embedding_dim and cfg.final_beta <= 1 else None
        self.next_id = 1  # 0 means "no object"
        self.stats = InstanceStats(Geometry.from_config(cfg), cfg.merge_same_class)
        self.pairs = PairTable()
        self.owner: Owner | None = None  # set by the stream where the structure model decides objects
        self.key_obj = np.full(0, -1, np.int64)  # element key -> the object its voxels take (-1: none yet)
        self.owned = np.zeros(0, bool)  # per instance id: an element's object (never merges with another)
        self.row_obj = np.zeros(0, np.int64)  # per map row: the element object it shows (0: its own instance)
        self.obj_size = np.zeros(0, np.int64)  # per object id: the voxels showing it as their element's

    @property
    def geometry(self) -> Geometry:
        return self.stats.geometry

    # ------------------------------------------------------------------------------------------ per scan

    def add(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Give the new rows instance ids and merge the instances that now agree; returns the merges."""
        new_rows = np.asarray(new_rows, dtype=np.int64)
        k = len(new_rows)
        merges: list[InstanceMerge] = []
        if k:
            contact_a, contact_b, linked = self._assign(vmap, new_rows)
            self.stats.grow(vmap, new_rows, seq, self.next_id)
            touched = self._add_pairs(vmap, contact_a, contact_b, linked)
            merges += self._merge_pairs(vmap, seq, touched)
        if self.owner is not None:
            self.show_elements(vmap)
        if self.absorb is not None and self.next_id > 1:
            merges += self._absorb_stale(vmap, seq)
        return merges

    def _assign(self, vmap: VoxelMap, new_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Instance ids of the new rows (see the package docstring); returns every neighbouring voxel pair
        (new row, other row) and whether the labeller linked it."""
        k = len(new_rows)
        nb = vmap.neighbour_rows(new_rows, self.reach)
        a = np.repeat(np.arange(k), nb.shape[1])
        b = nb.ravel().astype(np.int64)
        keep = b >= 0
        a, b = a[keep], b[keep]
        order = np.argsort(new_rows)
        pos = np.searchsorted(new_rows, b, sorter=order).clip(max=k - 1)
        b_local = order[pos]
        b_is_new = new_rows[b_local] == b
        old_ids = vmap.instance_ids[b].astype(np.int64)
        # New-new pairs once each (the voxel itself excluded); new-old pairs only to labelled voxels.
        candidate = np.where(b_is_new, b_local > a, old_ids > 0)
        a, b, b_local, b_is_new, old_ids = (
            a[candidate],
            b[candidate],
            b_local[candidate],
            b_is_new[candidate],
            old_ids[candidate],
        )
        linked = np.asarray(self.affinity(vmap, new_rows[a], b), bool)
        if self.normal_links != "off":
            linked &= self._normals_agree(vmap, new_rows, nb, a, b)
        contact_a, contact_b = new_rows[a], b

        pos_new = vmap.positions[new_rows]
        label = np.zeros(k, np.int64)
        # Each group of linked new voxels joins the older instance it has most direct links to (counting only
        # links from voxels on that instance's plane, if it has one); of the group, the voxels on that plane
        # join (all of them, for an instance without a plane). Other older instances the group touches stay
        # apart: whether they are one object is decided at the instance level, where geometry is checked.
        nn = linked & b_is_new
        u, v = a[nn], b_local[nn]
        graph = coo_matrix((np.ones(len(u), np.int8), (u, v)), shape=(k, k))
        _, group = connected_components(graph, directed=False)
        direct = linked & ~b_is_new
        da, did = a[direct], old_ids[direct]
        if len(da):
            self.stats.reserve(self.next_id)
            fits = self.stats.on_plane(did, pos_new[da])
            da, did = da[fits], did[fits]
        if len(da):
            keys, count = np.unique(pack_ordered(group[da], did), return_counts=True)
            g, inst = unpack_pairs(keys)
            order = np.lexsort((-count, g))
            first = order[np.r_[True, g[order][1:] != g[order][:-1]]]
            chosen = np.zeros(group.max() + 1, np.int64)
            chosen[g[first]] = inst[first]
            cand = chosen[group]
            has = np.flatnonzero(cand > 0)
            on = self.stats.on_plane(cand[has], pos_new[has])
            label[has[on]] = cand[has[on]]
        # The rest: connected components over linked new-new pairs among themselves, each a new instance.
        rest = label == 0
        if rest.any():
            both = rest[u] & rest[v]
            graph = coo_matrix((np.ones(int(both.sum()), np.int8), (u[both], v[both])), shape=(k, k))
            _, comp = connected_components(graph, directed=False)
            _, comp_rest = np.unique(comp[rest], return_inverse=True)
            label[rest] = self.next_id + comp_rest.ravel()
            self.next_id += int(comp_rest.max()) + 1
        vmap.instance_ids[new_rows] = label
        return contact_a, contact_b, linked

    def _normals_agree(
        self, vmap: VoxelMap, new_rows: np.ndarray, nb: np.ndarray, a: np.ndarray, b: np.ndarray
    ) -> np.ndarray:
        """Per voxel pair (new row a, row b): False where the local surface normals say two surfaces meet.
        New voxels without a normal from the labeller get one here (PCA over their neighbouring voxels); a
        normal counts when the surface around the voxel is flat (curvature <= _FLAT_CURVATURE). "agree":
        two flat voxels must have parallel normals; "strict": besides, a flat voxel and a voxel at an edge
        or corner do not link (a corner belongs to both walls and would otherwise join them)."""
        missing = ~np.abs(vmap.normals[new_rows]).any(axis=1)
        if missing.any():
            pos = vmap.positions[np.maximum(nb[missing], 0)]
            normals, curvature = group_pca(pos, nb[missing] >= 0)
            normals[curvature > _FLAT_CURVATURE] = 0.0  # not flat: no normal (zero also means "unknown")
            vmap.normals[new_rows[missing]] = normals
        na, nbv = vmap.normals[new_rows[a]], vmap.normals[b]
        fa, fb = np.abs(na).any(axis=1), np.abs(nbv).any(axis=1)
        parallel = np.abs(np.einsum("ij,ij->i", na, nbv)) >= np.cos(np.radians(self.geometry.plane_angle_deg))
        ok = ~(fa & fb) | parallel
        if self.normal_links == "strict":
            ok &= fa == fb
        return ok

    # ------------------------------------------------------------------------------------------ elements

    def _reserve_owned(self) -> None:
        self.stats.reserve(self.next_id)
        if len(self.owned) < len(self.stats.size):
            owned = np.zeros(len(self.stats.size), bool)
            owned[: len(self.owned)] = self.owned
            self.owned = owned

    def is_owned(self, ids: np.ndarray) -> np.ndarray:
        """Whether each instance id is a structural element's object."""
        ids = np.asarray(ids, np.int64)
        out = np.zeros(len(ids), bool)
        inside = ids < len(self.owned)
        out[inside] = self.owned[ids[inside]]
        return out

    def show_elements(self, vmap: VoxelMap) -> None:
        """Which element object each voxel shows (`row_obj`): voxels on a structural element (`owner`) show the
        element's object, geometry and not embeddings saying what one slab, column or beam is. The clustering
        underneath is left as it is (its instances, and the class votes over them, do not change) until `claim`.
        An element first seen takes over the object of an element gone since (a refitted slab keeps its object
        id) where most of its voxels showed it, else a new id."""
        n = len(vmap)
        if self.owner is None or not n:
            return
        keys = np.asarray(self.owner(n), np.int64)
        if len(self.row_obj) < n:
            self.row_obj = np.r_[self.row_obj, np.zeros(max(n, 2 * len(self.row_obj)) - len(self.row_obj), np.int64)]
        rows = np.flatnonzero(keys >= 0)
        k = keys[rows]
        if len(k) and len(self.key_obj) <= int(k.max()):
            grown = np.full(max(int(k.max()) + 1, 2 * len(self.key_obj)), -1, np.int64)
            grown[: len(self.key_obj)] = self.key_obj
            self.key_obj = grown
        fresh = np.unique(k[self.key_obj[k] < 0])
        if len(fresh):
            live = np.zeros(len(self.key_obj), bool)
            live[k] = True
            dead = np.flatnonzero((self.key_obj >= 0) & ~live)  # elements gone (refitted, dropped)
            before = self.row_obj[rows]
            for key in fresh.tolist():  # one iteration per element first seen this scan
                mine = before[k == key]
                free = dead[np.isin(self.key_obj[dead], mine)]
                if len(free):
                    votes = np.bincount(mine, minlength=int(self.key_obj[free].max()) + 1)[self.key_obj[free]]
                    heir = int(free[np.argmax(votes)])
                    self.key_obj[key] = self.key_obj[heir]
                    self.key_obj[heir] = -1
                    dead = dead[dead != heir]
                else:
                    self.key_obj[key] = self.next_id
                    self.next_id += 1
        self.row_obj[:n] = 0
        self.row_obj[rows] = self.key_obj[k]
        self.obj_size = np.bincount(self.row_obj[:n], minlength=self.next_id)
        self.obj_size[0] = 0

    def claim(self, vmap: VoxelMap, seq: int) -> np.ndarray:
        """The element objects into the map itself (at the end of a run): every voxel showing an element's object
        (`show_elements`) moves to it, with the per-instance sums and contacts; returns the instances that
        changed. An element's object never merges with another's afterwards."""
        if self.owner is None or not len(vmap):
            return np.zeros(0, np.int64)
        self.show_elements(vmap)
        n = len(vmap)
        rows = np.flatnonzero(self.row_obj[:n] > 0)
        if not len(rows):
            return np.zeros(0, np.int64)
        want = self.row_obj[rows]
        self._reserve_owned()
        self.owned[want] = True
        cur = vmap.instance_ids[rows].astype(np.int64)
        move = cur != want
        if not move.any():
            return np.zeros(0, np.int64)
        moved, into = rows[move], want[move]
        self.stats.shrink(vmap, moved)
        vmap.instance_ids[moved] = into
        self.stats.grow(vmap, moved, seq, self.next_id)
        # the moved voxels touch their neighbours' instances now (not linked: a merge needs agreement)
        nb = vmap.neighbour_rows(moved, self.reach)
        a = np.repeat(moved, nb.shape[1])
        b = nb.ravel().astype(np.int64)
        keep = b >= 0
        self._add_pairs(vmap, a[keep], b[keep], np.zeros(int(keep.sum()), bool))
        return np.unique(np.r_[cur[move], into])

    # ------------------------------------------------------------------------------------------- pairs

    def _add_pairs(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray, linked: np.ndarray) -> np.ndarray:
        """Count the touching voxel pairs between instances; returns the instances this scan touched."""
        ia = vmap.instance_ids[rows_a].astype(np.int64)
        ib = vmap.instance_ids[rows_b].astype(np.int64)
        apart = (ia != ib) & (ia > 0) & (ib > 0)
        self.pairs.add(ia[apart], ib[apart], linked[apart])
        return np.unique(np.r_[ia, ib])

    def _merge_pairs(self, vmap: VoxelMap, seq: int, touched: np.ndarray | None = None) -> list[InstanceMerge]:
        """One round of instance merging over the touching pairs (those of `touched` instances only, if given)."""
        if not len(self.pairs):
            return []
        a, b = self.pairs.pairs()
        sel = np.ones(len(a), bool) if touched is None else np.isin(a, touched) | np.isin(b, touched)
        sel &= self.pairs.contacts >= self.min_contacts
        a, b, links, contacts = a[sel], b[sel], self.pairs.links[sel], self.pairs.contacts[sel]
        # Linked voxel pairs (the study's bridging) or, with embeddings, agreeing mean embeddings; two pieces
        # of one plane need less agreement (their geometry already says they may be one surface).
        agree = links >= self.min_links
        if self.merge_beta is not None:
            sim = self.stats.similarity(a, b)
            agree |= sim > self.merge_beta
            # A long shared boundary (many touching voxel pairs for the smaller piece's size) is evidence too.
            wrapped = contacts >= self.contact_ratio * np.minimum(self.stats.size[a], self.stats.size[b])
            agree |= wrapped & (sim > self.contact_beta)
            maybe = ~agree & (sim > self.plane_beta)  # pieces of one plane: decided below, with the geometry
        else:
            maybe = np.zeros(len(a), bool)
        cand = agree | maybe  # the geometry only for pairs that could merge (most touching pairs cannot)
        a, b, agree, maybe = a[cand], b[cand], agree[cand], maybe[cand]
        ok, one_plane = self.stats.fit(a, b)
        sel = ok & (agree | (maybe & one_plane))
        return self._merge_groups(vmap, a[sel], b[sel], seq)

    def _merge_groups(self, vmap: VoxelMap, a: np.ndarray, b: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Merge the connected groups of the pairs (a, b), each into its smallest id; a planar member whose
        plane disagrees with the group's largest planar member stays out (pairs chain, planes must not)."""
        if not len(a):
            return []
        nodes, inv = np.unique(np.r_[a, b], return_inverse=True)
        inv = inv.reshape(2, -1)
        graph = coo_matrix((np.ones(len(a), np.int8), (inv[0], inv[1])), shape=(len(nodes), len(nodes)))
        _, comp = connected_components(graph, directed=False)
        planar, _, _ = self.stats.planes(nodes)
        owned = self.is_owned(nodes)
        # An element's object anchors its group (another element's stays out: geometry told them apart), else
        # the largest planar member (or the largest member).
        weight = self.stats.size[nodes] + planar * (1 << 40) + owned * (1 << 41)
        order = np.lexsort((-weight, comp))
        first = order[np.r_[True, comp[order][1:] != comp[order][:-1]]]
        anchor = np.zeros(comp.max() + 1, np.int64)
        anchor[comp[first]] = nodes[first]
        fits = self.stats.compatible(anchor[comp], nodes) | (anchor[comp] == nodes)
        fits &= ~owned | (anchor[comp] == nodes)
        nodes, comp = nodes[fits], comp[fits]
        target = np.full(comp.max() + 1, np.iinfo(np.int64).max, np.int64)
        np.minimum.at(target, comp, nodes)
        into = target[comp]
        keep = into != nodes
        return self._merge(vmap, nodes[keep], into[keep], seq)

    def _merge(self, vmap: VoxelMap, gone: np.ndarray, into: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Instances `gone` become `into` everywhere in the map, in the per-instance sums and in the pairs."""
        if not len(gone):
            return []
        self.stats.reserve(self.next_id)
        lut = np.arange(self.next_id, dtype=np.int64)
        lut[gone] = into
        ids = vmap.instance_ids
        ids[:] = lut[ids]
        self.stats.merge(gone, into)
        self.pairs.rename(lut)
        if len(self.owned):  # an element's object keeps its element under its new id
            self._reserve_owned()
            held = self.key_obj >= 0
            self.key_obj[held] = lut[self.key_obj[held]]
            was = self.is_owned(gone)
            self.owned[gone[was]] = False
            self.owned[into[was]] = True
        return [
            InstanceMerge(int(target), tuple(int(g) for g in gone[into == target]), seq) for target in np.unique(into)
        ]

    def _best_neighbour(self, small: np.ndarray, beta: float) -> tuple[np.ndarray, np.ndarray]:
        """For fragments `small`: the larger touching instance whose mean embedding agrees most (at `beta` or
        more) and whose geometry allows it (larger only, so fragments never join each other in a cycle);
        returns (fragments, targets)."""
        a, b = self.pairs.pairs()
        frag = np.r_[a, b]
        other = np.r_[b, a]
        ok = np.isin(frag, small) & (self.stats.size[other] > self.stats.size[frag]) & ~self.is_owned(frag)
        frag, other = frag[ok], other[ok]
        if not len(frag):
            return frag, other
        sim = self.stats.similarity(frag, other)
        good = (sim >= beta) & self.stats.compatible(frag, other)
        frag, other, sim = frag[good], other[good], sim[good]
        order = np.lexsort((-sim, frag))
        first = order[np.r_[True, frag[order][1:] != frag[order][:-1]]] if len(order) else order
        return frag[first], other[first]

    def _absorb_stale(self, vmap: VoxelMap, seq: int) -> list[InstanceMerge]:
        """A fragment that stayed under `absorb[0]` voxels for `absorb[1]` scans (an object still being
        scanned keeps growing) joins the neighbouring instance whose mean embedding it agrees with most,
        if that similarity reaches `absorb[2]`. Each fragment gets this one chance."""
        assert self.absorb is not None
        min_voxels, wait, beta = self.absorb
        ids = np.arange(len(self.stats.size))
        stale = ids[(self.stats.size > 0) & (self.stats.size < min_voxels) & (self.stats.last_grown == seq - wait)]
        if not len(stale) or not len(self.pairs):
            return []
        frag, into = self._best_neighbour(stale, beta)
        big = self.stats.size[into] >= min_voxels
        return self._merge_chain(vmap, frag[big], into[big], seq)

    def _merge_chain(self, vmap: VoxelMap, frag: np.ndarray, into: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Fragments join their targets; a target that is itself joining somewhere passes its fragments on."""
        if not len(frag):
            return []
        lut = np.arange(self.next_id, dtype=np.int64)
        lut[frag] = into
        for _ in range(len(frag)):  # follow chains fragment -> fragment -> instance (short in practice)
            nxt = lut[lut]
            if np.array_equal(nxt, lut):
                break
            lut = nxt
        into = lut[frag]
        keep = into != frag
        return self._merge(vmap, frag[keep], into[keep], seq)

    # ------------------------------------------------------------------------------------------ the end

    def finish(self, vmap: VoxelMap, seq: int) -> list[InstanceMerge]:
        """Map-level consolidation at the end of a run: instance merging over every touching pair until
        nothing changes, then every fragment under `min_object_voxels` joins the touching instance it agrees
        with most (at `final_beta`), larger ones first."""
        merges: list[InstanceMerge] = []
        for _ in range(_MAX_FINAL_ROUNDS):
            step = self._merge_pairs(vmap, seq)
            if not step:
                break
            merges += step
        if self.final_beta is not None and self.min_object_voxels > 1 and len(self.pairs):
            for _ in range(_MAX_FINAL_ROUNDS):
                small = np.flatnonzero((self.stats.size > 0) & (self.stats.size < self.min_object_voxels))
                frag, into = self._best_neighbour(small, self.final_beta)
                step = self._merge_chain(vmap, frag, into, seq)
                if not step:
                    break
                merges += step
        return merges

    def shown_ids(self, instance_ids: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Instance ids as the user sees them: objects under `min_object_voxels` voxels read as 0 (no object);
        with the map `rows` they belong to, voxels on an element show its object (`show_elements`)."""
        ids = np.asarray(instance_ids)
        if rows is not None and len(self.row_obj):
            obj = np.zeros(len(ids), np.int64)
            inside = np.asarray(rows) < len(self.row_obj)
            obj[inside] = self.row_obj[np.asarray(rows)[inside]]
            size = np.zeros(len(ids), np.int64)
            size[obj > 0] = self.obj_size[obj[obj > 0]]
            el = obj > 0
            ids = np.where(el, obj, ids).astype(ids.dtype)
            hidden = self._hidden(ids) & ~el
            return np.where(hidden | (el & (size < self.min_object_voxels)), 0, ids).astype(ids.dtype)
        return np.where(self._hidden(ids), 0, ids).astype(ids.dtype)

    def _hidden(self, ids: np.ndarray) -> np.ndarray:
        """Whether each instance id is under `min_object_voxels` voxels (or 0)."""
        if self.min_object_voxels <= 1 or not len(self.stats.size):
            return np.zeros(len(ids), bool)
        big = np.zeros(max(len(self.stats.size), int(ids.max(initial=0)) + 1), bool)
        big[: len(self.stats.size)] = self.stats.size >= self.min_object_voxels
        big[0] = False
        return ~big[ids]
