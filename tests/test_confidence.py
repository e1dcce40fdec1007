"""Every labelled voxel carries a confidence: the labeller's probability for the class it shows (MCPNet's
softmax), kept in the voxel map, exported as a `confidence` PLY property beside every property the map had."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData
from rrd_read import read_rrd

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import read_cloud, write_cloud
from aftershock.pipeline.config import Config
from aftershock.pipeline.labellers.mcpnet import create
from aftershock.pipeline.types import LabelledCloud
from aftershock.pipeline.voxel_map import VoxelMap
from aftershock.sinks import rerun_blueprint as L

MAP_PROPERTIES = ("x", "y", "z", "red", "green", "blue", "class_id", "instance_id")


def test_a_real_logs_exported_map_carries_a_confidence_per_point(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "export"
    code = main(["run", str(lidar_dir / "velodyne_vlp16_indoor.mcap"), "--export", str(out), "--quiet", "--json"])
    assert code == 0
    assert json.loads(capsys.readouterr().out)["labeller"] == "mcpnet"
    names = PlyData.read(str(out / "map.ply"))["vertex"].data.dtype.names
    assert names == (*MAP_PROPERTIES, "confidence")  # added, nothing dropped or reordered
    cloud = read_cloud(out / "map.ply")
    assert cloud.confidence is not None and cloud.class_ids is not None
    labelled = cloud.class_ids != UNLABELLED
    conf = cloud.confidence[labelled]
    assert labelled.all() and (conf > 0).all() and (conf <= 1).all()
    # a softmax over 14 classes: never below 1/14 for the class the network chose; the votes may go lower
    assert 0.2 < float(np.median(conf)) < 1.0 and conf.std() > 0.01


def test_the_recording_carries_confidence_beside_class_ids_and_shows_the_uncertain_voxels(
    lidar_dir: Path, tmp_path: Path, capsys
) -> None:
    rrd, out = tmp_path / "run.rrd", tmp_path / "export"
    log = str(lidar_dir / "velodyne_vlp16_indoor.mcap")
    assert main(["run", log, "--save", str(rrd), "--export", str(out), "--quiet", "--json"]) == 0
    capsys.readouterr()
    rec = read_rrd(rrd)
    tiles = sorted(rec.under(L.MAP))
    assert tiles
    for entity in (*tiles, L.LABELS):
        assert {"Points3D:class_ids", "confidence"} <= rec.components(entity), entity
    last = {e: np.asarray(rec.rows(e, "confidence")[-1]) for e in tiles}  # each tile as the run left it
    conf = np.concatenate(list(last.values()))
    classes = np.concatenate([np.asarray(rec.rows(e, "Points3D:class_ids")[-1]) for e in tiles])
    assert len(conf) == len(classes) and ((conf > 0) & (conf <= 1)).all()
    # every voxel under the threshold is drawn again, in one colour no class has, and none above it
    threshold = Config().rerun.uncertain_below
    shown = np.concatenate([np.asarray(rec.rows(e, "confidence")[-1]) for e in rec.under(L.UNCERTAIN)])
    exported = read_cloud(out / "map.ply").confidence
    assert exported is not None
    assert len(shown) == int((exported < threshold).sum()) > 0 and (shown < threshold).all()


def test_an_instance_vote_gives_each_voxel_the_networks_probability_of_its_new_class() -> None:
    labeller = create(Config())
    vmap = VoxelMap(0.1, labeller.embedding_dim)
    rows, _ = vmap.insert(np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5.0, 0, 0]]))
    c = labeller.net.num_classes
    prob = np.full((4, c), 0.01, np.float32)
    prob[0, 2], prob[0, 7] = 0.80, 0.10  # two voxels sure of class 2 (wall) out-vote one of class 7 (table)
    prob[1, 2], prob[1, 7] = 0.70, 0.20
    prob[2, 7], prob[2, 2] = 0.60, 0.30
    prob[3, 7] = 0.90  # another instance: left as it is
    labeller._grow(len(vmap))
    labeller.raw_prob[rows] = prob
    labeller.raw_class[rows] = prob.argmax(1)
    labeller.raw_score[rows] = prob.max(1)
    vmap.class_ids[rows] = prob.argmax(1)
    vmap.scores[rows] = prob.max(1)
    vmap.instance_ids[rows] = [1, 1, 1, 2]
    labeller.vote_instances(vmap, np.array([1]))
    assert vmap.class_ids.tolist() == [2, 2, 2, 7]
    np.testing.assert_allclose(vmap.scores, [0.80, 0.70, 0.30, 0.90], atol=1e-3)
    np.testing.assert_allclose(vmap.to_cloud().confidence, vmap.scores)


def test_confidence_reads_back_and_is_not_taken_for_intensity(tmp_path: Path) -> None:
    pts = np.random.default_rng(0).uniform(0, 1, (50, 3))
    conf = np.linspace(0.1, 1.0, 50, dtype=np.float32)
    cloud = LabelledCloud(pts, class_ids=np.zeros(50, np.uint16), confidence=conf)
    back = read_cloud(write_cloud(tmp_path / "c.ply", cloud))
    assert back.intensity is None
    assert back.confidence is not None
    np.testing.assert_allclose(back.confidence, conf)
    assert back.select(np.arange(5)).confidence == pytest.approx(conf[:5])
