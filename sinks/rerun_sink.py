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
- `world/map/x{i}y{j}`: the accumulated labelled map (`class_ids`, `instance_id`), voxel-downsampled to
  `cfg.map_voxel_m` and cut into square tiles of `cfg.map_tile_m`; at each map update (the stream sends one
  every `map_every` scans) only the tiles that changed are re-logged (only their labels when their points
  stayed), so a long mission stays light in the file and fluid in the viewer.
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
  warnings and the run summary as text log entries.
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from pathlib import Path
from typing import Any, Final
from urllib.parse import urlsplit

import numpy as np
import rerun as rr

from aftershock.pipeline.classes import CLASS_COLORS, CLASS_NAMES, UNLABELLED, UNLABELLED_COLOR, instance_colors
from aftershock.pipeline.cloud_io import check_output
from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.geometry import voxel_downsample
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.types import Crack, Frame, InstanceMerge, LabelledCloud, RunInfo, RunSummary, Scan, Story
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks.rrd_compact import compact
from aftershock.sinks.structure_layer import log_structure

TRAJECTORY_PIECE: Final = 100  # poses per trajectory strip (each scan re-logs its strip); older strips stay
DRIFT_ARROW_M_PER_MM: Final = 0.05  # drift arrows are drawn 50 times larger than life (1 mm -> 5 cm)
SPAWN_PORT: Final = 9876
BATCH_SECONDS: Final = 1.0
BATCH_BYTES: Final = 16 * 2**20
# Rerun's file writer cannot recover from a full disk: its thread dies and every later flush, disconnect and
# even the interpreter's exit wait for ever. So the recording stops while this much room is left (a batch in
# flight plus a scan's layers fit), and a flush that makes no progress for FLUSH_STALL_S is given up.
MIN_FREE_BYTES: Final = 3 * BATCH_BYTES
FLUSH_POLL_S: Final = 0.5
FLUSH_STALL_S: Final = 10.0
_WRITE_FAILED: Final = "writing the recording failed"
FIT_SAMPLE: Final = 20_000  # embeddings the colour projection is fitted on
STATS_EVERY: Final = 10  # per-scan scalars go out as columns every this many scans (live plots lag by as much)
RECORDING_ID_PREFIX: Final = "aftershock-"

SCAN_RADIUS: Final = rr.Radius.ui_points(1.5)
MAP_RADIUS_OF_VOXEL: Final = 0.2  # map points drawn with a world-space radius of this fraction of the voxel
CRACK_RADIUS: Final = rr.Radius.ui_points(3.0)
TRAJECTORY_COLOR: Final = (255, 210, 0)
GROWTH_INLIER_COLOR: Final = (60, 220, 90)
GROWTH_NEIGHBOUR_COLOR: Final = (255, 200, 40)
CRACK_COLOR: Final = (255, 30, 60)
MILD_CRACK_COLOR: Final = (255, 150, 0)

# A perceptually ordered ramp (viridis stops) for intensity colouring, interpolated per channel.
_RAMP: Final = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64)


def annotation_context() -> rr.AnnotationContext:
    """The class table (and the unlabelled id) as a Rerun annotation context."""
    infos = [(i, name, tuple(int(c) for c in CLASS_COLORS[i])) for i, name in enumerate(CLASS_NAMES)]
    infos.append((UNLABELLED, "unlabelled", tuple(int(c) for c in UNLABELLED_COLOR)))
    return rr.AnnotationContext(infos)


