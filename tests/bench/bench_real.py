"""Real-log benchmark (slow; `make bench-real`): every real LiDAR log in shared/data/lidar through `aftershock run`,
its exported map checked against the planes found in it without the labeller (pipeline.planecheck).

Per log it prints floor, ceiling and wall agreement (share of each plane's points carrying that class; "no such
plane" where the map has none), the class shares of the map and the run's warnings. Logs are discovered, not
listed: MCAP, PCD, PLY, ROS 1 bags and ROS 2 bag folders in REAL_LIDAR (default: the first shared/data/lidar
above the checkout). REAL_ARGS adds options to every run (e.g. `--labeller region-growing`); REAL_JSON writes
the figures to a file. No pipeline setting is chosen on these logs; the plane finder's own thresholds were set by
looking at which planes it found in their maps (surfaces or not), never at agreement figures.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any, Final

import numpy as np
import pytest

from aftershock.pipeline.cloud_io import read_cloud
from aftershock.pipeline.config import Config
from aftershock.pipeline.planecheck import check_map, class_shares

pytestmark = pytest.mark.timeout(3600)

REPO: Final = Path(__file__).resolve().parents[2]
LOG_SUFFIXES: Final = (".mcap", ".pcd", ".ply", ".bag")
EXTRA_ARGS: Final = shlex.split(os.environ.get("REAL_ARGS", ""))
UNCERTAIN: Final = Config().rerun.uncertain_below  # the viewer's threshold for drawing a voxel as uncertain
SHOWN_SHARE: Final = 0.01  # classes under this share of a map are left out of the printed line


def data_folder() -> Path | None:
    if "REAL_LIDAR" in os.environ:
        return Path(os.environ["REAL_LIDAR"])
    return next((p / "shared/data/lidar" for p in REPO.parents if (p / "shared/data/lidar").is_dir()), None)


def real_logs(folder: Path) -> list[Path]:
    """Files with a log suffix, and folders holding a ROS 2 bag (metadata.yaml)."""
    found = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in LOG_SUFFIXES]
    found += [p for p in folder.iterdir() if p.is_dir() and (p / "metadata.yaml").is_file()]
    return sorted(found)


def run_log(log: Path, out: Path) -> dict[str, Any]:
    """`aftershock run LOG --export OUT --json` in its own process; the summary, its notices and warnings."""
    cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--export", str(out), "--json", "--force"]
    proc = subprocess.run([*cmd, *EXTRA_ARGS], capture_output=True, text=True, env={**os.environ, "CI": "true"})
    assert proc.returncode == 0, f"{log.name}: exit {proc.returncode}\n{proc.stderr[-2000:]}"
    summary = json.loads(proc.stdout)
    said = [line.removeprefix("aftershock: ") for line in proc.stderr.splitlines() if line.startswith("aftershock:")]
    summary["_warnings"] = [*summary.get("warnings", []), *(w for w in said if w not in summary.get("warnings", []))]
    return summary


def measure(log: Path, out: Path) -> dict[str, Any]:
    summary = run_log(log, out)
    cloud = read_cloud(out / "map.ply")
    assert cloud.class_ids is not None and len(cloud) > 0, f"{log.name}: the exported map has no labels"
    poses = np.loadtxt(out / "poses_tum.txt", ndmin=2)
    sensor_z = float(np.median(poses[:, 3]))  # the levelled map's z: the sensor's height over the run
    check = check_map(cloud.points, cloud.class_ids, sensor_z)
    return {
        "log": log.name,
        "scans": summary["scans"],
        "map_points": len(cloud),
        "environment": summary.get("environment"),
        "floor": check.floor,
        "ceiling": check.ceiling,
        "wall": check.wall,
        "wall_planes": len(check.room.walls),
        "floor_height_m": None if check.room.floor is None else check.room.floor.z_m - sensor_z,
        "ceiling_height_m": None if check.room.ceiling is None else check.room.ceiling.z_m - sensor_z,
        "class_shares": check.shares,
        # the labeller's confidence where the map carries it (None: not exported, not measured)
        "median_confidence": None if cloud.confidence is None else float(np.median(cloud.confidence)),
        "uncertain_share": None if cloud.confidence is None else float(np.mean(cloud.confidence < UNCERTAIN)),
        "plane_classes": {
            name: class_shares(cloud.class_ids, np.concatenate([q.indices for q in planes]))
            for name, planes in (
                ("floor", [check.room.floor] if check.room.floor else []),
                ("ceiling", [check.room.ceiling] if check.room.ceiling else []),
                ("wall", check.room.walls),
            )
            if planes
        },
        "warnings": summary["_warnings"],
    }


def _share(value: float | None) -> str:
    return "no such plane" if value is None else f"{value:.3f}"


def report(rows: list[dict[str, Any]]) -> str:
    lines = [f"{'log':32s} {'scans':>5s} {'points':>7s}  {'floor':>13s} {'ceiling':>13s} {'wall':>13s}  wall planes"]
    for r in rows:
        lines.append(
            f"{r['log']:32s} {r['scans']:5d} {r['map_points']:7d}  {_share(r['floor']):>13s} "
            f"{_share(r['ceiling']):>13s} {_share(r['wall']):>13s}  {r['wall_planes']}"
        )
    for r in rows:
        shares = ", ".join(f"{k} {v:.1%}" for k, v in r["class_shares"].items() if v >= SHOWN_SHARE)
        lines.append(f"\n{r['log']} ({r['environment']}): {shares}")
        heights = [(n, r[f"{n}_height_m"]) for n in ("floor", "ceiling") if r[f"{n}_height_m"] is not None]
        if heights:
            lines.append("  planes from the sensor: " + ", ".join(f"{n} {h:+.2f} m" for n, h in heights))
        for name, shares in r["plane_classes"].items():
            top = ", ".join(f"{k} {v:.1%}" for k, v in shares.items() if v >= SHOWN_SHARE)
            lines.append(f"  {name} plane points: {top}")
        if r["median_confidence"] is not None:
            lines.append(
                f"  confidence: median {r['median_confidence']:.2f}, {r['uncertain_share']:.1%} of the map under "
                f"{UNCERTAIN:g} (drawn as uncertain)"
            )
        lines.append("  warnings: " + ("; ".join(r["warnings"]) if r["warnings"] else "none"))
    return "\n".join(lines)


def test_real_logs(tmp_path: Path) -> None:
    folder = data_folder()
    if folder is None or not folder.is_dir():
        pytest.skip("no shared/data/lidar above the checkout (set REAL_LIDAR)")
    logs = real_logs(folder)
    assert logs, f"no real logs in {folder}"
    rows = [measure(log, tmp_path / log.name) for log in logs]
    print(f"\n{len(logs)} real logs in {folder}; args: {' '.join(EXTRA_ARGS) or 'none'}\n" + report(rows))
    if path := os.environ.get("REAL_JSON"):
        Path(path).write_text(json.dumps(rows, indent=2) + "\n")
