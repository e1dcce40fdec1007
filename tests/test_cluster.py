"""The clustering stage: voxels join instances where the labeller links them and geometry allows, instances
merge when they agree, small fragments join or hide; the pair table and the per-instance statistics under it,
checked against plain recounts; the stage reads what the labelling stage handed over."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.cluster import (
    Geometry,
    InstanceClusterer,
    InstanceStats,
    PairTable,
    cluster_frame,
)
from aftershock.pipeline.cluster.pairs import pack_pairs, unpack_pairs
from aftershock.pipeline.config import ClusterConfig
from aftershock.pipeline.label import label_frame
from aftershock.pipeline.types import Frame, Scan
from aftershock.pipeline.voxel_map import VoxelMap

# Every instance-level rule off (mean embeddings, absorbing, final joins, hiding, normal checks): a test turns on
# the ones it is about.
_PLAIN: dict[str, Any] = {
    "merge_beta": 2.0,
    "absorb_voxels": 1,
    "min_object_voxels": 1,
    "final_beta": 2.0,
    "plane_beta": 2.0,
    "contact_beta": 2.0,
    "normal_links": "off",
}


def _rules(**changes: Any) -> ClusterConfig:
    return ClusterConfig(**(_PLAIN | changes))


def test_clustering_links_merges_and_relabels() -> None:
    vm = VoxelMap(1.0)
    same = lambda m, a, b: np.ones(len(a), bool)  # noqa: E731 - every neighbour pair agrees
    cl = InstanceClusterer(_rules(), same)
    left, _ = vm.insert(np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]]), None, 0)
    assert cl.add(vm, left, 0) == []
    right, _ = vm.insert(np.array([[4.5, 0.5, 0.5]]), None, 1)
    assert cl.add(vm, right, 1) == []
    assert list(vm.instance_ids) == [1, 1, 2]
    # A bridge of two voxels touches both instances: they merge into the smaller id, everywhere in the map.
    bridge, _ = vm.insert(np.array([[2.5, 0.5, 0.5], [3.5, 0.5, 0.5]]), None, 2)
    merges = cl.add(vm, bridge, 2)
    assert [(m.into, m.merged, m.seq) for m in merges] == [(1, (2,), 2)]
    assert (vm.instance_ids == 1).all()
    # An isolated voxel starts a new instance; a pair that does not agree stays apart.
    apart = InstanceClusterer(_rules(), lambda m, a, b: np.zeros(len(a), bool))
    lone, _ = vm.insert(np.array([[10.5, 0.5, 0.5], [11.5, 0.5, 0.5]]), None, 3)
    vm.instance_ids[lone] = 0
    apart.next_id = cl.next_id
    apart.add(vm, lone, 3)
    assert len(set(vm.instance_ids[lone])) == 2 and 1 not in set(vm.instance_ids[lone])


def test_neighbouring_instances_merge_when_their_mean_embeddings_agree() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731 - no single voxel pair links
    cl = InstanceClusterer(_rules(merge_beta=0.9), never, embedding_dim=2)
    east, north = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    rows, _ = vm.insert(np.array([[0.5, 0.5, 0.5]]), None, 0)
    vm.embeddings[rows] = east
    cl.add(vm, rows, 0)
    # A neighbour with a different mean embedding stays apart ...
    rows, _ = vm.insert(np.array([[1.5, 0.5, 0.5]]), None, 1)
    vm.embeddings[rows] = north
    assert cl.add(vm, rows, 1) == [] and len(set(vm.instance_ids)) == 2
    # ... one that agrees joins, and so does a far voxel once a bridge of agreeing voxels reaches it.
    rows, _ = vm.insert(np.array([[0.5, 1.5, 0.5], [3.5, 0.5, 0.5]]), None, 2)
    vm.embeddings[rows] = east
    merges = cl.add(vm, rows, 2)
    assert [(m.into, m.merged) for m in merges] == [(1, (3,))]
    assert vm.instance_ids.tolist() == [1, 2, 1, 4]
    rows, _ = vm.insert(np.array([[1.5, 1.5, 0.5], [2.5, 1.5, 0.5]]), None, 3)
    vm.embeddings[rows] = east
    merges = cl.add(vm, rows, 3)
    assert vm.instance_ids.tolist() == [1, 2, 1, 1, 1, 1] and [m.into for m in merges] == [1]
    # The embedding sums follow the merges: instance 1 holds five east voxels, the north one is apart.
    np.testing.assert_allclose(cl.stats.sums[1], 5 * east)
    np.testing.assert_allclose(cl.stats.sums[2], north)


def test_a_fragment_that_stops_growing_joins_the_neighbour_it_agrees_with() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731
    # Fragments under 3 voxels, 2 scans without growth, similarity 0.7; instance merging itself kept off (no
    # mean embeddings agree more than 1).
    rules = _rules(merge_beta=1.0, absorb_voxels=3, absorb_after_scans=2, absorb_beta=0.7)
    cl = InstanceClusterer(rules, never, embedding_dim=2)
    wall = np.array([[x + 0.5, 0.5, 0.5] for x in range(4)])
    rows, _ = vm.insert(wall, None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    cl.add(vm, rows, 0)
    vm.instance_ids[rows] = 1  # one object of 4 voxels (the links above were all refused)
    cl.stats.sums[:] = 0.0
    cl.stats.sums[1] = [4.0, 0.0]
    cl.stats.size[:] = 0
    cl.stats.size[1] = 4
    close, _ = vm.insert(np.array([[0.5, 1.5, 0.5]]), None, 1)  # agrees with the wall (cos 0.8)
    vm.embeddings[close] = [0.8, 0.6]
    far, _ = vm.insert(np.array([[3.5, 1.5, 0.5]]), None, 1)  # does not (cos 0)
    vm.embeddings[far] = [0.0, 1.0]
    cl.add(vm, np.r_[close, far], 1)
    assert vm.instance_ids[close][0] not in (0, 1) and vm.instance_ids[far][0] not in (0, 1)
    assert cl.add(vm, np.zeros(0, np.int64), 2) == []  # not stale yet (grew at scan 1)
    elsewhere, _ = vm.insert(np.array([[10.5, 10.5, 10.5]]), None, 3)
    vm.embeddings[elsewhere] = [1.0, 0.0]
    fragment = int(vm.instance_ids[close][0])
    merges = cl.add(vm, elsewhere, 3)  # two scans without growth: the close fragment joins the wall
    assert [(m.into, m.merged) for m in merges] == [(1, (fragment,))]
    assert vm.instance_ids[close][0] == 1 and vm.instance_ids[far][0] not in (0, 1)
    assert cl.stats.size[1] == 5


def _wall_voxels(axis: int, at: float, extent: tuple[float, float], height: float = 2.0) -> np.ndarray:
    """Centres of 0.1 m voxels of a vertical wall: x = at (axis 0) or y = at (axis 1), along the other axis."""
    along = np.arange(extent[0], extent[1], 0.1) + 0.05
    up = np.arange(0.0, height, 0.1) + 0.05
    u, z = np.meshgrid(along, up, indexing="ij")
    fixed = np.full(u.size, at + 0.05)
    xy = (fixed, u.ravel()) if axis == 0 else (u.ravel(), fixed)
    return np.c_[xy[0], xy[1], z.ravel()]


@pytest.mark.parametrize("geometry", [True, False])
def test_a_wall_does_not_grow_round_a_corner_into_the_next_wall(geometry: bool) -> None:
    """Every voxel pair agrees (the embeddings cannot tell the walls apart), yet the second wall stays its own
    object: once the first wall is known to be planar, voxels off its plane do not join it, and the two planar
    instances never merge (their normals are at 90°). Without the geometric test they become one."""
    vm = VoxelMap(0.1, embedding_dim=2)
    same = lambda m, a, b: np.ones(len(a), bool)  # noqa: E731
    shape = {} if geometry else {"plane_min_voxels": 10**9}
    cl = InstanceClusterer(_rules(merge_beta=0.9, min_object_voxels=10, final_beta=0.7, **shape), same, 2)
    first = _wall_voxels(1, 0.0, (0.0, 3.0))  # y = 0, x from 0 to 3 m
    rows, _ = vm.insert(first, None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    vm.class_ids[rows] = SemanticClass.WALL
    cl.add(vm, rows, 0)
    assert len(set(vm.instance_ids[rows])) == 1
    second = _wall_voxels(0, 3.0, (0.1, 3.0))  # x = 3, meets the first wall's end
    rows2, _ = vm.insert(second, None, 1)
    vm.embeddings[rows2] = [1.0, 0.0]
    vm.class_ids[rows2] = SemanticClass.WALL
    cl.add(vm, rows2, 1)
    cl.finish(vm, 1)
    a, b = vm.instance_ids[rows], vm.instance_ids[rows2]
    if not geometry:
        assert (b == a[0]).all()
        return
    # The second wall is one object of its own; only its voxels within plane_offset_m (0.2 m) of the first
    # wall's plane -- its first two columns, at 0.1 and 0.2 m -- may join the first wall at the corner.
    values, counts = np.unique(b, return_counts=True)
    assert len(set(a)) == 1 and values[counts.argmax()] != a[0] and counts.max() >= 0.95 * len(b)
    assert (b == a[0]).sum() <= 40


def test_coplanar_pieces_merge_and_small_fragments_are_hidden() -> None:
    """Two pieces of one wall that grew apart merge when their mean embeddings agree; at the end of the run a
    small fragment joins the wall it agrees with, and an isolated one under the minimum size reads as 0."""
    vm = VoxelMap(0.1, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731 - no voxel links: only instance-level rules
    cl = InstanceClusterer(_rules(merge_beta=0.9, min_object_voxels=20, final_beta=0.7), never, 2)
    wall = _wall_voxels(1, 0.0, (0.0, 2.0))
    rows, _ = vm.insert(wall, None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    vm.class_ids[rows] = SemanticClass.WALL
    # Without links every voxel starts alone; instance merging then joins neighbours that agree.
    merges = cl.add(vm, rows, 0)
    assert merges and len(np.unique(vm.instance_ids[rows])) < len(rows)
    merges = cl.finish(vm, 0)
    assert len(np.unique(vm.instance_ids[rows])) == 1
    lone, _ = vm.insert(np.array([[10.05, 10.05, 10.05]]), None, 1)
    vm.embeddings[lone] = [1.0, 0.0]
    cl.add(vm, lone, 1)
    cl.finish(vm, 1)
    shown = cl.shown_ids(vm.instance_ids)
    assert shown[lone][0] == 0 and (shown[rows] == vm.instance_ids[rows]).all() and shown[rows][0] > 0


@pytest.mark.parametrize("normal_links", ["off", "strict"])
def test_two_walls_seen_at_once_split_at_the_corner_by_their_normals(normal_links: str) -> None:
    """Both walls arrive in one scan, so no plane is known yet: only the voxels' own surface normals can
    keep the corner from joining them (with the check off they are one object)."""
    vm = VoxelMap(0.1, embedding_dim=2)
    same = lambda m, a, b: np.ones(len(a), bool)  # noqa: E731
    rules = _rules(merge_beta=0.9, normal_links=normal_links, min_object_voxels=10, final_beta=0.7)
    cl = InstanceClusterer(rules, same, embedding_dim=2)
    rows, _ = vm.insert(np.r_[_wall_voxels(1, 0.0, (0.0, 3.0)), _wall_voxels(0, 3.0, (0.1, 3.0))], None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    vm.class_ids[rows] = SemanticClass.WALL
    cl.add(vm, rows, 0)
    cl.finish(vm, 0)
    a, b = vm.instance_ids[rows[:600]], vm.instance_ids[rows[600:]]
    if normal_links == "off":
        assert len(set(a) | set(b)) == 1
    else:
        values, counts = np.unique(b, return_counts=True)
        assert len(set(a)) == 1 and values[counts.argmax()] != a[0] and counts.max() >= 0.9 * len(b)


def test_the_pair_table_counts_contacts_and_links_and_folds_renamed_pairs() -> None:
    rng = np.random.default_rng(3)
    table = PairTable()
    counts: dict[tuple[int, int], list[int]] = {}
    for _ in range(5):
        ia, ib = rng.integers(1, 12, 200), rng.integers(1, 12, 200)
        linked = rng.random(200) < 0.3
        apart = ia != ib
        table.add(ia[apart], ib[apart], linked[apart])
        for a, b, link in zip(ia[apart], ib[apart], linked[apart], strict=True):
            c = counts.setdefault((min(a, b), max(a, b)), [0, 0])
            c[0] += 1
            c[1] += int(link)
    lo, hi = table.pairs()
    assert (np.diff(table.keys) > 0).all()  # sorted, unique
    assert {
        (int(a), int(b)): [int(c), int(k)] for a, b, c, k in zip(lo, hi, table.contacts, table.links, strict=True)
    } == counts
    # 3 becomes 2: their pairs with a third instance add up, the pair between them goes.
    lut = np.arange(12)
    lut[3] = 2
    table.rename(lut)
    lo, hi = table.pairs()
    assert not ((lo == 3) | (hi == 3)).any() and not ((lo == 2) & (hi == 2)).any()
    both = counts.get((2, 5), [0, 0])[0] + counts.get((3, 5), [0, 0])[0]
    assert table.contacts[(lo == 2) & (hi == 5)].tolist() == ([both] if both else [])
    lo, hi = unpack_pairs(pack_pairs(np.array([7]), np.array([4])))
    assert (lo.tolist(), hi.tolist()) == ([4], [7])


def test_instance_stats_follow_growth_and_merges_and_know_a_wall_by_its_plane() -> None:
    vm = VoxelMap(0.1, embedding_dim=2)
    wall = _wall_voxels(1, 0.0, (0.0, 2.0))  # the plane y = 0.05
    rows, _ = vm.insert(np.r_[wall, [[5.05, 5.05, 0.05], [5.15, 5.05, 0.05]]], None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    vm.class_ids[rows] = SemanticClass.WALL
    vm.instance_ids[rows[: len(wall)]] = 1
    vm.instance_ids[rows[len(wall) :]] = 2
    stats = InstanceStats(Geometry())
    stats.grow(vm, rows, seq=4, next_id=3)
    assert stats.size[1:3].tolist() == [len(wall), 2] and stats.last_grown[1:3].tolist() == [4, 4]
    np.testing.assert_allclose(stats.psum[1], wall.sum(axis=0))
    planar, normal, centroid = stats.planes(np.array([1, 2]))
    assert planar.tolist() == [True, False]  # two voxels: too few to have a shape
    assert abs(normal[0, 1]) > 0.999 and abs(centroid[0, 1] - 0.05) < 1e-9
    assert stats.on_plane(np.array([1, 1]), np.array([[1.0, 0.1, 1.0], [1.0, 0.5, 1.0]])).tolist() == [True, False]
    stats.merge(np.array([2]), np.array([1]))
    assert stats.size[1:3].tolist() == [len(wall) + 2, 0] and stats.sums[2].tolist() == [0.0, 0.0]
    np.testing.assert_allclose(stats.sums[1], [len(wall) + 2, 0.0])
    assert not stats.plane_known[1]  # the merge changed it: its plane is fitted again when asked


def test_the_clusterer_takes_its_rules_from_its_config_section() -> None:
    cfg = ClusterConfig()
    with_embeddings = InstanceClusterer(cfg, lambda m, a, b: a == b, embedding_dim=8)
    assert with_embeddings.merge_beta == cfg.merge_beta and with_embeddings.final_beta == cfg.final_beta
    assert with_embeddings.absorb == (cfg.absorb_voxels, cfg.absorb_after_scans, cfg.absorb_beta)
    assert with_embeddings.geometry == Geometry.from_config(cfg) and with_embeddings.min_object_voxels == 50
    # Without embeddings, the rules on mean embeddings are off; a merge_beta over 1 turns them off too.
    for clusterer in (
        InstanceClusterer(cfg, lambda m, a, b: a == b, embedding_dim=0),
        InstanceClusterer(ClusterConfig(merge_beta=1.5, final_beta=1.5), lambda m, a, b: a == b, 8),
    ):
        assert clusterer.merge_beta is None and clusterer.final_beta is None and clusterer.absorb is None


class _EveryNeighbour:
    """A labeller that calls every voxel clutter and links every neighbouring pair."""

    name = "every-neighbour"
    embedding_dim = 0

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> None:
        vmap.class_ids[new_rows] = SemanticClass.CLUTTER

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        return np.ones(len(rows_a), bool)

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        return None


def test_the_stage_clusters_the_rows_the_labelling_stage_opened_and_labels_the_kept_points() -> None:
    vm = VoxelMap(0.1)
    cl = InstanceClusterer(_rules(), _EveryNeighbour().affinity)
    near = _wall_voxels(1, 0.0, (0.0, 1.0), height=0.5)  # 50 voxels, one point each, all within range
    far = np.array([[30.0, 0.0, 0.0]])  # outside the labelling range: not kept
    pts = np.r_[near, near + 0.01, far]  # the second copy falls in the same voxels
    frame = Frame(Scan(0, pts, seq=0), pose=np.eye(4), world_points=pts)
    label_frame(frame, vm, _EveryNeighbour(), range_m=10.0)
    rows = frame.map_rows
    assert rows is not None and rows.points.tolist() == list(range(2 * len(near)))
    assert rows.new_rows.tolist() == list(range(len(near))) and rows.first_points.tolist() == list(range(len(near)))
    assert (rows.rows == np.r_[np.arange(len(near)), np.arange(len(near))]).all()
    cluster_frame(frame, vm, cl)
    assert frame.labels is not None and (vm.instance_ids == 1).all()  # one linked group: one instance
    assert (frame.labels.instance_ids[: 2 * len(near)] == 1).all() and frame.labels.instance_ids[-1] == 0
    # The same points again open nothing: nothing is clustered, the points keep their instance.
    again = Frame(Scan(1, pts, seq=1), pose=np.eye(4), world_points=pts)
    label_frame(again, vm, _EveryNeighbour(), range_m=10.0)
    cluster_frame(again, vm, cl)
    assert again.map_rows is not None and len(again.map_rows.new_rows) == 0 and "merges" not in again.counts
    assert again.labels is not None and (again.labels.instance_ids[:-1] == 1).all() and cl.next_id == 2


class _Owner:
    """A structure model's `object_keys` stand-in: the element key of each map row, as a test sets it."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)

    def __call__(self, n: int) -> np.ndarray:
        out = np.full(n, -1, np.int64)
        out[: min(n, len(self.keys))] = self.keys[:n]
        return out


