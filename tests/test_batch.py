"""`aftershock batch` end to end: real and simulated MCAP logs through a real two-node Ray cluster (joined with
--address), a corrupt log among them, the site index and every mission's outputs read back; resuming; a local
instance listening on 127.0.0.1 only, interrupted with Ctrl-C; bad input refused in one line."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from fixtures import interruptible, truncate_in_chunk
from rrd_read import read_rrd

from aftershock.pipeline.batch.folder import MARKER_FILE, completed_row
from aftershock.pipeline.batch.site_index import COLUMN_NAMES, OBJECT_COLUMNS, STRUCTURE_COLUMNS
from aftershock.pipeline.batch.sources import expand_sources, name_missions
from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import read_cloud
from aftershock.sinks import rerun_blueprint as L

CLI = [sys.executable, "-m", "aftershock.pipeline"]
ENV = os.environ | {"CI": "true", "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
FAST = ["--labeller", "region-growing"]  # the stream is the same; the labeller is not what is tested here


def _batch(args: list[str], timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, "batch", *args], capture_output=True, text=True, env=ENV, timeout=timeout)


def _simulate(path: Path, scans: int, seed: int) -> Path:
    cmd = [*CLI, "simulate", "--out", str(path), "--scans", str(scans), "--seed", str(seed), "--sensor", "vlp16-20hz"]
    subprocess.run(cmd, check=True, capture_output=True, env=ENV, timeout=300)
    return path


@pytest.fixture(scope="module")
def cluster() -> Iterator[str]:
    """Two Ray nodes (one CPU each) on 127.0.0.1; yields the head's address."""
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"  # loopback-only, as `batch` runs its own
    from ray._private import ray_constants
    from ray.cluster_utils import Cluster

    ray_constants.ENABLE_RAY_CLUSTER = False
    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    c.add_node(num_cpus=1)
    c.wait_for_nodes()
    try:
        yield c.address
    finally:
        c.shutdown()


