"""Agreement of labels with planes found without the labeller, on exported maps of the real logs (issue #28's
measure; `make bench-real` is the project's benchmark of it, this is the structure model's quick check).

    python tests/bench/structure_planes_check.py EXPORTS   # EXPORTS/<log>/map.ply and poses_tum.txt per real log

Planes by RANSAC (open3d, 5 cm, at least 2 % of the map, the largest connected piece of each): the lowest large
horizontal plane below the sensor is floor (ground outdoors), the highest above it ceiling, vertical planes at least
1.2 m tall and 1.5 m wide walls; the share of each plane's points with that label, and the map's class shares.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from plyfile import PlyData

from aftershock.pipeline.classes import CLASS_NAMES, SemanticClass

LOGS = ("ouster_os1_64_ros1", "velodyne_vlp16_indoor", "room_scan1", "room_scan2", "ouster_os1_128_outdoor")


def load(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v = PlyData.read(str(folder / "map.ply"))["vertex"]
    pts = np.c_[v["x"], v["y"], v["z"]].astype(np.float64)
    poses = np.loadtxt(folder / "poses_tum.txt", ndmin=2)
    return pts, np.asarray(v["class_id"]).astype(np.int64), poses[:, 1:4]


def planes(pts: np.ndarray, max_planes: int = 15) -> list[tuple[np.ndarray, np.ndarray]]:
    rest = np.arange(len(pts))
    out = []
    least = max(60, int(0.02 * len(pts)))
    o3d.utility.random.seed(0)
    for _ in range(max_planes):  # one iteration per plane
        if len(rest) < least:
            break
        model, inl = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[rest])).segment_plane(0.05, 3, 1000)
        inl = np.asarray(inl)
        if len(inl) < least:
            break
        idx = rest[inl]
        pieces = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[idx])).cluster_dbscan(0.35, 3))
        if (pieces >= 0).any():
            idx = idx[pieces == np.bincount(pieces[pieces >= 0]).argmax()]
        if len(idx) >= least:
            out.append((np.asarray(model[:3]), idx))
        rest = np.setdiff1d(rest, rest[inl])
    return out


def check(folder: Path, outdoor: bool) -> dict[str, Any]:
    pts, cls, traj = load(folder)
    sensor_z = float(np.median(traj[:, 2]))
    shares = np.bincount(cls[cls < len(CLASS_NAMES)], minlength=len(CLASS_NAMES)) / len(cls)
    res: dict[str, Any] = {"points": len(pts)}
    res["shares"] = {CLASS_NAMES[i]: round(float(s), 3) for i, s in enumerate(shares) if s >= 0.01}
    flat, walls = [], []
    for n, idx in planes(pts):
        if abs(n[2]) > 0.95:
            flat.append((float(np.median(pts[idx, 2])), idx))
        elif abs(n[2]) < 0.1:
            along = np.array([-n[1], n[0], 0.0]) / np.linalg.norm(n[:2])
            if np.ptp(pts[idx, 2]) >= 1.2 and np.ptp(pts[idx] @ along) >= 1.5:
                walls.append(idx)
    below = [p for p in flat if p[0] < sensor_z - 0.3]
    above = [p for p in flat if p[0] > sensor_z + 0.3]
    floor = SemanticClass.GROUND if outdoor else SemanticClass.FLOOR
    if below:
        z, idx = min(below, key=lambda p: p[0])
        res["floor_plane"] = (round(z, 2), len(idx), round(float(np.mean(cls[idx] == floor)), 3))
    if above and not outdoor:
        z, idx = max(above, key=lambda p: p[0])
        res["ceiling_plane"] = (round(z, 2), len(idx), round(float(np.mean(cls[idx] == SemanticClass.CEILING)), 3))
    if walls:
        on = np.concatenate(walls)
        res["walls"] = (len(walls), len(on), round(float(np.mean(cls[on] == SemanticClass.WALL)), 3))
    res["ceiling_below_sensor"] = int(np.sum((cls == SemanticClass.CEILING) & (pts[:, 2] < sensor_z)))
    res["floor_above_sensor"] = int(np.sum((cls == SemanticClass.FLOOR) & (pts[:, 2] > sensor_z)))
    return res


if __name__ == "__main__":
    root = Path(sys.argv[1])
    for name in LOGS:
        if (root / name / "map.ply").is_file():
            print(name, json.dumps(check(root / name, "outdoor" in name)))
