"""`aftershock run` and `aftershock eval` end to end: real logs to a recording that is read back, a log with
ground truth scored, bad inputs and outputs refused in one line, Ctrl-C leaving a valid recording."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from faults_data import write_log
from fixtures import chunk_offsets, interruptible, write_ros2_mcap
from rrd_read import read_rrd, rrd_verify

from aftershock.pipeline.classes import NUM_CLASSES, SemanticClass
from aftershock.pipeline.cli import main
from aftershock.pipeline.config import load_config
from aftershock.pipeline.stream import run_stream
from aftershock.pipeline.types import RunInfo
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks.rerun_sink import RerunSink

REAL_LOGS = ("velodyne_vlp16_indoor.mcap", "ouster_os1_128_outdoor.mcap", "ouster_os1_64_ros1.mcap", "room_scan1.pcd")
EVAL_KEYS = (
    "overall_accuracy",
    "mean_accuracy",
    "mean_iou",
    "nmi",
    "ami",
    "ari",
    "precision",
    "recall",
    "ate_m",
    "scans",
    "scans_per_second",
    "level_tilt_deg",
    "confusion",
)


def _run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", REAL_LOGS)
def test_real_logs_run_end_to_end(name: str, lidar_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "run.rrd"
    args = ["run", str(lidar_dir / name), "--save", str(out), "--labeller", "region-growing", "--quiet", "--json"]
    code, stdout, _ = _run_cli(args, capsys)
    assert code == 0
    summary = json.loads(stdout)
    assert summary["scans"] >= 1 and summary["map_voxels"] > 100 and summary["instances"] > 0
    assert summary["registration_failures"] == []
    assert set(summary["mean_timings_ms"]) >= {"register", "label", "cluster", "sinks"}
    assert 0.0 <= summary["level_tilt_deg"] < 5.0  # levelled from the first scan; these sensors sat near level

    rec = read_rrd(out)
    assert {L.SCAN_TIMELINE} <= rec.timelines
    assert {L.ROBOT, L.LABELS} <= rec.entities
    assert not {L.REGISTERED, L.LABELLED, L.INSTANCES, L.EMBEDDING} & rec.entities  # --debug-layers only
    # raw scans only where the viewer cannot open the log beside the recording (ROS 1 MCAP, PCD)
    assert (L.RAW in rec.entities) == ("ros1" in name or not name.endswith(".mcap"))
    assert rec.under(L.MAP)
    seqs = rec.times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE)
    assert len(seqs) == summary["scans"]
    classes = set(rec.values(L.LABELS, "Points3D:class_ids").astype(int).tolist())
    assert classes and classes <= set(range(NUM_CLASSES))
    assert rrd_verify(out).returncode == 0


def test_debug_layers_on_request(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "debug.rrd"
    log = lidar_dir / REAL_LOGS[0]
    args = ["run", str(log), "--save", str(out), "--labeller", "region-growing", "--quiet", "--debug-layers"]
    assert _run_cli(args, capsys)[0] == 0
    rec = read_rrd(out)
    assert {L.REGISTERED, L.LABELLED, L.INSTANCES, L.LABELS} <= rec.entities
    kept = rec.values(L.LABELLED, "Points3D:class_ids")
    assert len(kept) > 2 * len(rec.values(L.LABELS, "Points3D:class_ids"))  # every kept point, not one per voxel


# ----------------------------------------------------------------------------------- a log with truth


def _hall(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 12 x 8 x 3 m hall: floor, ceiling, four walls and three boxes, with classes and instances."""
    pts, cls, inst = [], [], []

    def face(origin, u, v, n, c, i) -> None:
        a = rng.uniform(0, 1, (n, 2))
        pts.append(np.asarray(origin) + a[:, :1] * u + a[:, 1:] * v)
        cls.append(np.full(n, c, np.uint16))
        inst.append(np.full(n, i, np.uint32))

    x, y, z = np.eye(3)
    face([0, 0, 0], 12 * x, 8 * y, 90_000, SemanticClass.FLOOR, 1)
    face([0, 0, 3], 12 * x, 8 * y, 90_000, SemanticClass.CEILING, 2)
    face([0, 0, 0], 12 * x, 3 * z, 30_000, SemanticClass.WALL, 3)
    face([0, 8, 0], 12 * x, 3 * z, 30_000, SemanticClass.WALL, 4)
    face([0, 0, 0], 8 * y, 3 * z, 20_000, SemanticClass.WALL, 5)
    face([12, 0, 0], 8 * y, 3 * z, 20_000, SemanticClass.WALL, 6)
    for k, (bx, by) in enumerate([(3, 2.2), (6, 5.6), (9, 2.4)]):
        for origin, u, v in (
            ([bx, by, 0], 0.8 * x, 0.7 * z),
            ([bx, by + 0.8, 0], 0.8 * x, 0.7 * z),
            ([bx, by, 0.7], 0.8 * x, 0.8 * y),
            ([bx, by, 0], 0.8 * y, 0.7 * z),
        ):
            face(origin, u, v, 3000, SemanticClass.TABLE, 7 + k)
    return np.vstack(pts), np.concatenate(cls), np.concatenate(inst)


