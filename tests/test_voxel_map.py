"""The voxel map: first point per voxel, new work only for new voxels, neighbourhoods and MCPNet context,
checked against plain Python sets and brute force on small random clouds."""

from __future__ import annotations

import numpy as np
import pytest

from aftershock.pipeline.classes import UNLABELLED
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


def test_to_cloud_copies() -> None:
    vm = VoxelMap(0.1)
    vm.insert(np.zeros((1, 3)), np.array([[9, 9, 9]], np.uint8), 0)
    cloud = vm.to_cloud()
    vm.class_ids[0] = 4
    assert cloud.class_ids[0] == UNLABELLED and len(cloud) == 1 and cloud.colors[0, 0] == 9
