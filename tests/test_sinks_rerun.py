"""The Rerun sink, checked by reading real recordings back: entities, timelines, scans logged, class ids."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from fixtures import interruptible
from rerun.chunk import McapReader, RrdReader
from rrd_read import read_rrd, rrd_verify
from sinks_data import VELODYNE, frames, map_of

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.geometry import voxel_downsample
from aftershock.pipeline.sink import Stage
from aftershock.pipeline.types import Crack, DamageFound, LabelledCloud, RunInfo, RunSummary, Story
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks.rerun_sink import EmbeddingColors, RerunSink, log_id_of
from aftershock.sinks.rrd_compact import compact
from aftershock.sources.mcap_source import fingerprint

REPO = Path(__file__).resolve().parents[1]


def _run(
    path: Path, log: Path, *, source_kind: str = "mcap", raw_in_log: bool = False, repeat: int = 1, **cfg: object
) -> list:
    rerun_cfg = RerunConfig(**cfg)
    sink = RerunSink(path, False, None, rerun_cfg)
    log_id = fingerprint(log) if source_kind == "mcap" else ""
    info = RunInfo(str(log), source_kind, "/velodyne_points", labeller="rule", raw_in_log=raw_in_log, log_id=log_id)
    sink.begin(info)
    done = []
    try:
        for frame in frames(log, repeat):
            for stage in Stage:
                sink.stage(frame, stage)
            done.append(frame)
            if len(done) % rerun_cfg.map_every == 0:  # as the stream does
                sink.map_update(map_of(done), frame.seq)
        sink.end(RunSummary(scans=len(done)), map_of(done))
    finally:
        sink.close()
    return done


@pytest.fixture(scope="module")
def velodyne(lidar_dir: Path) -> Path:
    return lidar_dir / VELODYNE


@pytest.fixture(scope="module")
def recorded(velodyne: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    done = _run(path, velodyne, raw_in_log=True, map_every=2)
    return path, done


DEBUG_LAYERS = (L.REGISTERED, L.LABELLED, L.INSTANCES, L.EMBEDDING)


def test_recording_has_the_layout(recorded: tuple[Path, list], velodyne: Path) -> None:
    path, done = recorded
    rec = read_rrd(path)
    assert rec.application_id == "aftershock"
    assert log_id_of(rec.recording_id) == fingerprint(velodyne)  # `view` pairs it with its log
    assert rec.blueprints == 1  # the default blueprint travels with the file
    for entity in (L.WORLD, L.ROBOT, L.LABELS, f"{L.TRAJECTORY}/p0"):
        assert entity in rec.entities, entity
    # the viewer opens this log itself: no raw scans, no full-resolution layers unless asked for
    assert not rec.entities & {L.RAW, *DEBUG_LAYERS}
    assert rec.under(L.MAP), "no map tiles"
    assert {"stats/time_ms/register", "stats/time_ms/label", "stats/counts/kept", "log/merges"} <= rec.entities
    assert "AnnotationContext:context" in rec.components(L.WORLD)
    assert {"Points3D:positions", "Points3D:class_ids", "instance_id"} <= rec.components(L.LABELS)
    # the log's sensor frame hangs off the estimated pose, so its clouds appear where the robot was
    assert rec.rows(L.LOG_FRAME, "Transform3D:child_frame", static=True) == [[done[0].scan.frame_id]]
    assert rec.rows(L.LOG_FRAME, "Transform3D:parent_frame", static=True) == [[f"tf#/{L.ROBOT}"]]
    # every scan logged once per layer, on the scan timeline
    seqs = [f.seq for f in done]
    for entity, component in ((L.LABELS, "Points3D:class_ids"), (L.ROBOT, "Transform3D:translation")):
        assert rec.times(entity, component, L.SCAN_TIMELINE).tolist() == seqs, entity
    assert len(rec.rows("stats/time_ms/register", "Scalars:scalars")) == len(done)
    # per-scan scalars are sent as columns, on the same times as the layers
    for timeline in (L.SCAN_TIMELINE, L.MCAP_LOG_TIMELINE, L.MCAP_STAMP_TIMELINE):
        stats = rec.times("stats/counts/kept", "Scalars:scalars", timeline)
        assert np.array_equal(stats, rec.times(L.LABELS, "Points3D:class_ids", timeline)), timeline


def test_recording_holds_what_went_in(recorded: tuple[Path, list]) -> None:
    path, done = recorded
    rec = read_rrd(path)
    # one point per 10 cm voxel of the points kept for labelling, with that point's class and instance
    want_cls, want_inst, want_pts = [], [], []
    for f in done:
        kept = f.map_rows.points
        first, _ = voxel_downsample(f.world_points[kept], 0.1)
        want_cls.append(f.labels.class_ids[kept[first]])
        want_inst.append(f.labels.instance_ids[kept[first]])
        want_pts.append(f.world_points[kept[first]])
    got = rec.values(L.LABELS, "Points3D:class_ids")
    assert np.array_equal(got, np.concatenate(want_cls))
    assert UNLABELLED not in set(np.unique(got))  # only the points kept for labelling are shown
    assert np.array_equal(rec.values(L.LABELS, "instance_id"), np.concatenate(want_inst))
    pts = np.concatenate([np.asarray(r) for r in rec.rows(L.LABELS, "Points3D:positions")])
    assert np.allclose(pts, np.concatenate(want_pts), atol=1e-5)
    assert sum(len(c) for c in want_cls) < sum(len(f.map_rows.points) for f in done) / 2  # far fewer than kept
    positions = np.asarray(rec.rows(L.ROBOT, "Transform3D:translation"))
    assert np.allclose(positions.reshape(len(done), 3), [f.pose[:3, 3] for f in done])
    map_classes = np.concatenate([rec.values(e, "Points3D:class_ids") for e in rec.under(L.MAP)])
    assert set(np.unique(map_classes)) <= set(
        np.unique(np.concatenate([f.labels.class_ids[f.map_rows.points] for f in done]))
    )
    assert rec.texts("log/summary")[0].startswith(f"{len(done)} scans")
    assert rrd_verify(path).returncode == 0
    assert len(RrdReader(path).store()) > 0  # the footer was written on close


def test_timelines_line_up_with_rerun_mcap_import(recorded: tuple[Path, list], velodyne: Path) -> None:
    path, _ = recorded
    rec = read_rrd(path)
    assert rec.timelines == {L.SCAN_TIMELINE, L.MCAP_LOG_TIMELINE, L.MCAP_STAMP_TIMELINE}
    imported: dict[str, set[int]] = {L.MCAP_LOG_TIMELINE: set(), L.MCAP_STAMP_TIMELINE: set()}
    for chunk in McapReader(velodyne).stream():
        if chunk.entity_path == "/velodyne_points" and not chunk.is_static:
            batch = chunk.to_record_batch()
            for name, times in imported.items():
                times.update(batch.column(name).cast("int64").to_pylist())
    assert imported[L.MCAP_LOG_TIMELINE], "Rerun's MCAP import has no message_log_time"
    for name, times in imported.items():
        assert set(rec.times(L.LABELS, "Points3D:class_ids", name).tolist()) == times, name


def test_recordings_are_compact(recorded: tuple[Path, list], velodyne: Path, tmp_path: Path) -> None:
    """At the defaults a VLP-16 scan costs at most 100 KB of recording (the issue's budget); the debug layers
    hold every point of every stage."""
    path, done = recorded
    per_scan = path.stat().st_size / len(done)
    debug = tmp_path / "debug.rrd"
    _run(debug, velodyne, raw_in_log=True, map_every=2, debug_layers=True)
    debug_kb = debug.stat().st_size / len(done) / 1e3
    print(f"\nrecording per VLP-16 scan: {per_scan / 1e3:.0f} kB, with debug layers {debug_kb:.0f} kB")
    assert per_scan <= 100_000
    rec = read_rrd(debug)
    for entity in DEBUG_LAYERS:
        assert rec.times(entity, "Points3D:positions", L.SCAN_TIMELINE).tolist() == [f.seq for f in done], entity
    labelled = rec.values(L.LABELLED, "Points3D:class_ids")
    assert np.array_equal(labelled, np.concatenate([f.labels.class_ids[f.map_rows.points] for f in done]))
    inst = rec.values(L.INSTANCES, "instance_id")
    assert np.array_equal(inst, np.concatenate([f.labels.instance_ids[f.map_rows.points] for f in done]))
    assert debug.stat().st_size > 5 * path.stat().st_size


def test_raw_scans_stay_downsampled_when_the_viewer_cannot_open_the_log(velodyne: Path, tmp_path: Path) -> None:
    path = tmp_path / "ros1.rrd"
    done = _run(path, velodyne, source_kind="bag", raw_in_log=False)  # as from a ROS 1 bag
    rec = read_rrd(path)
    assert rec.times(L.RAW, "Points3D:positions", L.SCAN_TIMELINE).tolist() == [f.seq for f in done]
    assert L.LOG_FRAME not in rec.entities and log_id_of(rec.recording_id) is None
    for f, raw in zip(done, rec.rows(L.RAW, "Points3D:positions"), strict=True):
        raw = np.asarray(raw, dtype=np.float64)
        assert len(np.unique(np.floor(raw / 0.3), axis=0)) == len(raw) < len(f.scan) / 4  # one per 30 cm voxel
        first, _ = voxel_downsample(f.scan.points, 0.3)
        assert np.allclose(raw, f.scan.points[first], atol=1e-5)  # real points of the scan, not voxel centres


def test_other_sources_use_sensor_time(velodyne: Path, tmp_path: Path) -> None:
    path = tmp_path / "files.rrd"
    done = _run(path, velodyne, source_kind="files")
    rec = read_rrd(path)
    assert rec.timelines == {L.SCAN_TIMELINE, L.SENSOR_TIMELINE}
    stamps = rec.times(L.LABELS, "Points3D:class_ids", L.SENSOR_TIMELINE)
    assert stamps.tolist() == [f.scan.stamp_ns for f in done]


def test_map_relogs_only_changed_tiles(tmp_path: Path) -> None:
    path = tmp_path / "map.rrd"
    sink = RerunSink(path, False, None, RerunConfig(map_every=1, map_tile_m=10.0, map_voxel_m=0.1))
    sink.begin(RunInfo("m", "sim"))
    rng = np.random.default_rng(0)
    a = rng.uniform([0, 0, 0], [9, 9, 3], (2000, 3))  # tile x0y0
    b = rng.uniform([-9, 0, 0], [-1, 9, 3], (2000, 3))  # tile xm1y0
    cls = np.full(4000, 2, np.uint16)
    cloud = LabelledCloud(np.vstack([a, b]), class_ids=cls, instance_ids=np.ones(4000, np.uint32))
    sink.map_update(cloud, 0)
    sink.map_update(cloud, 1)  # nothing changed
    cls2 = cls.copy()
    cls2[:10] = 4  # a relabel inside x0y0 only
    sink.map_update(LabelledCloud(cloud.points, class_ids=cls2, instance_ids=cloud.instance_ids), 2)
    sink.close()
    rec = read_rrd(path)
    assert rec.under(L.MAP) == {f"{L.MAP}/x0y0", f"{L.MAP}/xm1y0"}
    # the relabelled tile gets its labels again, not its points; the other tile nothing
    assert rec.times(f"{L.MAP}/x0y0", "Points3D:positions", L.SCAN_TIMELINE).tolist() == [0]
    assert rec.times(f"{L.MAP}/x0y0", "Points3D:class_ids", L.SCAN_TIMELINE).tolist() == [0, 2]
    assert (rec.values(f"{L.MAP}/x0y0", "Points3D:class_ids") == 4).sum() == 10  # the relabelled points
    assert rec.times(f"{L.MAP}/xm1y0", "Points3D:positions", L.SCAN_TIMELINE).tolist() == [0]
    assert rec.times(f"{L.MAP}/xm1y0", "Points3D:class_ids", L.SCAN_TIMELINE).tolist() == [0]
    # downsampled to the map voxel: at most one point per 10 cm voxel
    pts = np.asarray(rec.rows(f"{L.MAP}/x0y0", "Points3D:positions")[0])
    assert len(np.unique(np.floor(pts / 0.1), axis=0)) == len(pts)


def test_refined_growth_and_damage_layers(tmp_path: Path) -> None:
    path = tmp_path / "layers.rrd"
    sink = RerunSink(path, False, None, RerunConfig())  # an on-demand command: no run, no `begin`
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 2, (500, 3))
    inst = (pts[:, 0] > 1).astype(np.uint32) + 1
    cloud = LabelledCloud(pts, class_ids=np.full(500, 4, np.uint16), instance_ids=inst)
    steps = [(np.arange(k * 10), np.arange(k * 10, k * 10 + 20)) for k in range(1, 6)]
    sink.refined(cloud, steps)
    crack = Crack(3, np.array([1.0, 1.0, 1.0]), 0.25, 0.004, 120, np.array([0, 0, 1.0]), np.array([1.0, 0, 0]), True)
    story = Story(1, 3.0, np.array([0, 0, 1.0, -3.0]), 3.0, 4.0, 5.0, 0.1, 0.1, 0.14, 1000)
    sink.damage(DamageFound([crack], LabelledCloud(pts[:50], instance_ids=np.full(50, 3, np.uint32)), [story]))
    sink.close()
    rec = read_rrd(path)
    assert L.LRGNET_STEP_TIMELINE in rec.timelines
    growth = rec.times(f"{L.REFINED_GROWTH}/inliers", "Points3D:positions", L.LRGNET_STEP_TIMELINE)
    assert growth.tolist() == [0, 1, 2, 3, 4]
    assert [len(r) for r in rec.rows(f"{L.REFINED_GROWTH}/neighbours", "Points3D:positions")] == [20] * 5
    assert np.array_equal(np.concatenate(rec.rows(L.REFINED, "instance_id", static=True)), inst)
    label = rec.texts(L.CRACKS, "Boxes3D:labels", static=True)[0]
    assert "25.0 cm long" in label and "4.0 mm wide" in label
    assert "5.0 mm" in rec.texts(L.DRIFT, "Arrows3D:labels", static=True)[0]
    assert f"{L.STORIES}/s1" in rec.entities
    assert "AnnotationContext:context" in rec.components(L.WORLD)


def test_embedding_colors_are_stable_across_scans() -> None:
    rng = np.random.default_rng(2)
    first = rng.normal(size=(300, 16))
    colors = EmbeddingColors()
    a = colors(first)
    colors(rng.normal(size=(300, 16)) + 5.0)  # a later scan does not refit
    assert np.array_equal(colors(first), a)
    assert a.dtype == np.uint8 and a.shape == (300, 3) and a.std() > 10


def test_outputs_are_checked_before_any_work(tmp_path: Path) -> None:
    existing = tmp_path / "old.rrd"
    existing.write_bytes(b"x")
    with pytest.raises(OutputError, match="already exists"):
        RerunSink(existing, False, None, RerunConfig())
    sink = RerunSink(existing, False, None, RerunConfig(), force=True)
    assert existing.read_bytes() == b"x"  # nothing is written before the run begins
    sink.begin(RunInfo("x", "sim"))
    sink.close()
    assert read_rrd(existing).application_id == "aftershock"
    fresh = tmp_path / "sub" / "new.rrd"
    RerunSink(fresh, False, None, RerunConfig()).close()  # a run refused before it began
    assert not fresh.exists()
    not_a_folder = tmp_path / "file.txt"
    not_a_folder.write_text("x")
    with pytest.raises(OutputError, match="cannot create the folder"):
        RerunSink(not_a_folder / "x.rrd", False, None, RerunConfig())


def test_bad_connect_url_is_an_output_error() -> None:
    with pytest.raises(OutputError, match="not a Rerun gRPC URL"):
        RerunSink(None, False, "http://localhost:9876", RerunConfig())
    with pytest.raises(OutputError, match="no Rerun viewer is listening"):
        RerunSink(None, False, f"rerun+http://127.0.0.1:{_free_port()}/proxy", RerunConfig())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_connect_streams_to_a_viewer_server(velodyne: Path, tmp_path: Path) -> None:
    port, out = _free_port(), tmp_path / "received.rrd"
    rerun = Path(sys.executable).with_name("rerun")
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    server = subprocess.Popen(
        [str(rerun), "--bind", "127.0.0.1", "--port", str(port), "--save", str(out)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=interruptible,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.2)
        sink = RerunSink(None, False, f"rerun+http://127.0.0.1:{port}/proxy", RerunConfig())
        sink.begin(RunInfo(str(velodyne), "mcap"))
        n = 0
        for frame in frames(velodyne):
            for stage in Stage:
                sink.stage(frame, stage)
            n += 1
        sink.close()
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            time.sleep(0.5)
            try:
                if len(read_rrd(out).rows(L.LABELS, "Points3D:class_ids")) == n:
                    break
            except Exception:  # the server may still be writing the first bytes
                continue
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(timeout=20)
    assert len(read_rrd(out).rows(L.LABELS, "Points3D:class_ids")) == n


_CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from aftershock.pipeline.config import RerunConfig
    from aftershock.pipeline.types import RunInfo, RunSummary
    from aftershock.pipeline.sink import Stage
    from aftershock.sinks.rerun_sink import RerunSink
    from sinks_data import frames, map_of

    log, out = Path(sys.argv[1]), Path(sys.argv[2])
    sink = RerunSink(out, False, None, RerunConfig(map_every=1))
    sink.begin(RunInfo(str(log), "mcap"))
    done = []
    try:
        for frame in frames(log, repeat=10_000):
            for stage in Stage:
                sink.stage(frame, stage)
            done.append(frame)
            sink.map_update(map_of(done[-4:]), frame.seq)
            print(frame.seq, flush=True)
    except KeyboardInterrupt:
        sink.end(RunSummary(scans=len(done), interrupted=True), map_of(done[-4:]))
    finally:
        sink.close()
    """
)


