"""Write a simulated mission as a ROS 2 MCAP: labelled PointCloud2 scans, the true pose, the scene's truth.

- `/lidar/points` (`sensor_msgs/msg/PointCloud2`, frame `lidar`): x y z intensity rgb (float32, rgb packed
  0x00RRGGBB; no rgb field for a mission without colour), t (uint32 ns after the header stamp), ring
  (uint16), class_id (uint16), instance_id (uint32). Points are in the sensor frame at the moment each was
  measured; the stamp is the sweep start. Logged when the sweep ends, as a driver would publish it.
- `/ground_truth/pose` (`geometry_msgs/msg/PoseStamped`, frame `map`): the sensor pose at the sweep start.
- Metadata `aftershock.simulator` (family, seed, sensor, story, scans, uri) and the attachment `truth.json`
  (stories, drift, tilt, cracks, instance classes).
Chunks are zstd-compressed; nothing depends on the clock, so a seed always gives the same bytes.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
from mcap.writer import CompressionType, Writer

from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.outputs import StreamedOutput, check_output
from aftershock.pipeline.pointcloud2 import (
    encode_pointcloud2,
    pose_stamped_message,
    register_cloud_and_pose,
    serialize_pointcloud2,
    serialize_pose_stamped,
)
from aftershock.pipeline.types import Scan
from aftershock.sources.simulator.scene import SceneTruth

POINTS_TOPIC: Final = "/lidar/points"
POSE_TOPIC: Final = "/ground_truth/pose"
MAP_FRAME: Final = "map"
CHUNK_BYTES: Final = 4 * 1024 * 1024


def pack_rgb(colors: np.ndarray) -> np.ndarray:
    c = np.asarray(colors, dtype=np.uint32)
    return ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).astype(np.uint32).view(np.float32)


def scan_columns(scan: Scan) -> dict[str, np.ndarray]:
    """The PointCloud2 columns of a simulated scan, in the documented field order."""
    assert scan.class_ids is not None and scan.instance_ids is not None, "a simulated scan carries its truth"
    n = len(scan)
    cols = {
        "x": scan.points[:, 0].astype(np.float32),
        "y": scan.points[:, 1].astype(np.float32),
        "z": scan.points[:, 2].astype(np.float32),
        "intensity": scan.intensity if scan.intensity is not None else np.zeros(n, np.float32),
    }
    if scan.colors is not None:  # a LiDAR without a camera has no rgb field at all, as on real robots
        cols["rgb"] = pack_rgb(scan.colors)
    cols.update(
        t=np.round((scan.times if scan.times is not None else np.zeros(n)) * 1e9).astype(np.uint32),
        ring=scan.ring if scan.ring is not None else np.zeros(n, np.uint16),
        class_id=scan.class_ids.astype(np.uint16),
        instance_id=scan.instance_ids.astype(np.uint32),
    )
    return cols


@dataclass(slots=True)
class MissionStats:
    scans: int = 0
    points: int = 0
    class_histogram: dict[int, int] = field(default_factory=dict)
    first_stamp_ns: int | None = None
    last_stamp_ns: int | None = None

    def add(self, scan: Scan) -> None:
        self.scans += 1
        self.points += len(scan)
        assert scan.class_ids is not None, "a simulated scan carries its truth"
        ids, counts = np.unique(scan.class_ids, return_counts=True)
        for i, c in zip(ids.tolist(), counts.tolist(), strict=True):
            self.class_histogram[i] = self.class_histogram.get(i, 0) + c
        if self.first_stamp_ns is None:
            self.first_stamp_ns = scan.stamp_ns
        self.last_stamp_ns = scan.stamp_ns


def truth_to_dict(truth: SceneTruth) -> dict:
    """The scene truth as plain JSON-ready data."""

    def arr(a: np.ndarray) -> list:
        return np.round(np.asarray(a, dtype=np.float64), 6).tolist()

    return {
        "family": truth.family,
        "seed": truth.seed,
        "footprint_m": list(truth.footprint_m),
        "stories": [
            {
                "index": s.index,
                "floor_z_m": s.floor_z_m,
                "ceiling_z_m": s.ceiling_z_m,
                "drift_x_mm": s.drift_x_mm,
                "drift_y_mm": s.drift_y_mm,
                "drift_mm": round(s.drift_mm, 3),
                "tilt_x_deg": s.tilt_x_deg,
                "tilt_y_deg": s.tilt_y_deg,
                "inter_story_drift_x_mm": s.inter_story_drift_x_mm,
                "inter_story_drift_y_mm": s.inter_story_drift_y_mm,
                "floor_plane": arr(s.floor_plane),
                "ceiling_plane": arr(s.ceiling_plane),
                "floor_instance_id": s.floor_instance_id,
                "ceiling_instance_id": s.ceiling_instance_id,
            }
            for s in truth.stories
        ],
        "levels": [
            {
                "index": lv.index,
                "z_m": lv.z_m,
                "drift_x_mm": lv.drift_x_mm,
                "drift_y_mm": lv.drift_y_mm,
                "tilt_x_deg": lv.tilt_x_deg,
                "tilt_y_deg": lv.tilt_y_deg,
            }
            for lv in truth.levels
        ],
        "cracks": [
            {
                "element_instance_id": c.element_instance_id,
                "element_class": c.element_class,
                "center": arr(c.center),
                "direction": arr(c.direction),
                "normal": arr(c.normal),
                "length_m": round(c.length_m, 6),
                "width_m": round(c.width_m, 6),
                "max_width_m": round(c.max_width_m, 6),
                "depth_m": round(c.depth_m, 6),
                "color": list(c.color),
                "polyline": arr(c.polyline),
            }
            for c in truth.cracks
        ],
        "instance_classes": {str(k): v for k, v in sorted(truth.instance_classes.items())},
    }


def write_mission(
    path: str | Path,
    scans: Iterable[Scan],
    *,
    truth: SceneTruth | None = None,
    metadata: dict[str, object] | None = None,  # written as strings
    force: bool = False,
) -> MissionStats:
    """Write scans (with ground truth) to an MCAP file; returns what was written."""
    p = check_output(path, force)
    stats = MissionStats()
    out = StreamedOutput(p)  # written as NAME.part and renamed when complete
    try:
        f = out.open("wb")
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", p) from None
    try:
        w = Writer(f, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="aftershock-simulator")
        points_ch, pose_ch = register_cloud_and_pose(w, POINTS_TOPIC, POSE_TOPIC)
        for seq, scan in enumerate(scans):
            if not scan.has_ground_truth or scan.gt_pose is None:
                raise ValueError("simulated scans carry class ids, instance ids and a true pose")
            msg = encode_pointcloud2(scan_columns(scan), stamp_ns=scan.stamp_ns, frame_id=scan.frame_id or "lidar")
            pose = pose_stamped_message(scan.gt_pose, scan.stamp_ns, MAP_FRAME)
            w.add_message(
                pose_ch,
                log_time=scan.stamp_ns,
                data=serialize_pose_stamped(pose),
                publish_time=scan.stamp_ns,
                sequence=seq,
            )
            log_time = scan.log_time_ns if scan.log_time_ns is not None else scan.stamp_ns
            w.add_message(
                points_ch, log_time=log_time, data=serialize_pointcloud2(msg), publish_time=log_time, sequence=seq
            )
            stats.add(scan)
        if metadata:
            w.add_metadata("aftershock.simulator", {k: str(v) for k, v in metadata.items()})
        if truth is not None:
            t0 = stats.first_stamp_ns or 0
            w.add_attachment(
                t0, t0, "truth.json", "application/json", json.dumps(truth_to_dict(truth), sort_keys=True).encode()
            )
        w.finish()
        f.flush()
    except OSError as exc:
        what = f"cannot write: {exc.strerror or exc}; the scans written before stay readable"
        raise OutputError(what, p) from None
    except BaseException:  # Ctrl-C, SIGTERM or a bad scan: no MCAP cut off mid-record is left behind
        out.discard()
        raise
    finally:
        with suppress(OSError):  # the buffer could not reach the disk either: the write error is reported
            out.close()
    return stats
