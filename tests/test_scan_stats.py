"""Scans unlike the networks' training scans are said so, once per run and reason: in the log (stderr) and in
the run's `warnings` (`run --json`, summary.json). The training range is pipeline.scan_stats' reference,
measured on MCPNet's training missions (`python -m aftershock.models.scan_reference_train`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from aftershock.models.transfer_split import VALIDATION_SEEDS, bench_uri
from aftershock.pipeline.cli import main
from aftershock.pipeline.scan_stats import REASONS, Reference, ScanStats


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    assert main(["run", *args, "--json"]) == 0
    out, err = capsys.readouterr()
    return json.loads(out), err


def test_a_real_indoor_ouster_log_warns_of_its_beam_pattern_once(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    """An OS1-64: 64 beams, where the networks learnt from 16 and 32."""
    summary, err = _run([str(lidar_dir / "ouster_os1_64_ros1.mcap"), "--export", str(tmp_path)], capsys)
    assert summary["scans"] == 2 and summary["labeller"] == "mcpnet"
    beams = [w for w in summary["warnings"] if w.startswith("beam pattern")]
    assert len(beams) == 1 and "beams 64" in beams[0], summary["warnings"]
    reasons = [w.split(" outside")[0] for w in summary["warnings"]]
    assert len(reasons) == len(set(reasons))  # once per reason, not per scan
    assert all(f"aftershock: {w}" in err for w in summary["warnings"])  # and in the log
    assert json.loads((tmp_path / "summary.json").read_text())["warnings"] == summary["warnings"]


def test_an_outdoor_ouster_log_warns_of_its_density_and_beams(lidar_dir: Path, capsys) -> None:
    """An OS1-128 in a street: 107k returns a scan of 128 beams."""
    summary, _ = _run([str(lidar_dir / "ouster_os1_128_outdoor.mcap"), "--quiet"], capsys)
    reasons = {w.split(" outside")[0] for w in summary["warnings"]}
    assert {"point density", "beam pattern"} <= reasons, summary["warnings"]


def test_a_simulated_mission_like_the_training_ones_does_not_warn(capsys) -> None:
    """A validation mission of a training generator (the benchmark's VLP-16 robot): in the family."""
    uri = bench_uri("office", VALIDATION_SEEDS[0], 8, color=False)
    summary, _ = _run([uri, "--quiet"], capsys)
    assert summary["scans"] == 8 and summary["warnings"] == [], summary["warnings"]


def test_the_baseline_learnt_nothing_and_is_not_warned_for(lidar_dir: Path, capsys) -> None:
    summary, _ = _run([str(lidar_dir / "ouster_os1_128_outdoor.mcap"), "--labeller", "region-growing", "-q"], capsys)
    assert summary["warnings"] == []


def test_the_shipped_reference_bounds_every_statistic() -> None:
    ref = Reference.load()
    assert set(ref.bounds) == set(REASONS) and "training missions" in ref.measured_on
    assert all(0 < lo <= hi for lo, hi in ref.bounds.values())
    inside = ScanStats(**{k: (lo + hi) / 2 for k, (lo, hi) in ref.bounds.items()})  # type: ignore[arg-type]
    assert ref.outside(inside) == []
    unmeasured = ScanStats(**{**inside.__dict__, "beams": None, "returns_per_voxel": None})
    assert ref.outside(unmeasured) == []