def ramp_colors(values: np.ndarray) -> np.ndarray:
    """Colours (N, 3) uint8 for scalar values, stretched between their 2nd and 98th percentiles."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(v) == 0:
        return np.zeros((0, 3), np.uint8)
    finite = v[np.isfinite(v)]
    lo, hi = np.percentile(finite, [2, 98]) if len(finite) else (0.0, 1.0)
    t = np.clip((np.nan_to_num(v, nan=lo) - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(_RAMP) - 1)
    stops = np.arange(len(_RAMP))
    return np.stack([np.interp(t, stops, _RAMP[:, c]) for c in range(3)], axis=1).astype(np.uint8)


class EmbeddingColors:
    """Embeddings (N, D) to RGB with a PCA fitted on the first batch and then frozen, so colours stay
    comparable from scan to scan."""

    def __init__(self) -> None:
        self.mean: np.ndarray | None = None
        self.axes: np.ndarray | None = None  # (D, 3)
        self.scale: np.ndarray | None = None  # (3,)

    def __call__(self, embeddings: np.ndarray) -> np.ndarray:
        e = np.asarray(embeddings, dtype=np.float32)
        if self.axes is None or self.axes.shape[0] != e.shape[1]:
            self._fit(e[:: max(1, len(e) // FIT_SAMPLE)].astype(np.float64))
        assert self.mean is not None and self.axes is not None and self.scale is not None
        # 0.5 + 0.5 * (e - mean) @ axes / scale, folded into one affine map
        gain = (0.5 * self.axes / self.scale).astype(np.float32)
        offset = (0.5 - self.mean @ (0.5 * self.axes / self.scale)).astype(np.float32)
        return (np.clip(e @ gain + offset, 0.0, 1.0) * 255).astype(np.uint8)

    def _fit(self, e: np.ndarray) -> None:
        d = e.shape[1]
        self.mean = e.mean(axis=0) if len(e) else np.zeros(d)
        axes = np.zeros((d, 3))
        if len(e) >= 2:
            _, _, vt = np.linalg.svd(e - self.mean, full_matrices=False)
            k = min(3, vt.shape[0])
            axes[:, :k] = vt[:k].T
        else:
            axes[: min(d, 3), : min(d, 3)] = np.eye(min(d, 3))
        self.axes = axes
        spread = ((e - self.mean) @ axes).std(axis=0) if len(e) >= 2 else np.ones(3)
        self.scale = np.maximum(2.0 * spread, 1e-6)


def recording_id_for(log_id: str) -> str:
    """A fresh recording id that names the log it was made from (`view` checks it): aftershock-<log>-<run>."""
    run = uuid.uuid4().hex[:12]
    return f"{RECORDING_ID_PREFIX}{log_id}-{run}" if log_id else f"{RECORDING_ID_PREFIX}{run}"


def log_id_of(recording_id: str) -> str | None:
    """The log fingerprint a recording id carries (None for recordings of inputs without one)."""
    if not recording_id.startswith(RECORDING_ID_PREFIX):
        return None
    parts = recording_id[len(RECORDING_ID_PREFIX) :].split("-")
    return parts[0] if len(parts) == 2 else None


def _listening(url: str, timeout_s: float = 2.0) -> bool:
    """Whether something accepts TCP connections at the host and port of a Rerun gRPC URL (True if no port)."""
    parts = urlsplit(url.replace("rerun+", "", 1))
    if parts.hostname is None or parts.port is None:
        return True
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout_s):
            return True
    except OSError:
        return False


def _datetime(ns: int) -> np.datetime64:
    return np.datetime64(int(ns), "ns")


def _world_points(frame: Frame) -> np.ndarray:
    if frame.world_points is not None:
        return frame.world_points
    pts = frame.scan.points
    if frame.pose is None:
        return pts
    return pts @ frame.pose[:3, :3].T + frame.pose[:3, 3]


def _scan_colors(scan: Scan) -> np.ndarray | None:
    if scan.colors is not None:
        return scan.colors
    if scan.intensity is not None:
        return ramp_colors(scan.intensity)
    return None


def _instance_colors(ids: np.ndarray) -> np.ndarray:
    """`instance_colors` computed once per distinct id (a scan has many points but few instances)."""
    unique, inverse = np.unique(ids, return_inverse=True)
    return instance_colors(unique)[inverse.reshape(-1)]


def _tile_name(ix: int, iy: int) -> str:
    return f"x{ix}y{iy}".replace("-", "m")


def _content_hash(points: np.ndarray, class_ids: np.ndarray, instance_ids: np.ndarray) -> np.ndarray:
    """A 64-bit hash per point of its position (mm) and labels; summing them gives an order-free tile hash."""
    mm = np.round(points * 1000.0).astype(np.int64).view(np.uint64)
    h = mm[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    h ^= mm[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= mm[:, 2] * np.uint64(0x165667B19E3779F9)
    h ^= class_ids.astype(np.uint64) * np.uint64(0x27D4EB2F165667C5)
    h ^= instance_ids.astype(np.uint64) * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(29))


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
        if save is None and not spawn and connect is None:
            raise ValueError("RerunSink needs at least one of save, spawn or connect")
        self.cfg = cfg
        self.path = check_output(save, force) if save is not None else None
        self.spawn = spawn
        self._sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self.path is not None:
            self._sinks.append(rr.FileSink(self.path))
        self._viewer_url = connect or f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"
        if connect is not None:
            try:
                self._sinks.append(rr.GrpcSink(connect))
            except (ValueError, RuntimeError) as exc:
                raise OutputError(f"not a Rerun gRPC URL ({exc})", connect) from None
            if not _listening(connect):
                raise OutputError("no Rerun viewer is listening there (start one with `rerun`)", connect)
        # Larger, rarer chunks than the default (200 ms, 2 MiB): the file's footer keeps ~0.4 kB per chunk in
        # memory until the end, so fewer chunks keep a long mission's memory flat; live viewers lag <= 1 s.
        self._batcher = rr.ChunkBatcherConfig(flush_tick=BATCH_SECONDS, flush_num_bytes=BATCH_BYTES)
        self._application_id = application_id
        self.rec = self._new_stream("")
        self._closed = False
        self._info = RunInfo(source="", source_kind="")
        self._started = False
        self._mcap_times = False
        self._scan: Scan | None = None  # the scan whose times are currently set
        self._stats_logged: set[str] = set()  # what was already logged for the scan `_stats_seq`
        self._stats_seq: int | None = None
        self._stats: dict[str, list[tuple[int, int | None, int, float]]] = {}  # entity -> (seq, log, stamp, value)
        self._stats_scans = 0  # scans buffered in `_stats`
        self._trajectory: list[np.ndarray] = []
        self._piece = 0
        self._tiles: dict[str, tuple[int, int, int]] = {}  # tile -> (points, position hash, label hash)
        self._map_bounds: tuple[np.ndarray, np.ndarray] | None = None
        self._embedding_colors = EmbeddingColors()

    # ------------------------------------------------------------------------------------------ hooks

    def _new_stream(self, log_id: str) -> rr.RecordingStream:
        rec = rr.RecordingStream(
            self._application_id, recording_id=recording_id_for(log_id), batcher_config=self._batcher
        )
        rr.set_log_time_enabled(False, recording=rec)  # wall-clock time of logging says nothing here
        return rec

    @property
    def raw_in_recording(self) -> bool:
        """Raw scans go into the recording unless the viewer can open the log beside it."""
        return self.cfg.raw_points and not self._info.raw_in_log

    def begin(self, info: RunInfo) -> None:
        if not self._started and info.log_id:
            self.rec = self._new_stream(info.log_id)
        self._info = info
        self._start()
        self._mcap_times = info.source_kind == "mcap"
        self.rec.send_recording_name(Path(info.source).name or info.source)
        what = f"source {info.source} ({info.source_kind}"
        what += f", topic {info.topic})" if info.topic else ")"
        what += f", {info.environment}, labeller {info.labeller or 'none'}"
        self.rec.log(f"{L.LOG}/run", rr.TextLog(what, level="INFO"), static=True)

    def _start(self) -> None:
        """Open the outputs (in `begin`, or with the first data when a command has no run to begin): a run
        refused before its first scan leaves no empty recording behind."""
        if self._started:
            return
        self._check_room()  # before the file is made: a full disk leaves nothing behind
        self._started = True
        if self.spawn:  # a viewer of this environment on 127.0.0.1 (the one already there is reused)
            from aftershock.sinks.rerun_viewer import start_viewer

            self._sinks.append(rr.GrpcSink(start_viewer(port=SPAWN_PORT).grpc_url))
        log_topic = self._info.topic if self._info.raw_in_log else None
        self.rec.set_sinks(*self._sinks, default_blueprint=L.default_blueprint(log_topic=log_topic))
        self.rec.log(L.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, annotation_context(), static=True)

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
        self._log_stats(frame)

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
        static = self._scan is None
        colors = _instance_colors(cloud.instance_ids) if cloud.instance_ids is not None else cloud.colors
        extra = [rr.AnyValues(instance_id=cloud.instance_ids)] if cloud.instance_ids is not None else []
        self.rec.log(
            L.REFINED,
            rr.Points3D(cloud.points, colors=colors, class_ids=cloud.class_ids, radii=SCAN_RADIUS),
            *extra,
            static=static,
        )
        if not steps:
            return
        self.rec.reset_time()
        for i, (inliers, neighbours) in enumerate(steps):
            self.rec.set_time(L.LRGNET_STEP_TIMELINE, sequence=i)
            self.rec.log(
                f"{L.REFINED_GROWTH}/inliers",
                rr.Points3D(cloud.points[inliers], colors=GROWTH_INLIER_COLOR, radii=rr.Radius.ui_points(2.5)),
            )
            self.rec.log(
                f"{L.REFINED_GROWTH}/neighbours",
                rr.Points3D(cloud.points[neighbours], colors=GROWTH_NEIGHBOUR_COLOR, radii=rr.Radius.ui_points(2.5)),
            )
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
            extra = (
                [rr.AnyValues(instance_id=crack_points.instance_ids)] if crack_points.instance_ids is not None else []
            )
            self.rec.log(
                L.CRACK_POINTS,
                rr.Points3D(crack_points.points, colors=CRACK_COLOR, radii=CRACK_RADIUS),
                *extra,
                static=static,
            )
        if cracks:
            self.rec.log(L.CRACKS, _crack_boxes(cracks), static=static)
        if stories:
            self._log_stories(stories, static)

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self._start()
        self._flush_stats()
        if len(final_map):
            self._log_map(final_map)
        text = (
            f"{summary.scans} scans, {summary.points} points, {summary.map_voxels} map voxels, "
            f"{summary.instances} instances, {summary.scans_per_second:.2f} scans/s"
        )
        if summary.registration_failures:
            text += f", registration flagged at scans {summary.registration_failures}"
        if summary.interrupted:
            text += " (interrupted)"
        self.rec.log(f"{L.LOG}/summary", rr.TextLog(text, level="INFO"))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._stats:  # scalars of scans after `end` (or without one) still reach the file
            self._flush_stats()
        try:
            self._flush()
        except RuntimeError as exc:  # a viewer that went away or never came: the file is still finished
            self.rec.disconnect()
            raise OutputError(f"the Rerun viewer could not be reached ({exc})", self._viewer_url) from None
        self.rec.disconnect()
        if self.path is not None and self.path.exists():
            size = self.path.stat().st_size
            free = self._free_bytes()
            if size > self.cfg.compact_above_mb * 1e6 and (free is None or free > size + MIN_FREE_BYTES):
                compact(self.path)

    # ------------------------------------------------------------------------------------------ errors

    def _free_bytes(self) -> int | None:
        if self.path is None:
            return None
        try:
            st = os.statvfs(self.path.parent)
        except OSError:
            return None
        return st.f_bavail * st.f_frsize

    def _check_room(self) -> None:
        """Stop the recording, readable, while the disk still has room for what is in flight (see MIN_FREE_BYTES)."""
        free = self._free_bytes()
        if free is None or free >= MIN_FREE_BYTES or self._closed:
            return
        started = self.path is not None and self.path.exists()  # the file is made when the sinks are set
        if started:
            self.close()  # later layers go nowhere: the stream stops on this error and finishes the other outputs
        what = "the recording was stopped here and stays readable" if started else "nothing was written"
        raise OutputError(
            f"the disk is nearly full ({free / 2**20:.1f} MiB free, a recording needs {MIN_FREE_BYTES // 2**20} MiB "
            f"of room); {what}",
            self.path,
        )

    def _flush(self) -> None:
        """Flush, giving up with OutputError when the file writer died (it says so, or the file stops growing for
        FLUSH_STALL_S); RuntimeError from a viewer that cannot be reached."""
        if self.path is None:
            self.rec.flush()
            return
        last_size, last_change = -1, time.monotonic()
        while True:
            try:
                self.rec.flush(timeout_sec=FLUSH_POLL_S)
                return
            except RuntimeError as exc:
                if "file" in str(exc).lower():  # "File-writer thread shut down prematurely"
                    error = self._write_failed(f"{self._why()} ({exc})")
                    self.rec.disconnect()  # returns at once here; Rerun says its piece now, before our line
                    raise error from None
                if "timed out" not in str(exc):
                    raise
            size = self.path.stat().st_size if self.path.exists() else 0
            now = time.monotonic()
            if size != last_size:
                last_size, last_change = size, now
            elif now - last_change > FLUSH_STALL_S and (self._why() != _WRITE_FAILED or not self._viewers):
                # The file stopped growing: its writer is dead. (With a viewer attached, a flush may just be
                # waiting for a slow viewer while the file is complete; only a full disk then says otherwise.)
                raise self._write_failed(self._why(), process_stuck=True)

    @property
    def _viewers(self) -> bool:
        return any(isinstance(s, rr.GrpcSink) for s in self._sinks)

    def _why(self) -> str:
        free = self._free_bytes()
        return "the disk is full" if free is not None and free < MIN_FREE_BYTES else _WRITE_FAILED

    def _write_failed(self, why: str, process_stuck: bool = False) -> OutputError:
        size = self.path.stat().st_size if self.path is not None and self.path.exists() else 0
        return OutputError(
            f"{why}; the recording stopped at {size} bytes, Rerun reads it up to there", self.path, process_stuck
        )

    # ------------------------------------------------------------------------------------------ layers

    def _set_time(self, scan: Scan) -> None:
        self._scan = scan
        if scan.seq != self._stats_seq:
            self._stats_seq = scan.seq
            self._stats_logged.clear()
            self._stats_scans += 1
            if self._stats_scans > STATS_EVERY:
                self._flush_stats()
                self._stats_scans = 1
        self.rec.set_time(L.SCAN_TIMELINE, sequence=scan.seq)
        if self._mcap_times and scan.log_time_ns is not None:
            self.rec.set_time(L.MCAP_LOG_TIMELINE, timestamp=_datetime(scan.log_time_ns))
            self.rec.set_time(L.MCAP_STAMP_TIMELINE, timestamp=_datetime(scan.stamp_ns))
        else:
            self.rec.set_time(L.SENSOR_TIMELINE, timestamp=_datetime(scan.stamp_ns))

    def _log_raw(self, frame: Frame) -> None:
        if not self.raw_in_recording:
            return
        scan = frame.scan
        colors = _scan_colors(scan)
        pts = scan.points
        if self.cfg.raw_voxel_m > 0 and len(pts):
            keep, _ = voxel_downsample(pts, self.cfg.raw_voxel_m)
            pts, colors = pts[keep], colors[keep] if colors is not None else None
        self.rec.log(L.RAW, rr.Points3D(pts, colors=colors, radii=SCAN_RADIUS))

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
        self.rec.log(L.ROBOT, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        if self.cfg.debug_layers:
            self.rec.log(
                L.REGISTERED, rr.Points3D(_world_points(frame), colors=_scan_colors(frame.scan), radii=SCAN_RADIUS)
            )
        self._trajectory.append(pose[:3, 3].copy())
        self.rec.log(
            f"{L.TRAJECTORY}/p{self._piece}",
            rr.LineStrips3D([np.asarray(self._trajectory)], colors=TRAJECTORY_COLOR, radii=rr.Radius.ui_points(2.5)),
        )
        if len(self._trajectory) >= TRAJECTORY_PIECE:
            self._trajectory = [self._trajectory[-1]]
            self._piece += 1
        if not frame.registration_ok:
            note = f": {frame.registration_note}" if frame.registration_note else ""
            self.rec.log(f"{L.LOG}/registration", rr.TextLog(f"scan {frame.seq} flagged{note}", level="WARN"))

    def _labelled_subset(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """World points kept for labelling, and their indices into the scan."""
        idx = np.flatnonzero(frame.keep) if frame.keep is not None else np.arange(len(frame.scan))
        return _world_points(frame)[idx], idx

    def _one_per_voxel(self, frame: Frame) -> np.ndarray:
        """Indices of one kept point per map voxel: as the labelling stage found them, else downsampled here."""
        if frame.voxel_points is not None:
            return frame.voxel_points
        pts, idx = self._labelled_subset(frame)
        return idx[voxel_downsample(pts, self.cfg.map_voxel_m)[0]] if len(pts) else idx

    def _log_labelled(self, frame: Frame) -> None:
        if frame.labels is None or not self.cfg.debug_layers:
            return
        pts, idx = self._labelled_subset(frame)
        self.rec.log(L.LABELLED, rr.Points3D(pts, class_ids=frame.labels.class_ids[idx], radii=SCAN_RADIUS))
        if self.cfg.embeddings and frame.labels.embeddings is not None:
            colors = self._embedding_colors(frame.labels.embeddings[idx])
            self.rec.log(L.EMBEDDING, rr.Points3D(pts, colors=colors, radii=SCAN_RADIUS))

    def _log_clustered(self, frame: Frame) -> None:
        labels = frame.labels
        if labels is None:
            return
        if self.cfg.debug_layers:
            pts, idx = self._labelled_subset(frame)
            inst = labels.instance_ids[idx]
            self.rec.log(
                L.INSTANCES,
                rr.Points3D(pts, colors=_instance_colors(inst), class_ids=labels.class_ids[idx], radii=SCAN_RADIUS),
                rr.AnyValues(instance_id=inst),
            )
        # The default layer: one point per map voxel, positions once, class and instance beside them.
        one = self._one_per_voxel(frame)
        self.rec.log(
            L.LABELS,
            rr.Points3D(
                _world_points(frame)[one].astype(np.float32),
                class_ids=labels.class_ids[one],
                radii=MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m * 1.5,
            ),
            rr.AnyValues(instance_id=labels.instance_ids[one]),
        )
        self.merges(frame.merges, frame.seq)

    def merges(self, merges: list[InstanceMerge], seq: int) -> None:
        for m in merges:
            merged = ", ".join(str(i) for i in m.merged)
            self.rec.log(f"{L.LOG}/merges", rr.TextLog(f"scan {m.seq}: instances {merged} merged into {m.into}"))

    def _log_stats(self, frame: Frame) -> None:
        """Each scalar once per scan (the first value seen), buffered and sent as columns (`_flush_stats`)."""
        scan = frame.scan
        when = (scan.seq, scan.log_time_ns if self._mcap_times else None, scan.stamp_ns)
        values = [("raw_points", f"{L.STATS_COUNTS}/raw_points", float(len(scan)))]
        values += [(f"t:{k}", f"{L.STATS_TIME}/{k}", float(v)) for k, v in frame.timings_ms.items()]
        values += [(f"c:{k}", f"{L.STATS_COUNTS}/{k}", float(v)) for k, v in frame.counts.items()]
        for key, entity, value in values:
            if key not in self._stats_logged:
                self._stats_logged.add(key)
                self._stats.setdefault(entity, []).append((*when, value))

    def _flush_stats(self) -> None:
        """One `send_columns` per series for the buffered scans instead of one `log` per value and scan."""
        for entity, rows in self._stats.items():
            for mcap in (True, False):  # rows on the MCAP timelines, then rows on the sensor time
                sel = [r for r in rows if (r[1] is not None) == mcap]
                if not sel:
                    continue
                seq, log_ns, stamp_ns, value = (np.array(c) for c in zip(*sel, strict=True))
                stamps = stamp_ns.astype("datetime64[ns]")
                indexes = [rr.TimeColumn(L.SCAN_TIMELINE, sequence=seq)]
                if mcap:
                    indexes.append(rr.TimeColumn(L.MCAP_LOG_TIMELINE, timestamp=log_ns.astype("datetime64[ns]")))
                    indexes.append(rr.TimeColumn(L.MCAP_STAMP_TIMELINE, timestamp=stamps))
                else:
                    indexes.append(rr.TimeColumn(L.SENSOR_TIMELINE, timestamp=stamps))
                self.rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=value))
        self._stats.clear()

    def _log_map(self, cloud: LabelledCloud) -> None:
        """Downsample, cut into tiles, and re-log only the tiles whose content changed since the last update."""
        if len(cloud) == 0:
            return
        keep, _ = voxel_downsample(cloud.points, self.cfg.map_voxel_m)
        pts = cloud.points[keep]
        n = len(pts)
        cls = cloud.class_ids[keep] if cloud.class_ids is not None else np.full(n, UNLABELLED, np.uint16)
        inst = cloud.instance_ids[keep] if cloud.instance_ids is not None else np.zeros(n, np.uint32)
        colors = cloud.colors[keep] if cloud.class_ids is None and cloud.colors is not None else None
        self._map_bounds = (pts.min(axis=0), pts.max(axis=0))

        cell = np.floor(pts[:, :2] / self.cfg.map_tile_m).astype(np.int64)
        packed = (cell[:, 0] << 32) + cell[:, 1]  # one sortable key per tile (tile indices stay far below 2^31)
        order = np.argsort(packed, kind="stable")
        sorted_keys = packed[order]
        starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
        counts = np.diff(np.r_[starts, n])
        tiles = cell[order[starts]]
        zeros = np.zeros(n, np.uint16)
        where_hash = np.add.reduceat(_content_hash(pts, zeros, zeros.astype(np.uint32))[order], starts)
        label_hash = np.add.reduceat(_content_hash(pts, cls, inst)[order], starts)
        radius = MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m
        seen: set[str] = set()
        for t, (ix, iy) in enumerate(tiles):
            name = f"{L.MAP}/{_tile_name(int(ix), int(iy))}"
            seen.add(name)
            signature = (int(counts[t]), int(where_hash[t]), int(label_hash[t]))
            before = self._tiles.get(name)
            if before == signature:
                continue
            self._tiles[name] = signature
            sel = order[starts[t] : starts[t] + counts[t]]
            if before is not None and before[:2] == signature[:2] and colors is None:
                # Same points in the same order (map rows only append): only the labels are new.
                self.rec.log(name, rr.Points3D.from_fields(class_ids=cls[sel]), rr.AnyValues(instance_id=inst[sel]))
                continue
            self.rec.log(
                name,
                rr.Points3D(
                    pts[sel].astype(np.float32),
                    class_ids=cls[sel] if colors is None else None,
                    colors=colors[sel] if colors is not None else None,
                    radii=radius,
                ),
                rr.AnyValues(instance_id=inst[sel]),
            )
        for gone in set(self._tiles) - seen:
            del self._tiles[gone]
            self.rec.log(gone, rr.Clear(recursive=False))

    def _log_stories(self, stories: list[Story], static: bool) -> None:
        lo, hi = self._map_bounds if self._map_bounds is not None else (np.full(3, -5.0), np.full(3, 5.0))
        cx, cy = (lo[:2] + hi[:2]) / 2
        half = np.maximum((hi[:2] - lo[:2]) / 2, 0.5)
        origins, vectors, labels = [], [], []
        for s in stories:
            a, b, c, d = (float(v) for v in s.plane)
            z = -(a * cx + b * cy + d) / c if abs(c) > 1e-6 else s.height_m
            center = np.array([cx, cy, z])
            label = f"story {s.index}: drift {s.drift_mm:.1f} mm, tilt {s.tilt_deg:.2f}°"
            self.rec.log(
                f"{L.STORIES}/s{s.index}",
                rr.Boxes3D(
                    centers=[center],
                    half_sizes=[[half[0], half[1], 0.005]],
                    quaternions=[rr.Quaternion(xyzw=_quaternion_to_z(np.array([a, b, c])))],
                    colors=[(120, 180, 255, 60)],
                    fill_mode="solid",
                    labels=[label],
                ),
                static=static,
            )
            origins.append(center)
            vectors.append([s.drift_x_mm * DRIFT_ARROW_M_PER_MM, s.drift_y_mm * DRIFT_ARROW_M_PER_MM, 0.0])
            labels.append(f"{s.drift_mm:.1f} mm")
        self.rec.log(
            L.DRIFT, rr.Arrows3D(origins=origins, vectors=vectors, labels=labels, colors=(255, 90, 90)), static=static
        )


def _rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat()


def _quaternion_to_z(normal: np.ndarray) -> np.ndarray:
    """(x, y, z, w) rotation taking +z onto `normal`."""
    n = normal / max(np.linalg.norm(normal), 1e-12)
    if n[2] < 0:
        n = -n
    axis = np.cross([0.0, 0.0, 1.0], n)
    s = np.linalg.norm(axis)
    if s < 1e-9:
        return np.array([0.0, 0.0, 0.0, 1.0])
    angle = np.arctan2(s, n[2])
    return np.append(axis / s * np.sin(angle / 2), np.cos(angle / 2))


def _crack_boxes(cracks: list[Crack]) -> rr.Boxes3D:
    """One box per crack: long side along its axis, short side across it in the surface, thin along the normal."""
    centers, half_sizes, quats, labels, colors = [], [], [], [], []
    for c in cracks:
        axis = c.axis / max(np.linalg.norm(c.axis), 1e-12)
        normal = c.normal - axis * float(np.dot(c.normal, axis))
        normal /= max(np.linalg.norm(normal), 1e-12)
        across = np.cross(normal, axis)
        quats.append(rr.Quaternion(xyzw=_rotation_to_quaternion(np.stack([axis, across, normal], axis=1))))
        centers.append(c.center)
        half_sizes.append([c.length_m / 2, max(c.width_m / 2, 0.002), 0.003])
        severity = "severe" if c.severe else "hairline"
        labels.append(
            f"crack {c.instance_id}: {c.length_m * 100:.1f} cm long, {c.width_m * 1000:.1f} mm wide ({severity})"
        )
        colors.append(CRACK_COLOR if c.severe else MILD_CRACK_COLOR)
    return rr.Boxes3D(centers=centers, half_sizes=half_sizes, quaternions=quats, labels=labels, colors=colors)