def write_truth_log(path: Path, scans: int = 30, points: int = 12_000, seed: int = 0, with_poses: bool = True) -> Path:
    """A ROS 2 MCAP of a sensor driving down the hall at 1 m height, with class/instance fields and true poses."""
    rng = np.random.default_rng(seed)
    world, cls, inst = _hall(rng)
    clouds, poses = [], []
    for k in range(scans):
        pose = np.eye(4)
        along = (0.3 * k) % 18.0  # back and forth between x = 1.5 and 10.5 m
        pose[:3, 3] = [1.5 + 9.0 - abs(along - 9.0), 4.0 + 0.5 * np.sin(k / 5), 1.0]
        rel = world - pose[:3, 3]
        near = np.flatnonzero(np.einsum("ij,ij->i", rel, rel) < 15**2)
        pick = near[rng.integers(0, len(near), points)]
        local = world[pick] - pose[:3, 3] + rng.normal(0, 0.005, (len(pick), 3))
        clouds.append(
            {
                "x": local[:, 0].astype(np.float32),
                "y": local[:, 1].astype(np.float32),
                "z": local[:, 2].astype(np.float32),
                "class_id": cls[pick],
                "instance_id": inst[pick],
            }
        )
        poses.append(pose)
    return write_ros2_mcap(path, clouds, poses=poses if with_poses else None)


def test_eval_scores_a_log_with_truth(tmp_path: Path, capsys) -> None:
    log = write_truth_log(tmp_path / "hall.mcap")
    # The study's 2 m range: within it the hall's floor, walls and ceiling meet only at clean corners, which
    # is what the geometric rules below are written for (further out, region growing joins them).
    near = ["--set", "label.indoor_range_m=2"]
    code, stdout, _ = _run_cli(["eval", str(log), "--labeller", "region-growing", *near, "--quiet", "--json"], capsys)
    assert code == 0
    rep = json.loads(stdout)
    assert set(EVAL_KEYS) <= set(rep)
    assert rep["scans"] == 30
    assert rep["ate_m"] < 0.05  # the hall has structure in every direction
    assert 0.5 < rep["overall_accuracy"] <= 1.0  # floor, ceiling and walls follow the geometric rules
    assert {"floor", "ceiling", "wall", "table"} <= set(rep["per_class_iou"])
    assert rep["per_class_iou"]["floor"] > 0.5 and rep["per_class_iou"]["table"] == 0.0
    # where the points went: every true class's row sums to its points, and the table's never say table
    assert sum(sum(row.values()) for row in rep["confusion"].values()) == rep["evaluated_points"]
    assert "table" not in rep["confusion"]["table"]
    for key in ("nmi", "ami", "ari", "precision", "recall"):
        assert 0.0 <= rep[key] <= 1.0
    assert rep["nmi"] > 0.3
    code, stdout, _ = _run_cli(["eval", str(log), "--labeller", "region-growing", "--quiet"], capsys)
    assert code == 0 and "mean IoU" in stdout and "ATE" in stdout


