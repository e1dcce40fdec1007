"""Rerun sink: every stage of every scan, the growing labelled map and the on-demand layers, on shared timelines.

Timelines
- `scan`: the scan's sequence number.
- `sensor_time`: the scan's stamp as a timestamp; for MCAP inputs it is replaced by the two timelines of Rerun's
  own MCAP import, `message_log_time` (MCAP log time) and `ros2_timestamp` (header stamp), both absolute ns,
  so the recording and the imported log line up when opened together.
- `lrgnet_step`: one object's growth, step by step (only the `world/refined/growth` layer lives on it).

A recording holds what the log does not. When the viewer opens the log itself (MCAP with ROS 2 or
Foxglove point clouds, `RunInfo.raw_in_log`), raw scans are left out: the log's sensor frame (the scans'
`frame_id`, which Rerun's MCAP import puts on the topic's entity) is tied to `world/robot`, so the log's
own clouds appear at the estimated pose, and the recording id carries the log's fingerprint
(`recording_id_for`) so `aftershock view` can open both as one recording.

Entities (`world/` is the site, z up, with the class table as a static annotation context)
- `world/map/x{i}y{j}`: the accumulated labelled map (`class_ids`, `instance_id`, `confidence`: the
  labeller's probability for the class), voxel-downsampled to
  `cfg.map_voxel_m` and cut into square tiles of `cfg.map_tile_m`; at each map update (the stream sends one
  every `map_every` scans) only the tiles that changed are re-logged (only their labels when their points
  stayed), so a long mission stays light in the file and fluid in the viewer. `world/uncertain/x{i}y{j}`: the
  tile's voxels with a confidence under `cfg.uncertain_below`, drawn larger in magenta over the map.
- `world/trajectory/p{k}`: the estimated trajectory as line strips of up to `TRAJECTORY_PIECE` poses; only the
  newest piece is re-logged per scan.
- `world/robot`: the pose (Transform3D, world <- sensor); `world/robot/raw` the raw scan in the sensor frame,
  downsampled to `cfg.raw_voxel_m`, only when the log cannot be opened beside the recording;
  `world/robot/log_frame` ties the log's sensor frame to the pose when it can.
- `world/scan/labels`: per scan, the points kept for labelling, one per voxel of `cfg.map_voxel_m`, with their
  `class_ids` and an `instance_id` component (positions once, both labels beside them).
- With `cfg.debug_layers` only, at full resolution: `world/scan/registered` (the deskewed scan in the world
  frame), `world/scan/labelled` (every kept point with its class), `world/scan/instances` (instance colours,
  `class_ids`, `instance_id`) and `world/scan/embedding` (MCPNet embeddings as colours).
- `world/refined` (+ `growth/inliers`, `growth/neighbours`): LRGNet's segmentation and one object's growth.
- `world/damage/crack_points`, `world/damage/cracks` (boxes labelled with length and width),
  `world/damage/stories/s{i}` (story planes), `world/damage/drift` (drift arrows, exaggerated, labelled in mm).
- `stats/time_ms/<stage>` and `stats/counts/<name>`: scalars per scan; `log/...`: merges, registration
  warnings, the run summary and its `warnings` (scans unlike the networks' training data) as text log entries.

The sink keeps the hooks and the time bookkeeping: `rerun_convert` turns our types into Rerun archetypes,
`rerun_tiles` decides which map tiles changed, `rerun_stats` batches the per-scan scalars, and
`rerun_output` owns the file and viewers and what happens when the disk fills.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final

import numpy as np
import rerun as rr

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.types import Crack, Frame, InstanceMerge, LabelledCloud, RunInfo, RunSummary, Scan, Story
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks import rerun_convert as C
from aftershock.sinks.rerun_convert import EmbeddingColors
from aftershock.sinks.rerun_output import RecordingOutput, log_id_of, recording_id_for
from aftershock.sinks.rerun_stats import ScanScalars
from aftershock.sinks.rerun_tiles import MapTiles
from aftershock.sinks.structure_layer import log_structure

__all__ = ["EmbeddingColors", "RerunSink", "log_id_of", "recording_id_for"]

TRAJECTORY_PIECE: Final = 100  # poses per trajectory strip (each scan re-logs its strip); older strips stay


class RerunSink(Sink):
    """Streams a run to an .rrd file, a spawned viewer and/or a remote viewer (any combination).

    The output path and URL are checked when the sink is made; the file is created and the viewer spawned
    in `begin`.
    """

    def __init__(
        self,
        save: Path | None,
        spawn: bool,
        connect: str | None,
        cfg: RerunConfig,
        force: bool = False,
        application_id: str = "aftershock",
    ) -> None:
        self.cfg = cfg
        self.out = RecordingOutput(save, spawn, connect, force, application_id, cfg.compact_above_mb)
        self._info = RunInfo(source="", source_kind="")
        self._mcap_times = False
        self._scan: Scan | None = None  # the scan whose times are currently set
        self._stats = ScanScalars()
        self._trajectory: list[np.ndarray] = []
        self._piece = 0
        self._tiles = MapTiles(cfg.map_voxel_m, cfg.map_tile_m)
        self._uncertain: set[str] = set()  # the uncertain-voxel tiles logged and not cleared
        self._embedding_colors = EmbeddingColors()

    @property
    def rec(self) -> rr.RecordingStream:
        return self.out.rec

    @property
    def path(self) -> Path | None:
        return self.out.path

    @property
    def raw_in_recording(self) -> bool:
        """Raw scans go into the recording unless the viewer can open the log beside it."""
        return self.cfg.raw_points and not self._info.raw_in_log

    # ------------------------------------------------------------------------------------------ hooks

    def begin(self, info: RunInfo) -> None:
        self.out.name_after(info.log_id)
        self._info = info
        self._start()
        self._mcap_times = info.source_kind == "mcap"
        self.rec.send_recording_name(Path(info.source).name or info.source)
        self.rec.log(f"{L.LOG}/run", rr.TextLog(C.run_text(info), level="INFO"), static=True)

    def _start(self) -> None:
        """Open the outputs (in `begin`, or with the first data when a command has no run to begin): a run
        refused before its first scan leaves no empty recording behind."""
        if self.out.started:
            return
        self._check_room()  # before the file is made: a full disk leaves nothing behind
        log_topic = self._info.topic if self._info.raw_in_log else None
        self.out.start(L.default_blueprint(log_topic=log_topic))
        self.rec.log(L.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, C.annotation_context(), static=True)
        discs, names = L.legend()
        self.rec.log(L.LEGEND_SWATCHES, discs, static=True)
        self.rec.log(L.LEGEND_NAMES, names, static=True)

    def stage(self, frame: Frame, stage: Stage) -> None:
        self._start()
        if stage is Stage.RAW:
            self._check_room()
        self._set_time(frame.scan)
        if stage is Stage.RAW:
            self._log_raw(frame)
        elif stage is Stage.REGISTERED:
            self._log_registered(frame)
        elif stage is Stage.LABELLED:
            self._log_labelled(frame)
        elif stage is Stage.CLUSTERED:
            self._log_clustered(frame)
        self._stats.record(frame, self._mcap_times)

    def map_update(self, cloud: LabelledCloud, seq: int) -> None:
        self._start()
        if self._scan is None or self._scan.seq != seq:
            self.rec.set_time(L.SCAN_TIMELINE, sequence=seq)
        self._log_map(cloud)

    def structure(self, elements: list[Element], seq: int, notes: list[str]) -> None:
        self._start()
        if self._scan is None or self._scan.seq != seq:
            self.rec.set_time(L.SCAN_TIMELINE, sequence=seq)
        log_structure(self.rec, elements)

    def refined(self, cloud: LabelledCloud, steps: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        self._start()
        self.rec.log(L.REFINED, *C.refined_points(cloud), static=self._scan is None)
        if not steps:
            return
        self.rec.reset_time()
        for i, (inliers, neighbours) in enumerate(steps):
            self.rec.set_time(L.LRGNET_STEP_TIMELINE, sequence=i)
            inlier_points, neighbour_points = C.growth_points(cloud, inliers, neighbours)
            self.rec.log(f"{L.REFINED_GROWTH}/inliers", inlier_points)
            self.rec.log(f"{L.REFINED_GROWTH}/neighbours", neighbour_points)
            self.rec.log(
                f"{L.LOG}/lrgnet",
                rr.TextLog(f"step {i}: {len(inliers)} inliers, {len(neighbours)} neighbours", level="DEBUG"),
            )
        self.rec.reset_time()
        if self._scan is not None:
            self._set_time(self._scan)

    def damage(
        self,
        cracks: list[Crack],
        crack_points: LabelledCloud | None,
        stories: list[Story],
        report: dict[str, Any] | None = None,
    ) -> None:
        self._start()
        static = self._scan is None
        if crack_points is not None and len(crack_points):
            self.rec.log(L.CRACK_POINTS, *C.crack_points(crack_points), static=static)
        if cracks:
            self.rec.log(L.CRACKS, C.crack_boxes(cracks), static=static)
        if stories:
            planes, arrows = C.story_layers(stories, self._tiles.bounds)
            for index, box, tag in planes:
                self.rec.log(f"{L.STORIES}/s{index}", box, static=static)
                self.rec.log(f"{L.STORIES}/s{index}/label", tag, static=static)
            if arrows is not None:
                self.rec.log(L.DRIFT, arrows, static=static)

    def merges(self, merges: list[InstanceMerge], seq: int) -> None:
        for m in merges:
            merged = ", ".join(str(i) for i in m.merged)
            self.rec.log(f"{L.LOG}/merges", rr.TextLog(f"scan {m.seq}: instances {merged} merged into {m.into}"))

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self._start()
        self._stats.flush(self.rec)
        if len(final_map):
            self._log_map(final_map)
        self.rec.log(f"{L.LOG}/summary", rr.TextLog(C.summary_text(summary), level="INFO"))
        for warning in summary.warnings:  # what the run warned of once (scans unlike the training data)
            self.rec.log(f"{L.LOG}/warnings", rr.TextLog(warning, level="WARN"))

    def close(self) -> None:
        if self.out.closed:
            return
        if self._stats:  # scalars of scans after `end` (or without one) still reach the file
            self._stats.flush(self.rec)
        self.out.close()

    def _check_room(self) -> None:
        """Stop the recording, readable, while the disk still has room for what is in flight."""
        error = self.out.room_error()
        if error is None:
            return
        if self.out.file_made:
            self.close()  # later layers go nowhere: the stream stops on this error and finishes the other outputs
        raise error

    # ------------------------------------------------------------------------------------------ layers

    def _set_time(self, scan: Scan) -> None:
        self._scan = scan
        self._stats.next_scan(scan.seq, self.rec)
        self.rec.set_time(L.SCAN_TIMELINE, sequence=scan.seq)
        if self._mcap_times and scan.log_time_ns is not None:
            self.rec.set_time(L.MCAP_LOG_TIMELINE, timestamp=C.datetime(scan.log_time_ns))
            self.rec.set_time(L.MCAP_STAMP_TIMELINE, timestamp=C.datetime(scan.stamp_ns))
        else:
            self.rec.set_time(L.SENSOR_TIMELINE, timestamp=C.datetime(scan.stamp_ns))

    def _log_raw(self, frame: Frame) -> None:
        if self.raw_in_recording:
            self.rec.log(L.RAW, C.raw_points(frame.scan, self.cfg.raw_voxel_m))

    def _log_registered(self, frame: Frame) -> None:
        if frame.pose is None:
            return
        pose = frame.pose
        if not self._trajectory and self._piece == 0:  # the robot's axes appear with its first pose
            self.rec.log(L.ROBOT, rr.TransformAxes3D(0.5), static=True)
            if self._info.raw_in_log and frame.scan.frame_id:
                # The log's clouds (on the topic's entity, in their frame_id) follow the estimated pose.
                link = rr.Transform3D(child_frame=frame.scan.frame_id, parent_frame=f"tf#/{L.ROBOT}")
                self.rec.log(L.LOG_FRAME, link, static=True)
        self.rec.log(L.ROBOT, C.pose_transform(pose))
        if self.cfg.debug_layers and frame.world_points is not None:
            colors = C.scan_colors(frame.scan)
            self.rec.log(L.REGISTERED, rr.Points3D(frame.world_points, colors=colors, radii=C.SCAN_RADIUS))
        self._trajectory.append(pose[:3, 3].copy())
        self.rec.log(f"{L.TRAJECTORY}/p{self._piece}", C.trajectory_strip(self._trajectory))
        if len(self._trajectory) >= TRAJECTORY_PIECE:
            self._trajectory = [self._trajectory[-1]]
            self._piece += 1
        if not frame.registration_ok:
            note = f": {frame.registration_note}" if frame.registration_note else ""
            self.rec.log(f"{L.LOG}/registration", rr.TextLog(f"scan {frame.seq} flagged{note}", level="WARN"))

    @staticmethod
    def _kept(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """The world points the labelling stage kept, and their indices into the scan."""
        assert frame.map_rows is not None
        idx = frame.map_rows.points
        world = frame.world_points if frame.world_points is not None else np.zeros((len(frame.scan), 3))
        return world[idx], idx

    def _log_labelled(self, frame: Frame) -> None:
        if frame.labels is None or frame.map_rows is None or not self.cfg.debug_layers:
            return
        pts, idx = self._kept(frame)
        self.rec.log(L.LABELLED, rr.Points3D(pts, class_ids=frame.labels.class_ids[idx], radii=C.SCAN_RADIUS))
        if self.cfg.embeddings and frame.labels.embeddings is not None:
            colors = self._embedding_colors(frame.labels.embeddings[idx])
            self.rec.log(L.EMBEDDING, rr.Points3D(pts, colors=colors, radii=C.SCAN_RADIUS))

    def _log_clustered(self, frame: Frame) -> None:
        labels = frame.labels
        if labels is None or frame.map_rows is None:
            return
        if self.cfg.debug_layers:
            pts, idx = self._kept(frame)
            self.rec.log(L.INSTANCES, *C.instance_points(pts, labels.class_ids[idx], labels.instance_ids[idx]))
        # The default layer: one point per map voxel (as the labelling stage found them), positions once, class
        # and instance beside them.
        one = frame.map_rows.first_points
        world = frame.world_points if frame.world_points is not None else np.zeros((len(frame.scan), 3))
        radius = C.MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m * 1.5
        conf = labels.scores[one] if labels.scores is not None else None
        self.rec.log(
            L.LABELS, *C.labelled_points(world[one], labels.class_ids[one], labels.instance_ids[one], radius, conf)
        )
        self.merges(frame.merges, frame.seq)

    def _log_map(self, cloud: LabelledCloud) -> None:
        """Re-log only the map tiles whose content changed since the last update (`rerun_tiles`)."""
        update = self._tiles.update(cloud)
        if update is None:
            return
        radius = C.MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m
        colors = update.colors
        for tile in update.changed:
            name, sel = f"{L.MAP}/{tile.name}", tile.sel
            conf = update.confidence[sel] if update.confidence is not None else None
            self._log_uncertain(tile.name, update.points[sel], conf)
            if tile.labels_only:
                self.rec.log(name, *C.tile_labels(update.class_ids[sel], update.instance_ids[sel], conf))
                continue
            cls = update.class_ids[sel] if colors is None else None
            tile_colors = colors[sel] if colors is not None else None
            self.rec.log(
                name, *C.map_tile(update.points[sel], cls, tile_colors, update.instance_ids[sel], radius, conf)
            )
        for gone in update.gone:
            self.rec.log(f"{L.MAP}/{gone}", rr.Clear(recursive=False))
            self._log_uncertain(gone, np.zeros((0, 3)), None)

    def _log_uncertain(self, tile: str, points: np.ndarray, confidence: np.ndarray | None) -> None:
        """The tile's voxels under `cfg.uncertain_below`, over the map in one colour (cleared when none is left)."""
        name = f"{L.UNCERTAIN}/{tile}"
        low = np.zeros(len(points), bool) if confidence is None else confidence < self.cfg.uncertain_below
        if confidence is not None and low.any():
            self._uncertain.add(name)
            radius = C.UNCERTAIN_RADIUS_OF_VOXEL * self.cfg.map_voxel_m
            self.rec.log(name, *C.uncertain_points(points[low], confidence[low], radius))
        elif name in self._uncertain:
            self._uncertain.discard(name)
            self.rec.log(name, rr.Clear(recursive=False))
