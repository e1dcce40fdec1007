"""The voxel map: first point per voxel, new work only for new voxels, neighbourhoods and MCPNet context,
checked against plain Python sets and brute force on small random clouds; clustering merges on it."""

from __future__ import annotations

import numpy as np
import pytest

from aftershock.pipeline.classes import UNLABELLED, SemanticClass
from aftershock.pipeline.cluster import Geometry, InstanceClusterer
from aftershock.pipeline.voxel_map import KeyTable, VoxelMap, pack_keys, unpack_keys


def test_key_table_finds_what_it_holds_through_growth() -> None:
    rng = np.random.default_rng(0)
    table = KeyTable(16)
    keys = rng.choice(10**12, 50_000, replace=False)
    for part in np.array_split(np.arange(len(keys)), 7):  # several growths on the way
        table.insert(keys[part], part)
    assert (table.find(keys) == np.arange(len(keys))).all()
    assert (table.find(keys + 10**12) == -1).all()
    assert table.size == len(keys) and table.capacity >= 2 * len(keys)


def test_pack_round_trip_with_negative_coordinates() -> None:
    coords = np.array([[0, 0, 0], [-1, -2, -3], [1000, -99999, 524287], [-524288, 7, 0]])
    assert (unpack_keys(pack_keys(coords)) == coords).all()