def test_ctrl_c_leaves_a_readable_recording(velodyne: Path, tmp_path: Path) -> None:
    out = tmp_path / "interrupted.rrd"
    env = dict(os.environ, CI="true", PYTHONPATH=f"{REPO}{os.pathsep}{REPO / 'tests'}")
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(velodyne), str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, text=True, preexec_fn=interruptible,
    )  # fmt: skip
    assert child.stdout is not None
    for _ in range(6):  # let it log a few scans, then interrupt it mid-run
        assert child.stdout.readline(), "the child stopped before it was interrupted"
    child.send_signal(signal.SIGINT)
    child.wait(timeout=60)
    assert child.returncode == 0
    rec = read_rrd(out)
    scans = rec.times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE)
    assert len(scans) >= 6 and scans.tolist() == list(range(len(scans)))
    assert "(interrupted)" in rec.texts("log/summary")[0]
    assert rrd_verify(out).returncode == 0
    assert len(RrdReader(out).store()) > 0


def _chunks(path: Path) -> int:
    reader = RrdReader(path)
    return sum(1 for _ in reader.stream(store=reader.recordings()[0]))


def test_a_large_recording_is_compacted_holding_the_same(
    recorded: tuple[Path, list], velodyne: Path, tmp_path: Path
) -> None:
    """Past `rerun.compact_above_mb` (0 here: every one) the finished file is rewritten by `rerun rrd optimize`:
    the same recording (id, blueprint, every row of every entity on every timeline), valid, nothing left beside."""
    as_written, _ = recorded
    path = tmp_path / "compacted.rrd"
    _run(path, velodyne, raw_in_log=True, map_every=2, compact_above_mb=0)
    assert rrd_verify(path).returncode == 0
    a, b = read_rrd(as_written), read_rrd(path)
    assert (a.application_id, log_id_of(a.recording_id), a.blueprints, a.timelines, a.entities) == (
        b.application_id,
        log_id_of(b.recording_id),
        b.blueprints,
        b.timelines,
        b.entities,
    )
    for entity in (L.LABELS, *sorted(a.under(L.MAP))):
        for component in ("Points3D:class_ids", "Points3D:positions"):
            got = b.times(entity, component, L.SCAN_TIMELINE).tolist()
            assert a.times(entity, component, L.SCAN_TIMELINE).tolist() == got
    rows_a = [np.asarray(r) for r in a.rows(L.LABELS, "Points3D:class_ids")]
    rows_b = [np.asarray(r) for r in b.rows(L.LABELS, "Points3D:class_ids")]
    assert all(np.array_equal(x, y) for x, y in zip(rows_a, rows_b, strict=True))
    assert [p.name for p in tmp_path.iterdir()] == ["compacted.rrd"]