def test_eval_with_true_poses_scores_labelling_alone(tmp_path: Path, capsys) -> None:
    """`--poses truth` places every scan with the log's own pose (no registration error) and says so."""
    log = write_truth_log(tmp_path / "hall.mcap")
    near = ["--set", "label.indoor_range_m=2"]
    args = ["eval", str(log), "--labeller", "region-growing", *near, "--quiet", "--json"]
    code, stdout, _ = _run_cli([*args, "--poses", "truth"], capsys)
    assert code == 0
    truth = json.loads(stdout)
    code, stdout, _ = _run_cli(args, capsys)
    estimated = json.loads(stdout)
    assert truth["poses"] == "truth" and estimated["poses"] == "estimated"
    assert set(EVAL_KEYS) <= set(truth) and truth["ate_m"] is None and estimated["ate_m"] < 0.05
    assert truth["scans"] == 30 and truth["registration_failures"] == 0
    assert 0.5 < truth["overall_accuracy"] <= 1.0 and truth["per_class_iou"]["floor"] > 0.5
    # The stream's poses are the log's true poses exactly.
    from aftershock import sources

    cfg = load_config(None, ["label.labeller=region-growing", "registration.poses=truth", *near[1:]])
    res = run_stream(sources.open(str(log)), cfg, [], RunInfo(source=str(log), source_kind="mcap"), lambda _t: None)
    finite = ~np.isnan(res.true_poses).any(axis=(1, 2))
    assert finite.all() and np.allclose(res.poses, res.true_poses, atol=1e-9)
    code, stdout, _ = _run_cli(
        ["eval", str(log), "--labeller", "region-growing", "--quiet", "--poses", "truth"], capsys
    )
    assert code == 0 and "true poses were used" in stdout


def test_objects_shown_have_the_minimum_size_and_merges_reach_the_recording(tmp_path: Path) -> None:
    """MCPNet on a short simulated mission: the map the user gets (and that `eval` scores) holds only objects
    of at least `cluster.min_object_voxels`; the merges, the end-of-run consolidation's included, are in the
    recording's merge log, and the last map in the recording shows the consolidated objects."""
    from aftershock import sources
    from aftershock.pipeline.commands.evaluate import evaluate_map

    uri = "sim://office?seed=5&sensor=vlp16&scans=20"
    cfg = load_config(None, ["label.labeller=mcpnet"])
    sink = RerunSink(tmp_path / "run.rrd", False, None, cfg.rerun)
    res = run_stream(sources.open(uri), cfg, [sink], RunInfo(source=uri, source_kind="sim"), lambda _t: None)
    ids, counts = np.unique(res.vmap.instance_ids, return_counts=True)
    shown = ids > 0
    assert shown.sum() == res.summary.instances >= 3
    assert counts[shown].min() >= cfg.cluster.min_object_voxels
    assert res.summary.fragments > res.summary.instances  # small fragments exist and are hidden
    scores = evaluate_map(res.vmap)
    assert 0 < scores["predicted_instances"] <= res.summary.instances
    rec = read_rrd(tmp_path / "run.rrd")
    merges = rec.texts("log/merges")
    assert merges and all("merged into" in t for t in merges)
    assert rec.times("log/merges", "TextLog:text", L.SCAN_TIMELINE).max() == 19
    last = {e: rec.rows(e, "instance_id") for e in rec.under(L.MAP)}
    final_ids = set(np.concatenate([np.asarray(r[-1]) for r in last.values() if r]).tolist())
    assert final_ids <= set(ids.tolist())


