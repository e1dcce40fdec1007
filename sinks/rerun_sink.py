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
- `world/trajectory/p{k}`: the estimated trajectory as line strips of up to `rerun_scan.TRAJECTORY_PIECE` poses;
  only the newest piece is re-logged per scan.
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

The sink keeps the hooks and the time bookkeeping: `rerun_scan` draws each stage of a scan, `rerun_map` the map
tiles (`rerun_tiles` decides which changed), `rerun_on_demand` LRGNet's segmentation and the damage;
`rerun_convert` turns our types into Rerun archetypes, `rerun_stats` batches the per-scan scalars, and
`rerun_output` owns the file and viewers and what happens when the disk fills.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.types import DamageFound, Frame, InstanceMerge, LabelledCloud, RunInfo, RunSummary, Scan
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks import rerun_convert as C
from aftershock.sinks.rerun_convert import EmbeddingColors
from aftershock.sinks.rerun_map import MapLayer
from aftershock.sinks.rerun_on_demand import log_damage, log_refined
from aftershock.sinks.rerun_output import RecordingOutput, log_id_of, recording_id_for
from aftershock.sinks.rerun_scan import ScanLayers, log_merges
from aftershock.sinks.rerun_stats import ScanScalars
from aftershock.sinks.structure_layer import log_structure

__all__ = ["EmbeddingColors", "RerunSink", "log_id_of", "recording_id_for"]


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
        self._scans = ScanLayers(cfg)
        self._map = MapLayer(cfg)

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
        if stage is Stage.RAW and self.raw_in_recording:
            self._scans.raw(self.rec, frame)
        elif stage is Stage.REGISTERED:
            self._scans.registered(self.rec, frame, tie_log_frame=self._info.raw_in_log)
        elif stage is Stage.LABELLED:
            self._scans.labelled(self.rec, frame)
        elif stage is Stage.CLUSTERED:
            self._scans.clustered(self.rec, frame)
        self._stats.record(frame, self._mcap_times)

    def map_update(self, cloud: LabelledCloud, seq: int) -> None:
        self._start()
        self._set_seq(seq)
        self._map.log(self.rec, cloud)

    def structure(self, elements: list[Element], seq: int, notes: list[str]) -> None:
        self._start()
        self._set_seq(seq)
        log_structure(self.rec, elements)

    def refined(self, cloud: LabelledCloud, steps: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        self._start()
        log_refined(self.rec, cloud, steps or [], static=self._scan is None)
        if steps and self._scan is not None:  # the growth steps cleared the scan's times
            self._set_time(self._scan)

    def damage(self, found: DamageFound) -> None:
        self._start()
        log_damage(self.rec, found, self._map.bounds, static=self._scan is None)

    def merges(self, merges: list[InstanceMerge], seq: int) -> None:
        log_merges(self.rec, merges)

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self._start()
        self._stats.flush(self.rec)
        if len(final_map):
            self._map.log(self.rec, final_map)
        self.rec.log(f"{L.LOG}/summary", rr.TextLog(C.summary_text(summary), level="INFO"))
        for warning in summary.warnings:  # what the run warned of once (scans unlike the training data)
            self.rec.log(f"{L.LOG}/warnings", rr.TextLog(warning, level="WARN"))

    def close(self) -> None:
        if self.out.closed:
            return
        if self._stats:  # scalars of scans after `end` (or without one) still reach the file
            self._stats.flush(self.rec)
        self.out.close()

    # ------------------------------------------------------------------------------------------ bookkeeping

    def _check_room(self) -> None:
        """Stop the recording, readable, while the disk still has room for what is in flight."""
        error = self.out.room_error()
        if error is None:
            return
        if self.out.file_made:
            self.close()  # later layers go nowhere: the stream stops on this error and finishes the other outputs
        raise error

    def _set_time(self, scan: Scan) -> None:
        self._scan = scan
        self._stats.next_scan(scan.seq, self.rec)
        self.rec.set_time(L.SCAN_TIMELINE, sequence=scan.seq)
        if self._mcap_times and scan.log_time_ns is not None:
            self.rec.set_time(L.MCAP_LOG_TIMELINE, timestamp=C.datetime(scan.log_time_ns))
            self.rec.set_time(L.MCAP_STAMP_TIMELINE, timestamp=C.datetime(scan.stamp_ns))
        else:
            self.rec.set_time(L.SENSOR_TIMELINE, timestamp=C.datetime(scan.stamp_ns))

    def _set_seq(self, seq: int) -> None:
        """Data of scan `seq` that comes outside its frame (the map, the structure) goes on that scan."""
        if self._scan is None or self._scan.seq != seq:
            self.rec.set_time(L.SCAN_TIMELINE, sequence=seq)