def test_insert_keeps_the_first_point_of_each_voxel() -> None:
    vm = VoxelMap(0.1)
    pts = np.array([[0.01, 0.01, 0.01], [0.05, 0.05, 0.05], [0.15, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    colors = np.array([[1, 1, 1], [2, 2, 2], [3, 3, 3], [4, 4, 4]], np.uint8)
    new, rows = vm.insert(pts, colors, seq=7, true_class_ids=np.array([1, 2, 3, 4], np.uint16))
    assert list(new) == [0, 1, 2] and list(rows) == [0, 0, 1, 2]
    assert np.allclose(vm.positions[0], pts[0]) and list(vm.colors[0]) == [1, 1, 1]
    assert list(vm.true_class_ids) == [1, 3, 4] and vm.has_truth
    assert (vm.first_seq == 7).all() and (vm.class_ids == UNLABELLED).all() and (vm.instance_ids == 0).all()
    # A later scan over the same voxels opens nothing; a new voxel is new work.
    new2, rows2 = vm.insert(np.array([[0.02, 0.02, 0.02], [0.35, 0.0, 0.0]]), None, seq=8)
    assert list(new2) == [3] and list(rows2) == [0, 3]
    assert np.allclose(vm.positions[0], pts[0]) and vm.first_seq[3] == 8


def test_many_scans_match_a_python_set_and_memory_follows_the_site() -> None:
    rng = np.random.default_rng(1)
    vm = VoxelMap(0.1)
    seen: set[tuple[int, int, int]] = set()
    site = rng.uniform(-3, 3, (20_000, 3))
    for seq in range(30):
        pts = site[rng.integers(0, len(site), 3000)] + rng.normal(0, 0.005, (3000, 3))
        keys = [tuple(k) for k in np.floor(pts / 0.1).astype(int)]
        expect_new = len({k for k in keys if k not in seen})
        new, rows = vm.insert(pts, None, seq)
        assert len(new) == expect_new
        seen.update(keys)
        assert np.allclose(np.floor(vm.positions[rows] / 0.1), np.floor(pts / 0.1))
    assert len(vm) == len(seen)
    size_after_30 = vm.nbytes
    for seq in range(30, 60):  # the same site again: no growth
        vm.insert(site[rng.integers(0, len(site), 3000)] * 0.999, None, seq)
    assert vm.nbytes <= size_after_30 * 1.01 + 4096 * 100


def test_neighbour_rows_against_brute_force() -> None:
    rng = np.random.default_rng(2)
    vm = VoxelMap(0.1)
    vm.insert(rng.uniform(0, 1, (3000, 3)), None, 0)
    rows = np.arange(0, len(vm), 7)
    nb = vm.neighbour_rows(rows)
    assert nb.shape == (len(rows), 27) and (nb[:, 13] == rows).all()
    coords = unpack_keys(vm.keys)
    for r, found in zip(rows[:50], nb[:50], strict=True):
        near = np.flatnonzero(np.abs(coords - coords[r]).max(axis=1) <= 1)
        assert set(found[found >= 0]) == set(near)
    assert vm.neighbour_rows(rows[:5], radius_voxels=2).shape == (5, 125)


@pytest.mark.parametrize("cell_m", [0.3, 0.25])
def test_context_rows_come_from_the_block_of_cells_around_each_point(cell_m: float) -> None:
    rng = np.random.default_rng(3)
    vm = VoxelMap(0.1)
    vm.insert(rng.uniform(0, 2, (4000, 3)), None, 0)
    vm.insert(rng.uniform(2, 3, (2000, 3)), None, 1)  # indexed lazily, after the first query too
    queries = np.r_[rng.uniform(0, 2, (100, 3)), rng.uniform(2, 3, (100, 3)), [[50.0, 50.0, 50.0]]]
    ctx = vm.context_rows(queries, cell_m=cell_m, num=50, rng=np.random.default_rng(0))
    assert ctx.shape == (201, 50)
    assert (ctx[-1] == -1).all()  # nothing stored near the far point
    got = ctx[:-1]
    assert (got >= 0).all()
    # Every sampled point lies in one of the 27 cells around the query's cell.
    if abs(cell_m / 0.1 - round(cell_m / 0.1)) < 1e-6:
        q_cell = np.floor_divide(np.floor(queries[:-1] / 0.1).astype(int), 3)
        p_cell = np.floor_divide(np.floor(vm.positions[got] / 0.1).astype(int), 3)
    else:
        q_cell = np.floor(queries[:-1] / cell_m).astype(int)
        p_cell = np.floor(vm.positions[got] / cell_m).astype(int)
    assert (np.abs(p_cell - q_cell[:, None, :]).max(axis=2) <= 1).all()
    # And the draw covers the block: with 50 draws from a full block several different points appear.
    assert np.mean([len(np.unique(r)) for r in got]) > 20
    vm.insert(np.array([[50.05, 50.05, 50.05]]), None, 2)
    assert (vm.context_rows(queries[-1:], cell_m=cell_m, num=5) == len(vm) - 1).all()


def test_clustering_links_merges_and_relabels() -> None:
    vm = VoxelMap(1.0)
    same = lambda m, a, b: np.ones(len(a), bool)  # noqa: E731 - every neighbour pair agrees
    cl = InstanceClusterer(same)
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
    apart = InstanceClusterer(lambda m, a, b: np.zeros(len(a), bool))
    lone, _ = vm.insert(np.array([[10.5, 0.5, 0.5], [11.5, 0.5, 0.5]]), None, 3)
    vm.instance_ids[lone] = 0
    apart.next_id = cl.next_id
    apart.add(vm, lone, 3)
    assert len(set(vm.instance_ids[lone])) == 2 and 1 not in set(vm.instance_ids[lone])


def test_to_cloud_copies() -> None:
    vm = VoxelMap(0.1)
    vm.insert(np.zeros((1, 3)), np.array([[9, 9, 9]], np.uint8), 0)
    cloud = vm.to_cloud()
    vm.class_ids[0] = 4
    assert cloud.class_ids[0] == UNLABELLED and len(cloud) == 1 and cloud.colors[0, 0] == 9


def test_neighbouring_instances_merge_when_their_mean_embeddings_agree() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731 - no single voxel pair links
    cl = InstanceClusterer(never, merge_beta=0.9)
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
    np.testing.assert_allclose(cl.sums[1], 5 * east)
    np.testing.assert_allclose(cl.sums[2], north)


def test_a_fragment_that_stops_growing_joins_the_neighbour_it_agrees_with() -> None:
    vm = VoxelMap(1.0, embedding_dim=2)
    never = lambda m, a, b: np.zeros(len(a), bool)  # noqa: E731
    # Fragments under 3 voxels, 2 scans without growth, similarity 0.7; instance merging itself kept off.
    cl = InstanceClusterer(never, merge_beta=2.0, absorb=(3, 2, 0.7))
    wall = np.array([[x + 0.5, 0.5, 0.5] for x in range(4)])
    rows, _ = vm.insert(wall, None, 0)
    vm.embeddings[rows] = [1.0, 0.0]
    cl.add(vm, rows, 0)
    vm.instance_ids[rows] = 1  # one object of 4 voxels (the links above were all refused)
    cl.sums[:] = 0.0
    cl.sums[1] = [4.0, 0.0]
    cl.size[:] = 0
    cl.size[1] = 4
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
    assert cl.size[1] == 5


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
    geo = Geometry() if geometry else Geometry(plane_min_voxels=10**9)
    cl = InstanceClusterer(same, merge_beta=0.9, geometry=geo, min_object_voxels=10, final_beta=0.7)
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
    cl = InstanceClusterer(never, merge_beta=0.9, min_object_voxels=20, final_beta=0.7)
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
    cl = InstanceClusterer(same, merge_beta=0.9, normal_links=normal_links, min_object_voxels=10, final_beta=0.7)
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