def test_eval_with_true_poses_refuses_a_log_without_them(tmp_path: Path, capsys) -> None:
    log = write_truth_log(tmp_path / "hall.mcap", scans=3, with_poses=False)
    code, stdout, err = _run_cli(["eval", str(log), "--quiet", "--poses", "truth"], capsys)
    assert code == 2 and stdout == "" and len(err.strip().splitlines()) == 1
    assert "hall.mcap" in err and "no true poses" in err
    code, _, err = _run_cli(["eval", str(log), "--quiet", "--poses", "guessed"], capsys)
    assert code == 2 and "estimated, truth" in err and len(err.strip().splitlines()) == 1


def test_eval_on_a_small_simulated_mission(capsys) -> None:
    uri = "sim://disaster?seed=5&sensor=vlp16&scans=8"
    code, stdout, _ = _run_cli(["eval", uri, "--labeller", "region-growing", "--quiet", "--json"], capsys)
    assert code == 0
    rep = json.loads(stdout)
    assert set(EVAL_KEYS) <= set(rep) and rep["scans"] == 8
    assert rep["environment"] == "indoor" and rep["evaluated_points"] > 100
    assert rep["ate_m"] < 0.3 and rep["nmi"] > 0.3


def test_the_default_labeller_falls_back_only_when_not_asked_for_by_name(
    lidar_dir: Path, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    uri = str(lidar_dir / "velodyne_vlp16_indoor.mcap")
    missing = tmp_path / "none.pt"
    # The shipped weights missing (a checkout without them): the default labeller falls back, with a notice.
    import aftershock.pipeline.labellers.mcpnet as mcpnet_labeller

    monkeypatch.setattr(mcpnet_labeller, "default_weights", lambda kind="mcpnet": missing)
    code, stdout, err = _run_cli(["run", uri, "--json"], capsys)
    assert code == 0 and json.loads(stdout)["labeller"] == "region-growing"
    assert "none.pt" in err and "using the region-growing baseline instead" in err
    # A labeller or a weights file named by the user must load or fail (issue 14), also with --quiet.
    for args in (["--labeller", "mcpnet"], ["--set", f'label.weights="{missing}"']):
        code, _, err = _run_cli(["run", uri, *args, "--quiet"], capsys)
        assert code == 2 and "none.pt" in err and len(err.strip().splitlines()) == 1


def test_eval_refuses_a_log_without_truth(lidar_dir: Path, capsys) -> None:
    code, stdout, err = _run_cli(["eval", str(lidar_dir / "velodyne_vlp16_indoor.mcap"), "--quiet"], capsys)
    assert code == 2 and stdout == ""
    assert err.strip().endswith("the log carries no ground truth (class_id / instance_id point fields)")
    assert len(err.strip().splitlines()) == 1


# ----------------------------------------------------------------------------------- bad input and output


def test_no_usable_scans(tmp_path: Path, capsys) -> None:
    tiny = [{"x": np.ones(5, np.float32), "y": np.ones(5, np.float32), "z": np.ones(5, np.float32)}] * 3
    log = write_ros2_mcap(tmp_path / "tiny.mcap", tiny)
    code, _, err = _run_cli(["run", str(log), "--labeller", "region-growing", "--quiet"], capsys)
    assert code == 2 and "no usable scans (3 scans, none with 100 points or more)" in err
    assert len(err.strip().splitlines()) == 1


def test_existing_and_unwritable_outputs_are_refused_before_work(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    log = str(lidar_dir / "velodyne_vlp16_indoor.mcap")
    out = tmp_path / "run.rrd"
    out.write_bytes(b"keep me")
    code, _, err = _run_cli(["run", log, "--save", str(out), "--quiet"], capsys)
    assert code == 2 and "already exists (pass --force to overwrite)" in err
    assert out.read_bytes() == b"keep me"
    args = ["run", log, "--save", str(out), "--force", "--quiet", "--labeller", "region-growing"]
    code, _, _ = _run_cli(args, capsys)
    assert code == 0 and out.stat().st_size > 1000
    # A folder that cannot be made (a file is in the way) and, unless we are root, one that cannot be written.
    (tmp_path / "a_file").write_text("")
    code, _, err = _run_cli(["run", log, "--export", str(tmp_path / "a_file" / "out"), "--quiet"], capsys)
    assert code == 2 and "a_file" in err and len(err.strip().splitlines()) == 1
    code, _, err = _run_cli(["run", log, "--save", str(tmp_path / "a_file" / "x.rrd"), "--quiet"], capsys)
    assert code == 2 and "cannot create the folder" in err and len(err.strip().splitlines()) == 1
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if not os.access(locked, os.W_OK):
            code, _, err = _run_cli(["run", log, "--save", str(locked / "x.rrd"), "--quiet"], capsys)
            assert code == 2 and "not writable" in err and len(err.strip().splitlines()) == 1
    finally:
        locked.chmod(0o700)


def test_unknown_labeller_and_bad_override(lidar_dir: Path, capsys) -> None:
    log = str(lidar_dir / "velodyne_vlp16_indoor.mcap")
    code, _, err = _run_cli(["run", log, "--labeller", "magic", "--quiet"], capsys)
    assert code == 2 and "unknown labeller 'magic'" in err
    code, _, err = _run_cli(["run", log, "--set", "map.voxel_size_m=fast", "--quiet"], capsys)
    assert code == 2 and "map.voxel_size_m" in err


# ----------------------------------------------------------------------------------- Ctrl-C


def test_ctrl_c_on_the_command_line(tmp_path: Path) -> None:
    log = write_truth_log(tmp_path / "long.mcap", scans=300, points=3000)
    out = tmp_path / "ctrlc.rrd"
    cmd = [
        sys.executable,
        "-m",
        "aftershock.pipeline",
        "run",
        str(log),
        "--save",
        str(out),
        "--labeller",
        "region-growing",
    ]
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, preexec_fn=interruptible
    )
    deadline = time.monotonic() + 60
    part = out.with_name(out.name + ".part")  # the sink creates it when the run begins, renamed when closed
    while time.monotonic() < deadline and not part.exists():
        time.sleep(0.1)
    time.sleep(3.0)  # some scans in, far from all 300
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted after" in stdout and "open it with its log: " in stdout and " view " in stdout
    scans = int(stdout.split("interrupted after ")[1].split()[0])
    assert 0 < scans < 300
    rec = read_rrd(out)
    # The scan in flight when Ctrl-C came may have reached the last stage too, without being counted.
    assert len(rec.times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE)) in (scans, scans + 1)
    assert rrd_verify(out).returncode == 0 and not part.exists()