def test_batch_on_a_two_node_cluster(cluster: str, lidar_dir: Path, tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    (logs / "robot2").mkdir(parents=True)
    sim = _simulate(logs / "office.mcap", 12, seed=4)
    _simulate(logs / "robot2" / "disaster.mcap", 10, seed=5)
    truncate_in_chunk(sim, logs / "robot2" / "cut.mcap", chunk=1)  # read up to the damage, with a warning
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + np.random.default_rng(0).bytes(4000))  # the magic, then garbage
    listing = tmp_path / "site.txt"
    listing.write_text(f"# robots' logs\n{lidar_dir / 'velodyne_vlp16_indoor.mcap'}\ncorrupt.mcap\nmissing.mcap\n")
    out = tmp_path / "out"

    t0 = time.perf_counter()
    proc = _batch([str(logs), str(listing), "--out", str(out), "--address", cluster, "--json", *FAST])
    assert proc.returncode == 1, proc.stderr  # some missions failed
    report = json.loads(proc.stdout)
    rows = {r["mission"]: r for r in report["missions"]}
    assert set(rows) == {"office", "disaster", "cut", "velodyne_vlp16_indoor", "corrupt", "missing"}

    index = pq.read_table(out / "missions.parquet")
    assert tuple(index.column_names) == COLUMN_NAMES
    table = {r["mission"]: r for r in index.to_pylist()}
    assert {k: v["status"] for k, v in table.items()} == {k: v["status"] for k, v in rows.items()}
    assert table["corrupt"]["status"] == "failed" and "corrupt.mcap" in table["corrupt"]["error"]
    assert "\n" not in table["corrupt"]["error"]
    assert table["missing"]["status"] == "failed" and "no such file" in table["missing"]["error"]
    assert not (out / "missing").exists() and not (out / "corrupt").exists()

    good = ["office", "disaster", "cut", "velodyne_vlp16_indoor"]
    for name in good:
        r = table[name]
        assert r["status"] == "ok", r
        assert r["scans"] >= 1 and r["map_voxels"] > 100 and r["objects"] > 0
        assert sum(r[c] for c in OBJECT_COLUMNS) <= r["objects"]
        folder = out / name
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["scans"] == r["scans"] and summary["map_voxels"] == r["map_voxels"]
        found = summary["structure_elements"]  # the structure model's elements, counted per kind in the index
        for col, kinds in STRUCTURE_COLUMNS.items():
            assert r[col] == sum(found.get(k, 0) for k in kinds), (name, col)
        assert len((folder / "poses_tum.txt").read_text().splitlines()) == r["scans"]
        assert len((folder / "poses_kitti.txt").read_text().splitlines()) == r["scans"]
        assert len(read_cloud(folder / "map.ply")) > 0
        rec = read_rrd(folder / "recording.rrd")  # the recording sink of `run`: grown as .part, then renamed
        assert not list(folder.glob("*.part"))
        assert rec.under("world/map") and len(rec.times(L.ROBOT, "Transform3D:translation", "scan")) == r["scans"]
        assert Path(r["recording"]) == folder / "recording.rrd" and Path(r["map"]) == folder / "map.ply"
        assert completed_row(folder, r["source"], r["config_hash"]) is not None
    assert table["office"]["scans"] == 12 and table["disaster"]["scans"] == 10
    assert table["office"]["structure_slabs"] >= 1 and table["office"]["structure_walls"] >= 1  # a simulated office
    assert table["office"]["ate_m"] is not None and table["office"]["ate_m"] < 0.5  # the simulator's true poses
    assert table["office"]["path_length_m"] > 0 and table["office"]["duration_s"] > 0
    assert table["velodyne_vlp16_indoor"]["ate_m"] is None  # no truth in a real log
    assert table["cut"]["scans"] < 12 and "damage" in (table["cut"]["warnings"] or "").lower()
    import duckdb  # the index as a user queries it

    sql = "SELECT mission, scans, objects FROM read_parquet(?) WHERE status = 'ok' AND ate_m IS NOT NULL ORDER BY 1"
    got = duckdb.execute(sql, [str(out / "missions.parquet")]).fetchall()
    assert got == [(n, table[n]["scans"], table[n]["objects"]) for n in sorted(good) if table[n]["ate_m"] is not None]
    nodes = {table[n]["node"] for n in good}
    assert len(nodes) == 2, nodes  # both nodes of the cluster ran missions

    # A re-run skips every complete mission (the failed ones are tried again) and keeps the index whole.
    t_first = time.perf_counter() - t0
    proc = _batch([str(logs), str(listing), "--out", str(out), "--address", cluster, "--json", *FAST])
    assert proc.returncode == 1, proc.stderr
    again = {r["mission"]: r for r in json.loads(proc.stdout)["missions"]}
    assert all(again[n]["reused"] for n in good) and again["corrupt"]["status"] == "failed"
    assert len(pq.read_table(out / "missions.parquet")) == 6
    assert time.perf_counter() - t0 - t_first < t_first

    # Another configuration is refused without --force, in one line.
    proc = _batch([str(logs), "--out", str(out), "--address", cluster, "--labeller", "mcpnet"])
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "another configuration" in proc.stderr and "label.labeller" in proc.stderr


def _listening_ports(pids: set[int]) -> list[tuple[str, int]]:
    import psutil

    out = []
    for conn in psutil.net_connections(kind="inet"):
        if conn.status == psutil.CONN_LISTEN and conn.pid in pids:
            out.append((conn.laddr.ip, conn.laddr.port))
    return out


def test_local_ray_on_loopback_and_ctrl_c(tmp_path: Path) -> None:
    """A local instance (no --address): every port it opens is on 127.0.0.1; Ctrl-C leaves the finished
    mission complete (with its damage report) and the interrupted one to be redone."""
    import psutil

    out = tmp_path / "out"
    args = ["sim://office?seed=1&scans=6&sensor=vlp16-20hz", "sim://disaster?seed=2&scans=3000&sensor=vlp16-20hz"]
    cmd = [*CLI, "batch", *args, "--out", str(out), "--workers", "2", "--damage", *FAST]
    # Its own process group, signalled as a whole: what a terminal's Ctrl-C does (Ray's servers included).
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
                            preexec_fn=interruptible, start_new_session=True)  # fmt: skip
    small = out / "sim-office-seed-1-scans-6-sensor-vlp16-20hz"
    big = out / "sim-disaster-seed-2-scans-3000-sensor-vlp16-20hz"
    ports: list[tuple[str, int]] = []
    deadline = time.time() + 240
    while time.time() < deadline and not ((small / MARKER_FILE).is_file() and (big / "poses_tum.txt").is_file()):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.5)
    pids = {proc.pid} | {p.pid for p in psutil.Process(proc.pid).children(recursive=True)}
    ports = _listening_ports(pids)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert ports and all(ip in ("127.0.0.1", "::ffff:127.0.0.1") for ip, _ in ports), ports
    assert "interrupted" in stderr and "Traceback" not in stderr
    rows = {r["mission"]: r for r in pq.read_table(out / "missions.parquet").to_pylist()}
    assert rows[small.name]["status"] == "ok" and (small / MARKER_FILE).is_file()
    report = json.loads((small / "damage.json").read_text())  # --damage: the report and its figures in the index
    done = rows[small.name]
    assert done["cracks"] == len(report["cracks"]) and done["severe_cracks"] == report["severe_cracks"]
    assert done["damage"] == str(small / "damage.json") and (done["worst_drift_mm"] is None) == all(
        st["drift_mm"] is None for st in report["stories"]
    )  # not measured (one slab) is null in the index, never 0
    assert rows[big.name]["status"] == "interrupted"
    assert completed_row(big, rows[big.name]["source"], rows[small.name]["config_hash"]) is None  # redone next time
    assert "interrupted" in stdout