def _floor_voxels(x: tuple[int, int]) -> np.ndarray:
    return np.array([[i + 0.5, j + 0.5, 0.5] for i in range(*x) for j in range(3)])


def test_voxels_on_one_element_show_one_object_whatever_their_embeddings_say_and_the_map_takes_it() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731 - the embeddings link nothing
    cl = InstanceClusterer(_rules(), never, embedding_dim=2)
    owner = _Owner()
    cl.owner = owner
    rows, _ = vm.insert(np.r_[_floor_voxels((0, 4)), [[10.5, 10.5, 0.5]]], None, 0)
    vm.embeddings[rows] = np.where(np.arange(len(rows))[:, None] % 2, [1.0, 0.0], [0.0, 1.0])
    owner.keys = np.r_[np.full(len(rows) - 1, 7), -1]  # every floor voxel on element 7; the far one on none
    cl.add(vm, rows, 0)
    clustered = vm.instance_ids[rows].copy()
    assert len(set(clustered.tolist())) == len(rows)  # the clustering itself is left as it was ...
    shown = cl.shown_ids(vm.instance_ids[rows], rows)
    floor = shown[:-1]
    assert len(set(floor.tolist())) == 1 and shown[-1] == clustered[-1] != floor[0]  # ... the floor shows one
    # Voxels seen later on the same element show the same object.
    more, _ = vm.insert(_floor_voxels((4, 6)), None, 1)
    vm.embeddings[more] = [0.0, 1.0]
    owner.keys = np.r_[owner.keys, np.full(len(more), 7)]
    cl.add(vm, more, 1)
    assert (cl.shown_ids(vm.instance_ids[more], more) == floor[0]).all()
    # At the end the map itself takes the element objects, and the per-instance sums follow the moved voxels.
    cl.claim(vm, 2)
    assert (vm.instance_ids[np.r_[rows[:-1], more]] == floor[0]).all() and vm.instance_ids[rows[-1]] == clustered[-1]
    assert cl.stats.size[floor[0]] == len(rows) - 1 + len(more) and cl.stats.size.sum() == len(vm)
    assert cl.is_owned(floor[:1]).all() and not cl.is_owned(clustered[-1:]).any()