def test_eval_with_the_truth_standing_in_for_classes_or_embeddings(capsys) -> None:
    """`--oracle` takes one part of the labeller out of the picture: with the true classes the semantic scores
    are perfect and the objects about the same (the clustering reads embeddings; classes only say which pieces
    are walls and floors); with a vector per true object the objects improve over the network's embeddings (and
    are no worse than geometry's slab and wall objects over them). Bad values and a labeller
    without embeddings: one line, exit 2."""
    uri = "sim://office?seed=5&sensor=vlp16&scans=15&robot=wheeled&height=1"
    reps = {}
    for oracle in ("none", "classes", "objects"):
        code, stdout, _ = _run_cli(["eval", uri, "--oracle", oracle, "--quiet", "--json"], capsys)
        assert code == 0
        reps[oracle] = json.loads(stdout)
        assert reps[oracle]["oracle"] == oracle and set(EVAL_KEYS) <= set(reps[oracle])
    plain, classes, objects = reps["none"], reps["classes"], reps["objects"]
    assert plain["labeller"] == "mcpnet" and classes["labeller"] == "mcpnet+true-classes"
    assert classes["overall_accuracy"] == 1.0 and classes["mean_iou"] == 1.0
    assert abs(classes["nmi"] - plain["nmi"]) < 0.03
    # the vectors stand in for the network's embeddings, so they are measured against the embeddings' own objects
    # (geometry's slab and wall objects off), and geometry's objects do not beat them either
    off = ["--set", "cluster.structure_objects=false"]
    code, stdout, _ = _run_cli(["eval", uri, *off, "--quiet", "--json"], capsys)
    embeddings = json.loads(stdout)
    assert code == 0
    assert objects["nmi"] > embeddings["nmi"] + 0.05 and objects["recall"] > embeddings["recall"]
    assert objects["nmi"] >= plain["nmi"] and objects["recall"] >= plain["recall"]
    code, _, err = _run_cli(["eval", uri, "--oracle", "labels"], capsys)
    assert code == 2 and "unknown --oracle 'labels'" in err and "Traceback" not in err
    code, _, err = _run_cli(["eval", uri, "--oracle", "objects", "--labeller", "region-growing"], capsys)
    assert code == 2 and "no embeddings" in err and len(err.strip().splitlines()) == 1


