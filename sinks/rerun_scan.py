"""The per-scan layers of a recording: the raw scan, the robot's pose and trajectory, the scan's labels, the
debug layers at full resolution, and the text log of merges and flagged registrations (`sinks.rerun_sink` lists
the entities). Logged on whatever time the sink set for the scan.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import rerun as rr

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.types import Frame, InstanceMerge
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks import rerun_convert as C
from aftershock.sinks.rerun_convert import EmbeddingColors

TRAJECTORY_PIECE: Final = 100  # poses per trajectory strip (each scan re-logs its strip); older strips stay


def log_merges(rec: rr.RecordingStream, merges: list[InstanceMerge]) -> None:
    for m in merges:
        merged = ", ".join(str(i) for i in m.merged)
        rec.log(f"{L.LOG}/merges", rr.TextLog(f"scan {m.seq}: instances {merged} merged into {m.into}"))


def _world(frame: Frame) -> np.ndarray:
    """The scan's points in the world frame (zeros before registration placed them)."""
    return frame.world_points if frame.world_points is not None else np.zeros((len(frame.scan), 3))


def _kept(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """The world points the labelling stage kept, and their indices into the scan."""
    assert frame.map_rows is not None
    idx = frame.map_rows.points
    return _world(frame)[idx], idx


class ScanLayers:
    """Draws each stage of a scan; keeps the trajectory's newest strip and the frozen embedding colours."""

    def __init__(self, cfg: RerunConfig) -> None:
        self.cfg = cfg
        self._trajectory: list[np.ndarray] = []  # positions of the newest strip
        self._piece = 0
        self._embedding_colors = EmbeddingColors()

    def raw(self, rec: rr.RecordingStream, frame: Frame) -> None:
        """The raw scan in the sensor frame, downsampled to `cfg.raw_voxel_m`."""
        rec.log(L.RAW, C.raw_points(frame.scan, self.cfg.raw_voxel_m))

    def registered(self, rec: rr.RecordingStream, frame: Frame, tie_log_frame: bool) -> None:
        """The pose, the trajectory's newest strip and (debug) the registered scan; `tie_log_frame`: the log's
        own clouds (on the topic's entity, in their frame_id) follow the estimated pose."""
        if frame.pose is None:
            return
        pose = frame.pose
        if not self._trajectory and self._piece == 0:  # the robot's axes appear with its first pose
            rec.log(L.ROBOT, rr.TransformAxes3D(0.5), static=True)
            if tie_log_frame and frame.scan.frame_id:
                link = rr.Transform3D(child_frame=frame.scan.frame_id, parent_frame=f"tf#/{L.ROBOT}")
                rec.log(L.LOG_FRAME, link, static=True)
        rec.log(L.ROBOT, C.pose_transform(pose))
        if self.cfg.debug_layers and frame.world_points is not None:
            colors = C.scan_colors(frame.scan)
            rec.log(L.REGISTERED, rr.Points3D(frame.world_points, colors=colors, radii=C.SCAN_RADIUS))
        self._trajectory.append(pose[:3, 3].copy())
        rec.log(f"{L.TRAJECTORY}/p{self._piece}", C.trajectory_strip(self._trajectory))
        if len(self._trajectory) >= TRAJECTORY_PIECE:
            self._trajectory = [self._trajectory[-1]]
            self._piece += 1
        if not frame.registration_ok:
            note = f": {frame.registration_note}" if frame.registration_note else ""
            rec.log(f"{L.LOG}/registration", rr.TextLog(f"scan {frame.seq} flagged{note}", level="WARN"))

    def labelled(self, rec: rr.RecordingStream, frame: Frame) -> None:
        """Debug only: every kept point with its class, and (with `cfg.embeddings`) its embedding as a colour."""
        if frame.labels is None or frame.map_rows is None or not self.cfg.debug_layers:
            return
        pts, idx = _kept(frame)
        rec.log(L.LABELLED, rr.Points3D(pts, class_ids=frame.labels.class_ids[idx], radii=C.SCAN_RADIUS))
        if self.cfg.embeddings and frame.labels.embeddings is not None:
            colors = self._embedding_colors(frame.labels.embeddings[idx])
            rec.log(L.EMBEDDING, rr.Points3D(pts, colors=colors, radii=C.SCAN_RADIUS))

    def clustered(self, rec: rr.RecordingStream, frame: Frame) -> None:
        """The scan's labels, one point per map voxel, and the merges of this scan; (debug) every kept point by
        instance."""
        labels = frame.labels
        if labels is None or frame.map_rows is None:
            return
        if self.cfg.debug_layers:
            pts, idx = _kept(frame)
            rec.log(L.INSTANCES, *C.instance_points(pts, labels.class_ids[idx], labels.instance_ids[idx]))
        # The default layer: one point per map voxel (as the labelling stage found them), positions once, class
        # and instance beside them.
        one = frame.map_rows.first_points
        radius = C.MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m * 1.5
        conf = labels.scores[one] if labels.scores is not None else None
        points = C.labelled_points(_world(frame)[one], labels.class_ids[one], labels.instance_ids[one], radius, conf)
        rec.log(L.LABELS, *points)
        log_merges(rec, frame.merges)