def test_an_elements_object_keeps_its_id_when_the_element_is_refitted_under_a_new_id() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731
    cl = InstanceClusterer(_rules(), never, embedding_dim=2)
    owner = _Owner()
    cl.owner = owner
    rows, _ = vm.insert(_floor_voxels((0, 4)), None, 0)
    owner.keys = np.full(len(rows), 3)
    cl.add(vm, rows, 0)
    first = int(cl.shown_ids(vm.instance_ids[rows[:1]], rows[:1])[0])
    # The slab is refitted: element 3 is gone, element 9 holds most of its voxels (and new ones).
    more, _ = vm.insert(_floor_voxels((4, 5)), None, 1)
    owner.keys = np.r_[np.full(len(rows) - 2, 9), -1, -1, np.full(len(more), 9)]
    cl.add(vm, more, 1)
    every = np.arange(len(vm))
    assert (cl.shown_ids(vm.instance_ids[every], every)[owner.keys == 9] == first).all()
    # A second element that appears beside it is an object of its own.
    other, _ = vm.insert(_floor_voxels((20, 22)), None, 2)
    owner.keys = np.r_[owner.keys, np.full(len(other), 11)]
    cl.add(vm, other, 2)
    shown = cl.shown_ids(vm.instance_ids[other], other)
    assert len(set(shown.tolist())) == 1 and shown[0] != first
    cl.claim(vm, 3)  # and the map keeps the ids the run showed
    assert (vm.instance_ids[owner.keys == 9] == first).all() and (vm.instance_ids[other] == shown[0]).all()