def _main(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["batch", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_unreachable_address_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    args = ["sim://office?scans=2", "--out", str(tmp_path / "o"), "--address"]
    code, _, err = _main([*args, f"127.0.0.1:{port}"], capsys)
    assert code == 2 and err.count("\n") == 1 and f"127.0.0.1:{port}" in err
    assert not (tmp_path / "o").exists()
    with socket.socket() as silent:  # something listens but never speaks gRPC: refused in bounded time
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        t0 = time.perf_counter()
        code, _, err = _main([*args, address], capsys)
        assert code == 2 and err.count("\n") == 1 and address in err
        assert time.perf_counter() - t0 < 30
    code, _, err = _main([*args, "nowhere"], capsys)
    assert code == 2 and "HOST:PORT" in err


def test_output_folder_of_other_results_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No Ray needed: every source is bad, so nothing runs, but the folder and index are written."""
    out = tmp_path / "out"
    missing = str(tmp_path / "nothing.mcap")
    code, stdout, _ = _main([missing, "--out", str(out), *FAST], capsys)
    assert code == 1 and "no such file" in stdout
    assert pq.read_table(out / "missions.parquet").to_pylist()[0]["status"] == "failed"
    code, _, err = _main([missing, "--out", str(out), "--damage", *FAST], capsys)
    assert code == 2 and "damage" in err and err.count("\n") == 1
    code, _, _ = _main([missing, "--out", str(out), "--damage", "--force", *FAST], capsys)
    assert code == 1
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    code, _, err = _main([missing, "--out", str(foreign)], capsys)
    assert code == 2 and "not a batch" in err
    assert (foreign / "notes.txt").read_text() == "mine"


def test_sources_expand_into_named_missions(tmp_path: Path) -> None:
    site = tmp_path / "site"
    (site / "a").mkdir(parents=True)
    (site / "b").mkdir()
    (site / "a" / "m1.mcap").write_bytes(b"x")
    (site / "b" / "m1.mcap").write_bytes(b"x")
    (site / "b" / "run.bag").write_bytes(b"x")
    bag2 = site / "b" / "ros2bag"
    bag2.mkdir()
    (bag2 / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (bag2 / "ros2bag_0.mcap").write_bytes(b"x")  # part of the ROS 2 bag, not a mission of its own
    scans = tmp_path / "scans"
    scans.mkdir()
    for k in range(3):
        (scans / f"{k}.pcd").write_bytes(b"x")
    listing = tmp_path / "list.txt"
    listing.write_text("site/a/m1.mcap  # again\n\nsim://office?seed=2\n")
    found = expand_sources([str(site), str(scans / "*.pcd"), str(listing), str(tmp_path / "nope" / "*.mcap")])
    named = {m.source: m for m in name_missions(found)}
    assert set(named) == {
        str(site / "a" / "m1.mcap"),
        str(site / "b" / "m1.mcap"),
        str(site / "b" / "run.bag"),
        str(bag2),
        str(scans / "*.pcd"),
        "sim://office?seed=2",
        str(tmp_path / "nope" / "*.mcap"),
    }
    names = [m.name for m in named.values()]
    assert len(set(names)) == len(names)
    assert named[str(site / "a" / "m1.mcap")].name.startswith("m1-")  # two m1: both get a hash of their path
    assert named[str(site / "b" / "run.bag")].name == "run" and named[str(bag2)].name == "ros2bag"
    assert named["sim://office?seed=2"].name == "sim-office-seed-2"
    assert named[str(tmp_path / "nope" / "*.mcap")].error is not None
    assert all(m.error is None for s, m in named.items() if "nope" not in s)
