"""The structure model on the real logs of shared/data/lidar: what a glance at their maps tells (no annotation).

Each log goes once through `aftershock run LOG --export` (a module fixture); the tests read the exported map and
structure.json. What they check was seen in the viewer and in plots of the maps (docs/benchmarks/real.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.cloud_io import read_cloud

C = SemanticClass
THRESHOLD_M = 0.06  # structure.plane_threshold_m: a voxel on a plane


def _run(log: Path, out: Path) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:
    cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--export", str(out), "--force", "-q"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    cloud = read_cloud(out / "map.ply")
    assert cloud.class_ids is not None
    return cloud.points, cloud.class_ids, json.loads((out / "structure.json").read_text())["elements"]


@pytest.fixture(scope="module")
def exports(lidar_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    names = ("room_scan1.pcd", "room_scan2.pcd", "ouster_os1_128_outdoor.mcap")
    if not all((lidar_dir / n).is_file() for n in names):
        pytest.skip("the real logs are not in shared/data/lidar")
    root = tmp_path_factory.mktemp("real")
    return {n: _run(lidar_dir / n, root / n.split(".")[0]) for n in names}


@pytest.mark.parametrize("log", ["room_scan1.pcd", "room_scan2.pcd"])
def test_the_lamps_hanging_under_the_room_scans_ceilings_are_no_beams(exports: dict[str, Any], log: str) -> None:
    # rows of pendant lamps 0.2-0.3 m under the ceiling, the ceiling seen over them: they were beam boxes
    _, classes, elements = exports[log]
    assert not [e for e in elements if e["kind"] == "beam"]
    assert np.mean(classes == C.BEAM) < 0.005


def test_room_scan1s_window_takes_its_reveal_and_leaves_the_walls_face_wall(exports: dict[str, Any]) -> None:
    # the window at x = -2.6 m: its frame and mullion stand 0.2-0.3 m behind the wall's face; the face around it
    # is the wall's (it was labelled window, 3 % of that wall)
    points, classes, elements = exports["room_scan1.pcd"]
    windows = [e for e in elements if e["kind"] == "window"]
    assert len(windows) == 1
    plane = np.array(windows[0]["plane"])
    on_face = np.abs(points @ plane[:3] + plane[3]) < THRESHOLD_M
    lo, hi = np.array(windows[0]["extent"]["min"]), np.array(windows[0]["extent"]["max"])
    near = np.all((points[:, :2] > lo[:2] - 0.3) & (points[:, :2] < hi[:2] + 0.3), axis=1)
    assert np.sum(near & (classes == C.WINDOW)) > 50  # the reveal's voxels
    assert not np.any(near & on_face & (classes == C.WINDOW))


def test_the_outdoor_facade_is_one_wall_outline(exports: dict[str, Any]) -> None:
    # the building at y = -8.8 m: recesses and balconies 0.2-0.5 m deep, each a plane (11 outlines before)
    _, _, elements = exports["ouster_os1_128_outdoor.mcap"]
    on_facade = [
        e for e in elements if e["kind"] == "wall" and e["extent"]["min"][1] > -9.5 and e["extent"]["max"][1] < -8.0
    ]
    assert len(on_facade) == 1
    assert on_facade[0]["extent"]["max"][0] - on_facade[0]["extent"]["min"][0] > 9.0