def test_two_elements_objects_never_merge_even_where_their_embeddings_agree() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731
    cl = InstanceClusterer(_rules(merge_beta=0.5), never, embedding_dim=2)
    owner = _Owner()
    cl.owner = owner
    rows, _ = vm.insert(np.r_[_floor_voxels((0, 3)), _floor_voxels((3, 6))], None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    owner.keys = np.r_[np.full(9, 1), np.full(9, 2)]  # two columns side by side, say
    cl.add(vm, rows, 0)
    cl.claim(vm, 0)
    cl.finish(vm, 0)
    a, b = vm.instance_ids[rows[0]], vm.instance_ids[rows[-1]]
    assert a != b and (vm.instance_ids[rows[:9]] == a).all() and (vm.instance_ids[rows[9:]] == b).all()
    # A voxel off both elements that agrees with them still joins one of them.
    loose, _ = vm.insert(np.array([[2.5, 3.5, 0.5]]), None, 1)
    vm.embeddings[loose] = [1.0, 0.0]
    owner.keys = np.r_[owner.keys, -1]
    cl.add(vm, loose, 1)
    cl.finish(vm, 1)
    assert vm.instance_ids[loose[0]] in (a, b) and vm.instance_ids[rows[0]] != vm.instance_ids[rows[-1]]
