"""The map as the recording cuts it: voxel-downsampled, in square tiles, and only the tiles that changed are
logged again (just their labels when their points stayed). No Rerun needed: checked on small synthetic maps."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.types import LabelledCloud
from aftershock.sinks.rerun_tiles import MapTiles, content_hash, tile_name

TILE_M = 4.0


def _site(n: int = 4000, seed: int = 0) -> LabelledCloud:
    """A 12 x 8 m floor: points at the centres of distinct 10 cm voxels."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(120 * 80, n, replace=False)
    pts = np.c_[(cells % 120) * 0.1 + 0.05, (cells // 120) * 0.1 - 3.95, np.zeros(n)]
    cls = np.full(n, SemanticClass.FLOOR, np.uint16)
    return LabelledCloud(pts, class_ids=cls, instance_ids=np.ones(n, np.uint32))


def _by_tile(tiles: MapTiles, cloud: LabelledCloud) -> dict[str, np.ndarray]:
    update = tiles.update(cloud)
    assert update is not None
    return {c.name: c.sel for c in update.changed}


def test_tile_names_spell_minus_as_m() -> None:
    assert tile_name(0, 0) == "x0y0" and tile_name(-1, 2) == "xm1y2" and tile_name(3, -12) == "x3ym12"


def test_a_tile_hash_ignores_the_order_of_points_but_not_a_label_or_a_millimetre() -> None:
    cloud = _site(500)
    cls, inst = cloud.class_ids, cloud.instance_ids
    total = content_hash(cloud.points, cls, inst).sum()
    perm = np.random.default_rng(1).permutation(len(cloud))
    assert content_hash(cloud.points[perm], cls[perm], inst[perm]).sum() == total
    other = inst.copy()
    other[7] = 2
    assert content_hash(cloud.points, cls, other).sum() != total
    moved = cloud.points.copy()
    moved[7, 2] += 0.001
    assert content_hash(moved, cls, inst).sum() != total


def test_the_first_update_logs_every_tile_each_holding_the_points_of_its_square() -> None:
    tiles = MapTiles(voxel_m=0.1, tile_m=TILE_M)
    cloud = _site()
    update = tiles.update(cloud)
    assert update is not None and not update.gone and update.colors is None
    assert len(update.points) == len(cloud)  # one point per voxel already: nothing to drop
    assert not any(c.labels_only for c in update.changed)
    everything = np.concatenate([c.sel for c in update.changed])
    assert sorted(everything.tolist()) == list(range(len(cloud)))  # every point in exactly one tile
    for change in update.changed:
        cell = np.floor(update.points[change.sel, :2] / TILE_M).astype(int)
        assert len(np.unique(cell, axis=0)) == 1
        assert tile_name(int(cell[0, 0]), int(cell[0, 1])) == change.name
    assert {c.name for c in update.changed} == {f"x{i}y{j}".replace("-", "m") for i in range(3) for j in (-1, 0)}
    np.testing.assert_allclose(tiles.bounds[0], cloud.points.min(axis=0))


def test_later_updates_log_only_the_tiles_that_changed() -> None:
    tiles = MapTiles(voxel_m=0.1, tile_m=TILE_M)
    cloud = _site()
    tiles.update(cloud)
    assert _by_tile(tiles, cloud) == {}  # the same map again: nothing to log
    # A new instance id in one tile: that tile again, labels only.
    relabelled = cloud.select(np.arange(len(cloud)))
    cell = np.floor(cloud.points[:, :2] / TILE_M)
    here = np.flatnonzero((cell[:, 0] == 1) & (cell[:, 1] == 0))[:5]
    relabelled.instance_ids[here] = 9
    update = tiles.update(relabelled)
    assert update is not None and [(c.name, c.labels_only) for c in update.changed] == [("x1y0", True)]
    # A point more in a tile (the map grew there): that tile with its points; a tile that emptied is cleared.
    grown = LabelledCloud(
        np.r_[relabelled.points, [[0.02, 0.0, 1.0]]],
        class_ids=np.r_[relabelled.class_ids, [SemanticClass.WALL]].astype(np.uint16),
        instance_ids=np.r_[relabelled.instance_ids, [3]].astype(np.uint32),
    )
    keep = np.floor(grown.points[:, 0] / TILE_M) != 2  # everything east of x = 8 m goes
    update = tiles.update(grown.select(keep))
    assert update is not None
    assert [(c.name, c.labels_only) for c in update.changed] == [("x0y0", False)]
    assert sorted(update.gone) == ["x2y0", "x2ym1"]
    assert set(tiles.signatures) == {"x0ym1", "x0y0", "x1ym1", "x1y0"}


def test_a_map_without_classes_is_drawn_by_colour_and_always_logged_whole() -> None:
    tiles = MapTiles(voxel_m=0.1, tile_m=TILE_M)
    site = _site(300)
    colors = np.full((len(site), 3), 128, np.uint8)
    plain = LabelledCloud(site.points, colors=colors)
    update = tiles.update(plain)
    assert update is not None and update.colors is not None and (update.colors == 128).all()
    assert (update.class_ids == 65535).all() and (update.instance_ids == 0).all()
    assert tiles.update(LabelledCloud(np.zeros((0, 3)))) is None  # an empty map changes nothing


def test_the_tiling_needs_no_rerun() -> None:
    code = "import sys, aftershock.sinks.rerun_tiles; sys.exit('rerun' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