def test_compacting_turns_many_small_chunks_into_few(tmp_path: Path) -> None:
    """A chunk per row (as a long mission's per-scan layers and scalars come out) -> a few large chunks."""
    path = tmp_path / "many.rrd"
    rec = rr.RecordingStream(
        "aftershock-test", recording_id="many", batcher_config=rr.ChunkBatcherConfig(flush_num_rows=1)
    )
    rec.save(path)
    rng = np.random.default_rng(0)
    clouds = [rng.random((50, 3)).astype(np.float32) for _ in range(300)]
    for seq, cloud in enumerate(clouds):
        rec.set_time(L.SCAN_TIMELINE, sequence=seq)
        rec.log("world/scan", rr.Points3D(cloud))
        rec.log("stats/value", rr.Scalars(float(seq)))
    rec.flush()
    rec.disconnect()
    before = _chunks(path)
    assert before >= 600
    assert compact(path)
    assert _chunks(path) < before / 20
    got = read_rrd(path)
    assert got.recording_id == "many"
    assert all(
        np.array_equal(np.asarray(r, np.float32), c)
        for r, c in zip(got.rows("world/scan", "Points3D:positions"), clouds, strict=True)
    )
    assert got.times("stats/value", "Scalars:scalars", L.SCAN_TIMELINE).tolist() == list(range(300))