def test_a_truth_stand_in_on_a_log_without_truth_is_refused(lidar_dir: Path, capsys) -> None:
    log = lidar_dir / "velodyne_vlp16_indoor.mcap"
    code, _, err = _run_cli(["run", str(log), "--set", "label.oracle=objects"], capsys)
    assert code == 2 and "needs a log with ground truth" in err and str(log) in err


@pytest.mark.parametrize("color", [True, False])
def test_the_on_demand_stages_and_exports_see_whether_the_log_had_color(color: bool, tmp_path: Path) -> None:
    """LRGNet and the damage assessment get the final map without colour when no scan had any (not the map's
    stand-in grey), so that a colour-free log is refined with the colour-free settings; the exported map of
    such a log reads back without colour (its PLY says the colour is a stand-in)."""
    from aftershock import sources
    from aftershock.pipeline.cloud_io import read_cloud
    from aftershock.sinks.files import FileExportSink

    uri = "sim://office?seed=5&sensor=vlp16&scans=3" + ("" if color else "&color=0")
    seen: list = []
    cfg = load_config(None, ["label.labeller=region-growing"])
    sink = FileExportSink(tmp_path / "export")
    res = run_stream(
        sources.open(uri), cfg, [sink], RunInfo(source=uri, source_kind="sim"), lambda _t: None,
        on_final_map=lambda cloud, _sinks: seen.append(cloud),
    )  # fmt: skip
    assert len(seen) == 1 and len(seen[0]) == len(res.vmap) > 0
    assert res.vmap.has_color is color and (seen[0].colors is not None) is color
    exported = read_cloud(sink.map_path)
    assert len(exported) == len(res.vmap) and (exported.colors is not None) is color


def test_a_cut_log_with_damage_json_keeps_why_it_ended_beside_the_damage_report(tmp_path: Path, capsys) -> None:
    """`run CUT.mcap --damage --json` on a log cut off in the middle of a chunk: `damage` says why the log
    ended (as in summary.json and `info --json`), `damage_report` is the damage assessment (as in damage.json);
    the report once overwrote the reason under one key (docs/json.md)."""
    log = write_log(tmp_path / "log.mcap", 12, chunk_size=50_000)
    start, length = chunk_offsets(log)[6]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: start + length // 2])
    out = tmp_path / "out"
    args = ["run", str(cut), "--labeller", "region-growing", "--damage", "--export", str(out), "-q", "--json"]
    code, stdout, err = _run_cli(args, capsys)
    assert code == 0, err
    result = json.loads(stdout)
    assert result["damaged_log"] is True and isinstance(result["damage"], str) and "cut off" in result["damage"]
    assert 5 <= result["scans"] < 12
    assert result["damage"] == json.loads((out / "summary.json").read_text())["damage"]
    report = result["damage_report"]
    assert {"cracks", "stories", "seconds"} <= set(report)
    assert report == json.loads((out / "damage.json").read_text())
