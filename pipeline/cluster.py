"""Clustering stage: incremental instance clustering over the voxel map, objects rather than fragments.

Two levels, so that every decision to join two *instances* passes one place that sees their geometry:

1. Voxels. Each new voxel links to its neighbouring voxels (new ones of the same scan, and older ones that
   already carry an instance) where the labeller's affinity says they agree (for MCPNet: cosine similarity
   of the embeddings above β) and, with `normal_links`, where their local surface normals do not say that
   two surfaces meet (so two walls seen in one scan split at their corner). A group of linked new voxels
   joins the older instance it has most links to -- but a voxel only joins a *planar* instance (a wall, a
   floor) when it lies on that instance's plane, so a wall cannot grow round a corner into the next wall.
   New voxels that reach no older instance form new instances (connected components). A scan's voxels
   never merge two older instances here.
2. Instances. Every pair of instances that touch is kept with its number of touching voxel pairs and of
   linked ones. Pairs merge when a voxel link joins them or their mean embeddings agree (`merge_beta`;
   two pieces of one plane: `plane_beta`) *and* their geometry agrees: two planar instances only when
   their normals are parallel and they lie in one plane (`Geometry`). This runs after every scan on the
   pairs the scan touched, and over the whole map at the end of the run (`finish`), which also lets every
   fragment under `min_object_voxels` join the touching instance it agrees with most (`final_beta`).

With `absorb`, a small fragment that has stopped growing (an object still being scanned keeps growing)
joins the neighbouring instance it agrees with most, at a lower similarity. Objects under
`min_object_voxels` are not shown (`shown_ids`): they stay in the map, as "no object", until they grow.
Merges are recorded on the frame as `InstanceMerge`s (and returned by `finish`), so the sinks can show them.
Every setting was chosen on validation missions (README, "Objects, not fragments").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from time import perf_counter
from typing import Final

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aftershock.pipeline.classes import NUM_CLASSES, SemanticClass
from aftershock.pipeline.config import ClusterConfig
from aftershock.pipeline.geometry import group_pca
from aftershock.pipeline.types import Frame, InstanceMerge
from aftershock.pipeline.voxel_map import VoxelMap

Affinity = Callable[[VoxelMap, np.ndarray, np.ndarray], np.ndarray]

_PAIR_SHIFT: Final = np.int64(32)
_MAX_FINAL_ROUNDS: Final = 50
_FLAT_CURVATURE: Final = 0.05  # λ0 / (λ0 + λ1 + λ2) of a voxel's neighbourhood at most this: a flat surface
_PLANE_CLASSES: Final = np.isin(
    np.arange(NUM_CLASSES), [SemanticClass.CEILING, SemanticClass.FLOOR, SemanticClass.WALL]
)


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
        return cls(
            cfg.plane_min_voxels,
            cfg.plane_thickness,
            cfg.plane_min_spread_m,
            cfg.plane_angle_deg,
            cfg.plane_offset_m,
            cfg.plane_wide_m,
        )


def _pack_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return (lo << _PAIR_SHIFT) | hi


def _pack_ordered(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (np.asarray(a, np.int64) << _PAIR_SHIFT) | np.asarray(b, np.int64)


def _unpack_pairs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return keys >> _PAIR_SHIFT, keys & ((np.int64(1) << _PAIR_SHIFT) - 1)


class InstanceClusterer:
    def __init__(
        self,
        affinity: Affinity,
        reach_voxels: int = 1,
        merge_beta: float | None = None,
        absorb: tuple[int, int, float] | None = None,
        geometry: Geometry | None = None,
        merge_same_class: bool = False,
        min_contacts: int = 1,
        min_object_voxels: int = 1,
        final_beta: float | None = None,
        min_links: int = 1,
        plane_beta: float = 2.0,
        normal_links: str = "off",
        contact_beta: float = 2.0,
        contact_ratio: float = 2.0,
    ) -> None:
        self.affinity = affinity
        self.reach = reach_voxels
        self.merge_beta = merge_beta
        self.absorb = absorb  # (fewest voxels, scans without growth, similarity): see `_absorb_stale`
        self.geometry = geometry or Geometry()
        self.same_class = merge_same_class
        self.min_contacts = min_contacts
        self.normal_links = normal_links  # "off" | "agree" | "strict": see `_normals_agree`
        self.contact_beta, self.contact_ratio = contact_beta, contact_ratio
        self.plane_beta = plane_beta  # mean-embedding similarity enough for two pieces of one plane
        self.min_links = max(min_links, 1) if min_links > 0 else np.iinfo(np.int64).max  # 0 = never by links
        self.min_object_voxels = min_object_voxels
        self.final_beta = final_beta  # fragments under min_object_voxels join a neighbour this similar at the end
        self.next_id = 1  # 0 means "no object"
        self.size = np.zeros(0, np.int64)  # voxels per instance id
        self.last_grown = np.zeros(0, np.int64)  # scan in which each instance last gained a voxel
        self.sums = np.zeros((0, 0), np.float64)  # per instance id: sum of its voxels' embeddings
        self.psum = np.zeros((0, 3), np.float64)  # ... of their positions
        self.pp = np.zeros((0, 6), np.float64)  # ... of xx, xy, xz, yy, yz, zz
        self.votes = np.zeros((0, NUM_CLASSES), np.int64)  # ... of the classes the labeller first gave them
        self.pair_keys = np.zeros(0, np.int64)  # touching instance pairs (lo << 32 | hi), sorted
        self.pair_contacts = np.zeros(0, np.int64)  # neighbouring voxel pairs between them
        self.pair_links = np.zeros(0, np.int64)  # ... of which the labeller linked
        self.plane_known = np.zeros(0, bool)  # per instance id: the cached plane below is current
        self.plane_planar = np.zeros(0, bool)
        self.plane_normal = np.zeros((0, 3))
        self.plane_centroid = np.zeros((0, 3))

    @classmethod
    def from_config(cls, cfg: ClusterConfig, affinity: Affinity, embedding_dim: int) -> InstanceClusterer:
        """The clusterer of `cfg` for a labeller with this affinity and embedding width (0 = none)."""
        merge_beta = cfg.merge_beta if embedding_dim and cfg.merge_beta <= 1 else None
        absorb = None
        if merge_beta is not None and cfg.absorb_voxels > 1:
            absorb = (cfg.absorb_voxels, cfg.absorb_after_scans, cfg.absorb_beta)
        return cls(
            affinity,
            cfg.link_reach_voxels,
            merge_beta,
            absorb,
            Geometry.from_config(cfg),
            cfg.merge_same_class,
            cfg.merge_min_contacts,
            cfg.min_object_voxels,
            cfg.final_beta if embedding_dim and cfg.final_beta <= 1 else None,
            cfg.merge_links,
            cfg.plane_beta,
            cfg.normal_links,
            cfg.contact_beta,
            cfg.contact_ratio,
        )

    # ------------------------------------------------------------------------------------------ per scan

    def add(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int) -> list[InstanceMerge]:
        """Give the new rows instance ids and merge the instances that now agree; returns the merges."""
        new_rows = np.asarray(new_rows, dtype=np.int64)
        k = len(new_rows)
        merges: list[InstanceMerge] = []
        if k:
            contact_a, contact_b, linked = self._assign(vmap, new_rows)
            self._grow_stats(vmap, new_rows, seq)
            touched = self._add_pairs(vmap, contact_a, contact_b, linked)
            merges += self._merge_pairs(vmap, seq, touched)
        if self.absorb is not None and self.next_id > 1:
            merges += self._absorb_stale(vmap, seq)
        return merges

    def _assign(self, vmap: VoxelMap, new_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Instance ids of the new rows (see the module docstring); returns every neighbouring voxel pair
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
            self._reserve()
            fits = self._on_plane(did, pos_new[da])
            da, did = da[fits], did[fits]
        if len(da):
            keys, count = np.unique(_pack_ordered(group[da], did), return_counts=True)
            g, inst = _unpack_pairs(keys)
            order = np.lexsort((-count, g))
            first = order[np.r_[True, g[order][1:] != g[order][:-1]]]
            chosen = np.zeros(group.max() + 1, np.int64)
            chosen[g[first]] = inst[first]
            cand = chosen[group]
            has = np.flatnonzero(cand > 0)
            on = self._on_plane(cand[has], pos_new[has])
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

    def _reserve(self) -> None:
        """Room in the per-instance arrays for every id handed out so far."""
        if len(self.size) >= self.next_id:
            return
        n = max(self.next_id, 2 * len(self.size), 1024)

        def grow(arr: np.ndarray, fill: float = 0) -> np.ndarray:
            out = np.full((n, *arr.shape[1:]), fill, arr.dtype)
            out[: len(arr)] = arr
            return out

        self.size, self.last_grown = grow(self.size), grow(self.last_grown, -1)
        self.psum, self.pp, self.votes = grow(self.psum), grow(self.pp), grow(self.votes)
        if self.sums.shape[1]:
            self.sums = grow(self.sums)

    def _grow_stats(self, vmap: VoxelMap, new_rows: np.ndarray, seq: int) -> None:
        if self.sums.shape[1] != vmap.embeddings.shape[1]:
            self.sums = np.zeros((len(self.size), vmap.embeddings.shape[1]))
        self._reserve()
        ids = vmap.instance_ids[new_rows].astype(np.int64)
        n = len(self.size)
        self.size += np.bincount(ids, minlength=n)[:n]
        grown = np.unique(ids)
        self.last_grown[grown] = seq
        self.plane_known[grown[grown < len(self.plane_known)]] = False
        p = vmap.positions[new_rows]
        for j in range(3):
            self.psum[:, j] += np.bincount(ids, weights=p[:, j], minlength=n)[:n]
        for j, (c0, c1) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            self.pp[:, j] += np.bincount(ids, weights=p[:, c0] * p[:, c1], minlength=n)[:n]
        cls = vmap.class_ids[new_rows].astype(np.int64)
        known = cls < NUM_CLASSES
        np.add.at(self.votes, (ids[known], cls[known]), 1)
        if self.sums.shape[1]:
            np.add.at(self.sums, ids, vmap.embeddings[new_rows])

    # ------------------------------------------------------------------------------------------ geometry

    def _planes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        for j, (c0, c1) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
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

    def _on_plane(self, ids: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Per (instance, point): the instance is not planar, or the point lies on its plane."""
        if not len(ids):
            return np.zeros(0, bool)
        uniq, inv = np.unique(ids, return_inverse=True)
        planar, normal, centroid = self._planes(uniq)
        inv = inv.ravel()
        dist = np.abs(np.einsum("ij,ij->i", points - centroid[inv], normal[inv]))
        return ~planar[inv] | (dist <= self.geometry.plane_offset_m)

    def _compatible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Pairs of instances whose geometry (and, if asked, majority class) allows them to be one object."""
        return self._geometry(a, b)[0]

    def _geometry(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(compatible, one plane): pairs that may be one object, and pairs of planar pieces of one plane."""
        pa, na, ca = self._planes(a)
        pb, nb, cb = self._planes(b)
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

    def _similarity(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Cosine similarity of the mean embeddings of instances a and b (pairwise)."""
        sa, sb = self.sums[a], self.sums[b]
        na = np.maximum(np.linalg.norm(sa, axis=1), 1e-12)
        nb = np.maximum(np.linalg.norm(sb, axis=1), 1e-12)
        return np.einsum("ij,ij->i", sa, sb) / (na * nb)

    # ------------------------------------------------------------------------------------------- pairs

    def _add_pairs(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray, linked: np.ndarray) -> np.ndarray:
        """Count the touching voxel pairs between instances; returns the instances this scan touched."""
        ia = vmap.instance_ids[rows_a].astype(np.int64)
        ib = vmap.instance_ids[rows_b].astype(np.int64)
        apart = (ia != ib) & (ia > 0) & (ib > 0)
        keys = _pack_pairs(ia[apart], ib[apart])
        self._store_pairs(
            np.r_[self.pair_keys, keys],
            np.r_[self.pair_contacts, np.ones(len(keys), np.int64)],
            np.r_[self.pair_links, linked[apart].astype(np.int64)],
        )
        return np.unique(np.r_[ia, ib])

    def _store_pairs(self, keys: np.ndarray, contacts: np.ndarray, links: np.ndarray) -> None:
        lo, hi = _unpack_pairs(keys)
        keep = lo != hi
        uniq, inv = np.unique(keys[keep], return_inverse=True)
        self.pair_keys = uniq
        self.pair_contacts = np.bincount(inv.ravel(), weights=contacts[keep], minlength=len(uniq)).astype(np.int64)
        self.pair_links = np.bincount(inv.ravel(), weights=links[keep], minlength=len(uniq)).astype(np.int64)

    def _merge_pairs(self, vmap: VoxelMap, seq: int, touched: np.ndarray | None = None) -> list[InstanceMerge]:
        """One round of instance merging over the touching pairs (those of `touched` instances only, if given)."""
        if not len(self.pair_keys):
            return []
        a, b = _unpack_pairs(self.pair_keys)
        sel = np.ones(len(a), bool) if touched is None else np.isin(a, touched) | np.isin(b, touched)
        sel &= self.pair_contacts >= self.min_contacts
        a, b, links, contacts = a[sel], b[sel], self.pair_links[sel], self.pair_contacts[sel]
        # Linked voxel pairs (the study's bridging) or, with embeddings, agreeing mean embeddings; two pieces
        # of one plane need less agreement (their geometry already says they may be one surface).
        agree = links >= self.min_links
        if self.merge_beta is not None:
            sim = self._similarity(a, b)
            agree |= sim > self.merge_beta
            # A long shared boundary (many touching voxel pairs for the smaller piece's size) is evidence too.
            wrapped = contacts >= self.contact_ratio * np.minimum(self.size[a], self.size[b])
            agree |= wrapped & (sim > self.contact_beta)
            maybe = ~agree & (sim > self.plane_beta)  # pieces of one plane: decided below, with the geometry
        else:
            maybe = np.zeros(len(a), bool)
        cand = agree | maybe  # the geometry only for pairs that could merge (most touching pairs cannot)
        a, b, agree, maybe = a[cand], b[cand], agree[cand], maybe[cand]
        ok, one_plane = self._geometry(a, b)
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
        planar, _, _ = self._planes(nodes)
        # The largest planar member of each group (or its largest member) anchors it.
        weight = self.size[nodes] + planar * (1 << 40)
        order = np.lexsort((-weight, comp))
        first = order[np.r_[True, comp[order][1:] != comp[order][:-1]]]
        anchor = np.zeros(comp.max() + 1, np.int64)
        anchor[comp[first]] = nodes[first]
        fits = self._compatible(anchor[comp], nodes) | (anchor[comp] == nodes)
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
        self._reserve()
        lut = np.arange(self.next_id, dtype=np.int64)
        lut[gone] = into
        ids = vmap.instance_ids
        ids[:] = lut[ids]
        for arr in (self.size, self.psum, self.pp, self.votes, self.sums):
            if arr.ndim == 1 or arr.shape[1]:
                np.add.at(arr, into, arr[gone])
                arr[gone] = 0
        np.maximum.at(self.last_grown, into, self.last_grown[gone])
        changed = np.r_[gone, into]
        self.plane_known[changed[changed < len(self.plane_known)]] = False
        if len(self.pair_keys):
            lo, hi = _unpack_pairs(self.pair_keys)
            self._store_pairs(_pack_pairs(lut[lo], lut[hi]), self.pair_contacts, self.pair_links)
        return [
            InstanceMerge(int(target), tuple(int(g) for g in gone[into == target]), seq) for target in np.unique(into)
        ]

    def _best_neighbour(self, small: np.ndarray, beta: float) -> tuple[np.ndarray, np.ndarray]:
        """For fragments `small`: the larger touching instance whose mean embedding agrees most (at `beta` or
        more) and whose geometry allows it (larger only, so fragments never join each other in a cycle);
        returns (fragments, targets)."""
        a, b = _unpack_pairs(self.pair_keys)
        frag = np.r_[a, b]
        other = np.r_[b, a]
        ok = np.isin(frag, small) & (self.size[other] > self.size[frag])
        frag, other = frag[ok], other[ok]
        if not len(frag):
            return frag, other
        sim = self._similarity(frag, other)
        good = (sim >= beta) & self._compatible(frag, other)
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
        ids = np.arange(len(self.size))
        stale = ids[(self.size > 0) & (self.size < min_voxels) & (self.last_grown == seq - wait)]
        if not len(stale) or not len(self.pair_keys):
            return []
        frag, into = self._best_neighbour(stale, beta)
        big = self.size[into] >= min_voxels
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
        if self.final_beta is not None and self.min_object_voxels > 1 and len(self.pair_keys):
            for _ in range(_MAX_FINAL_ROUNDS):
                small = np.flatnonzero((self.size > 0) & (self.size < self.min_object_voxels))
                frag, into = self._best_neighbour(small, self.final_beta)
                step = self._merge_chain(vmap, frag, into, seq)
                if not step:
                    break
                merges += step
        return merges

    def shown_ids(self, instance_ids: np.ndarray) -> np.ndarray:
        """Instance ids as the user sees them: objects under `min_object_voxels` voxels read as 0 (no object)."""
        ids = np.asarray(instance_ids)
        if self.min_object_voxels <= 1 or not len(self.size):
            return ids
        big = np.zeros(max(len(self.size), int(ids.max(initial=0)) + 1), bool)
        big[: len(self.size)] = self.size >= self.min_object_voxels
        big[0] = False
        return np.where(big[ids], ids, 0).astype(ids.dtype)


def cluster_frame(frame: Frame, vmap: VoxelMap, clusterer: InstanceClusterer) -> Frame:
    if frame.new_voxel_points is not None and len(frame.new_voxel_points):
        new_rows = vmap.lookup_points(frame.world_points[frame.new_voxel_points])
        merges = clusterer.add(vmap, new_rows, frame.seq)
        frame.merges.extend(merges)
        frame.counts["merges"] = len(merges)
    if frame.labels is not None and frame.keep is not None and frame.keep.any():
        idx = np.flatnonzero(frame.keep)
        rows = frame.kept_rows if frame.kept_rows is not None else vmap.lookup_points(frame.world_points[idx])
        ids = vmap.instance_ids[rows]
        frame.labels.instance_ids[idx] = clusterer.shown_ids(ids)
    frame.counts["instances_opened"] = clusterer.next_id - 1
    return frame


def cluster_stage(frames: Iterable[Frame], vmap: VoxelMap, clusterer: InstanceClusterer) -> Iterator[Frame]:
    for frame in frames:
        t0 = perf_counter()
        cluster_frame(frame, vmap, clusterer)
        frame.timings_ms["cluster"] = (perf_counter() - t0) * 1e3
        yield frame
