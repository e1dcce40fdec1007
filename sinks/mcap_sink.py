"""MCAP sink: the labelled scans and the estimated poses as ROS 2 messages, readable by Rerun and Foxglove.

- `/aftershock/labelled_points`: `sensor_msgs/msg/PointCloud2` of every scan in the world frame `map`, fields
  `x y z` (float32), `rgb` (float32 packed 0x00RRGGBB, the class colour), `class_id` (uint16, 65535 where not
  labelled), `instance_id` (uint32, 0 = no object) and `intensity` (float32) when the scan has it.
- `/aftershock/pose`: `geometry_msgs/msg/PoseStamped` (frame `map`), the sensor pose at the scan stamp.

Messages carry the scan's header stamp and are logged at the input's log time (the stamp when there is none),
so the file lines up with the input log. Chunks are zstd-compressed; `close` writes the summary, also after
Ctrl-C, so what was processed stays readable.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Final

import numpy as np
from mcap.writer import CompressionType, Writer

from aftershock.pipeline.classes import UNLABELLED, class_colors
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.outputs import StreamedOutput, check_output
from aftershock.pipeline.pointcloud2 import (
    encode_pointcloud2,
    pose_stamped_message,
    register_cloud_and_pose,
    serialize_pointcloud2,
    serialize_pose_stamped,
)
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.types import Frame, LabelledCloud, RunInfo, RunSummary

POINTS_TOPIC: Final = "/aftershock/labelled_points"
POSE_TOPIC: Final = "/aftershock/pose"
WORLD_FRAME: Final = "map"
# Frames wait here until their last stage; a stream that never sends CLUSTERED still gets them written.
MAX_PENDING: Final = 8


def pack_rgb(colors: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours as the float32 `rgb` field of PCL, Rerun and Foxglove (bits 0x00RRGGBB)."""
    c = np.asarray(colors, dtype=np.uint32)
    return ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).astype(np.uint32).view(np.float32)


def labelled_columns(frame: Frame) -> dict[str, np.ndarray] | None:
    """The PointCloud2 columns of a frame's scan in the world frame, or None before it has a pose."""
    if frame.world_points is not None:
        world = frame.world_points
    elif frame.pose is not None:
        world = frame.scan.points @ frame.pose[:3, :3].T + frame.pose[:3, 3]
    else:
        return None
    n = len(world)
    labels = frame.labels
    cls = labels.class_ids if labels is not None else np.full(n, UNLABELLED, np.uint16)
    inst = labels.instance_ids if labels is not None else np.zeros(n, np.uint32)
    cols: dict[str, np.ndarray] = {
        "x": world[:, 0].astype(np.float32),
        "y": world[:, 1].astype(np.float32),
        "z": world[:, 2].astype(np.float32),
        "rgb": pack_rgb(class_colors(cls)),
        "class_id": cls.astype(np.uint16),
        "instance_id": inst.astype(np.uint32),
    }
    if frame.scan.intensity is not None:
        cols["intensity"] = frame.scan.intensity.astype(np.float32)
    return cols


class McapSink(Sink):
    """Writes the labelled scans and poses to one MCAP file as they finish (the path is checked when the sink
    is made, the file created in `begin`)."""

    def __init__(self, path: Path, force: bool = False) -> None:
        self.path = check_output(path, force)
        self._out = StreamedOutput(self.path)  # written as NAME.part, renamed by `close`
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._points = self._pose = 0
        self._pending: dict[int, Frame] = {}
        self._sequence = 0
        self._failed = False  # the disk refused a write: nothing more is tried
        self.scans_written = 0

    def begin(self, info: RunInfo) -> None:
        # The file is made only now: a run refused before its first scan leaves nothing behind.
        self._open()

    def stage(self, frame: Frame, stage: Stage) -> None:
        if self._failed:
            return
        self._pending[frame.seq] = frame
        with self._writing():
            if stage is Stage.CLUSTERED:
                self._write(self._pending.pop(frame.seq))
            while len(self._pending) > MAX_PENDING:
                self._write(self._pending.pop(min(self._pending)))

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        if self._failed:
            return
        with self._writing():
            self._flush_pending()

    def close(self) -> None:
        if self._file is None or self._writer is None:
            return
        try:
            if not self._failed:  # after a failed write, finishing would only fail again
                with self._writing():
                    self._flush_pending()
                    self._writer.finish()
        finally:
            with suppress(OSError):  # the buffer could not be written out either: the write error was reported
                self._out.close()
            self._file = None
            self._writer = None

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """OSError (a full disk, a lost mount) as one line naming the file; the messages already written stay
        readable (the reader reads an MCAP without its summary up to the damage)."""
        try:
            yield
        except OSError as exc:
            self._failed = True
            what = f"cannot write: {exc.strerror or exc}; what was written before stays readable"
            raise OutputError(what, self.path) from None

    def _open(self) -> Writer:
        if self._writer is not None:
            return self._writer
        try:
            self._file = self._out.open("wb")
        except OSError as exc:
            raise OutputError(f"cannot write: {exc.strerror}", self.path) from None
        writer = Writer(self._file, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="aftershock")
        self._points, self._pose = register_cloud_and_pose(writer, POINTS_TOPIC, POSE_TOPIC)
        self._writer = writer
        return writer

    def _flush_pending(self) -> None:
        for seq in sorted(self._pending):
            self._write(self._pending.pop(seq))

    def _write(self, frame: Frame) -> None:
        self._open()  # also when `begin` was not called
        cols = labelled_columns(frame)
        if cols is None:
            return
        scan = frame.scan
        log_time = scan.log_time_ns if scan.log_time_ns is not None else scan.stamp_ns
        msg = encode_pointcloud2(cols, stamp_ns=scan.stamp_ns, frame_id=WORLD_FRAME)
        self._add(self._points, log_time, serialize_pointcloud2(msg))
        pose = frame.stamp_pose if frame.stamp_pose is not None else frame.pose
        if pose is not None:
            self._add(self._pose, log_time, serialize_pose_stamped(pose_stamped_message(pose, scan.stamp_ns)))
        self.scans_written += 1
        # Whatever the writer handed over (the header, each finished chunk) reaches the file now, so a killed
        # run keeps every finished chunk, read up to the cut.
        assert self._file is not None
        self._file.flush()

    def _add(self, channel: int, log_time: int, data: bytes) -> None:
        assert self._writer is not None
        self._writer.add_message(channel, log_time=log_time, data=data, publish_time=log_time, sequence=self._sequence)
        self._sequence += 1
