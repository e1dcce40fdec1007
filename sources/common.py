"""What every log reader shares: topic choice, the time window, every-N / max-scans, ground-truth poses.

A reader turns its log into a stream of events (`CloudMessage`, `PoseMessage`, `Damage`) in log-time
order; `assemble` turns those into `Scan`s, decoding only the clouds it keeps.
"""

from __future__ import annotations

import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from aftershock.pipeline.errors import DamagedLogWarning, InputError
from aftershock.pipeline.pointcloud2 import Field, NoXYZError, columns_to_scan
from aftershock.pipeline.progress import bar
from aftershock.pipeline.types import Scan, SourceReport

POINTCLOUD_TYPES: Final[frozenset[str]] = frozenset(
    {"sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2", "foxglove.PointCloud"}
)
POSE_TYPES: Final[frozenset[str]] = frozenset({"geometry_msgs/msg/PoseStamped", "geometry_msgs/PoseStamped"})

# Ground-truth pose at a scan stamp: interpolated between poses at most this far apart, else the nearest
# pose if it is this close; scans wait at most POSE_WAIT_S of log time for the pose after their stamp.
POSE_MAX_GAP_S: Final[float] = 1.0
POSE_TOLERANCE_S: Final[float] = 0.05
POSE_WAIT_S: Final[float] = 2.0
_POSE_HISTORY: Final[int] = 256


@dataclass(slots=True)
class DecodedCloud:
    columns: dict[str, np.ndarray]
    stamp_ns: int  # header stamp, 0 if the message has none
    frame_id: str
    fields: tuple[Field, ...] | None = None  # as the message declares them (None: files without PointFields)
    height: int = 1


@dataclass(slots=True)
class CloudMessage:
    """A point-cloud message, decoded only if kept (`decode` is called at most once)."""

    log_time_ns: int
    topic: str
    decode: Callable[[], DecodedCloud]


@dataclass(slots=True)
class PoseMessage:
    log_time_ns: int
    stamp_ns: int
    matrix: np.ndarray


@dataclass(slots=True)
class Damage:
    """The log cannot be read past this point."""

    reason: str


@dataclass(slots=True)
class Skipped:
    """A message (or a chunk of them) that cannot be read; the log goes on after it."""

    log_time_ns: int
    topic: str
    reason: str


Event = CloudMessage | PoseMessage | Damage | Skipped

# Log times are unsigned 64-bit in MCAP and ROS 2 bags; everything downstream (numpy, Rerun, the MCAP sink) holds
# them as signed 64-bit nanoseconds, so a time at or past 2**63 (the year 2262) is a damaged record, not a time.
TIME_LIMIT_NS: Final[int] = 1 << 63


def time_in_range(ns: int | None) -> bool:
    return ns is None or 0 <= ns < TIME_LIMIT_NS


def bad_time(ev: Event) -> Skipped | None:
    """`Skipped` for a cloud or pose message whose log time no signed 64-bit clock can hold, else None."""
    if isinstance(ev, CloudMessage | PoseMessage) and not time_in_range(ev.log_time_ns):
        topic = ev.topic if isinstance(ev, CloudMessage) else "pose"
        return Skipped(ev.log_time_ns, topic, f"its log time {ev.log_time_ns} ns is past 2**63 ns (the year 2262)")
    if isinstance(ev, PoseMessage) and not time_in_range(ev.stamp_ns):
        return Skipped(ev.log_time_ns, "pose", f"its stamp {ev.stamp_ns} ns is past 2**63 ns (the year 2262)")
    return None


def pose_event(log_time_ns: int, topic: str, decode: Callable[[], tuple[int, np.ndarray]]) -> PoseMessage | Skipped:
    """A pose message, or `Skipped` when it cannot be decoded or is no rigid pose (a zero or NaN quaternion)."""
    try:
        stamp_ns, matrix = decode()
    except Exception as exc:  # any decoder failure on one message: the log goes on
        return Skipped(log_time_ns, topic, _reason(exc))
    if not time_in_range(log_time_ns):
        return Skipped(log_time_ns, topic, f"its log time {log_time_ns} ns is past 2**63 ns (the year 2262)")
    return PoseMessage(log_time_ns, stamp_ns or log_time_ns, matrix)


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# --------------------------------------------------------------------------------------------- topics


def choose_topic(types: Mapping[str, str], topic: str | None, path: str | Path) -> str:
    """The point-cloud topic to read: the one asked for, else the only one; a clear error otherwise."""
    clouds = sorted(t for t, ty in types.items() if ty in POINTCLOUD_TYPES)
    listing = ", ".join(clouds) if clouds else "none"
    if topic is not None:
        if topic not in types:
            raise InputError(f"no topic {topic!r} in the log; point-cloud topics: {listing}", path)
        if types[topic] not in POINTCLOUD_TYPES:
            raise InputError(
                f"topic {topic} carries {types[topic]}, not a point cloud; point-cloud topics: {listing}", path
            )
        return topic
    if not clouds:
        seen = ", ".join(f"{t} ({ty})" for t, ty in sorted(types.items())) or "no topics at all"
        raise InputError(f"no point-cloud topic (PointCloud2 or foxglove.PointCloud) in the log; it has {seen}", path)
    if len(clouds) > 1:
        raise InputError(f"{len(clouds)} point-cloud topics ({listing}); choose one with --topic", path)
    return clouds[0]


def choose_pose_topic(types: Mapping[str, str], pose_topic: str | None, path: str | Path) -> str | None:
    """The ground-truth PoseStamped topic: the one asked for, else the only one, else none."""
    poses = sorted(t for t, ty in types.items() if ty in POSE_TYPES)
    if pose_topic is not None:
        if types.get(pose_topic) not in POSE_TYPES:
            listing = ", ".join(poses) or "none"
            raise InputError(f"no PoseStamped topic {pose_topic!r}; PoseStamped topics: {listing}", path)
        return pose_topic
    return poses[0] if len(poses) == 1 else None


@dataclass(frozen=True, slots=True)
class ReadOptions:
    """What of a log a reader reads (names of `SourceConfig`), whether it shows a progress bar on stderr, and the
    `SourceReport` it fills with the messages it skipped and the damage that ended the log. Checked when made."""

    topic: str | None = None  # the point-cloud topic (None: the only one)
    pose_topic: str | None = None  # the ground-truth PoseStamped topic (None: the only one, if any)
    start_s: float | None = None  # the window, in seconds from the log's start
    end_s: float | None = None
    max_scans: int | None = None
    every: int = 1  # keep every n-th cloud
    progress: bool = False
    report: SourceReport | None = None

    def __post_init__(self) -> None:
        if self.every < 1:
            raise InputError(f"--every must be at least 1, not {self.every}")
        if self.max_scans is not None and self.max_scans < 1:
            raise InputError(f"--max-scans must be at least 1, not {self.max_scans}")
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise InputError(f"--end ({self.end_s} s) comes before --start ({self.start_s} s)")

    def window_ns(self, log_start_ns: int | None) -> tuple[int | None, int | None]:
        """[lo, hi) log-time bounds in ns of the window, for a log starting at `log_start_ns`."""
        if log_start_ns is None:
            return None, None
        lo = None if self.start_s is None else log_start_ns + round(self.start_s * 1e9)
        hi = None if self.end_s is None else log_start_ns + round(self.end_s * 1e9)
        return lo, hi


# --------------------------------------------------------------------------------------------- poses


def _slerp(m0: np.ndarray, m1: np.ndarray, w: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation, Slerp

    rots = Rotation.from_matrix(np.stack([m0[:3, :3], m1[:3, :3]]))
    out = np.eye(4)
    out[:3, :3] = Slerp([0.0, 1.0], rots)([w]).as_matrix()[0]
    out[:3, 3] = (1 - w) * m0[:3, 3] + w * m1[:3, 3]
    return out


class PoseTrack:
    """Recent ground-truth poses; the pose at a stamp by interpolation or the nearest within tolerance."""

    def __init__(self) -> None:
        self.stamps: deque[int] = deque(maxlen=_POSE_HISTORY)
        self.poses: deque[np.ndarray] = deque(maxlen=_POSE_HISTORY)

    def add(self, stamp_ns: int, matrix: np.ndarray) -> None:
        if self.stamps and stamp_ns < self.stamps[-1]:  # out of order: keep the deque sorted
            items = sorted([*zip(self.stamps, self.poses, strict=True), (stamp_ns, matrix)], key=lambda x: x[0])
            self.stamps = deque((s for s, _ in items), maxlen=_POSE_HISTORY)
            self.poses = deque((p for _, p in items), maxlen=_POSE_HISTORY)
            return
        self.stamps.append(stamp_ns)
        self.poses.append(matrix)

    @property
    def latest_ns(self) -> int | None:
        return self.stamps[-1] if self.stamps else None

    def at(self, stamp_ns: int) -> np.ndarray | None:
        if not self.stamps:
            return None
        stamps = np.fromiter(self.stamps, dtype=np.int64, count=len(self.stamps))
        i = int(np.searchsorted(stamps, stamp_ns))
        if i < len(stamps) and stamps[i] == stamp_ns:
            return self.poses[i].copy()
        if 0 < i < len(stamps) and (stamps[i] - stamps[i - 1]) * 1e-9 <= POSE_MAX_GAP_S:
            w = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
            return _slerp(self.poses[i - 1], self.poses[i], float(w))
        near = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
        j = min(near, key=lambda k: abs(int(stamps[k]) - stamp_ns))
        return self.poses[j].copy() if abs(int(stamps[j]) - stamp_ns) * 1e-9 <= POSE_TOLERANCE_S else None


# --------------------------------------------------------------------------------------------- assembling scans


def assemble(
    events: Iterable[Event], options: ReadOptions, *, path: str | Path, topic: str, with_poses: bool, total: int | None
) -> Iterator[Scan]:
    """Scans from a reader's events (`total` clouds in them, if known): keep every `every`-th cloud, decode it,
    drop invalid points, attach the ground-truth pose, number the scans, stop after `max_scans`; warn at damage.

    A message that cannot be decoded is skipped with a warning naming its log time (listed in `report`);
    only a topic where not one message decodes is an error."""
    every, max_scans = options.every, options.max_scans
    report = options.report if options.report is not None else SourceReport()
    first_failure: str | None = None
    pending: deque[Scan] = deque()  # decoded scans waiting for a pose at or after their stamp
    track = PoseTrack()
    clouds = 0
    empty = 0
    seq = 0
    damage: str | None = None
    if total is not None:
        total = -(-total // every) if max_scans is None else min(-(-total // every), max_scans)

    def finish(scan: Scan) -> Scan:
        nonlocal seq
        if with_poses:
            scan.gt_pose = track.at(scan.stamp_ns)
        scan.seq = seq
        seq += 1
        return scan

    wait_ns = round(POSE_WAIT_S * 1e9)

    def due(now_ns: int, flush: bool) -> Iterator[Scan]:
        """Pending scans, in order, whose pose is settled: a later pose exists, or they waited long enough."""
        while pending:
            head = pending[0]
            settled = track.latest_ns is not None and head.stamp_ns <= track.latest_ns
            if not (flush or settled or (head.log_time_ns or 0) < now_ns - wait_ns):
                return
            yield finish(pending.popleft())

    with bar(total, desc=Path(str(path)).name, show=options.progress) as pbar:
        for ev in events:
            if isinstance(ev, Damage):
                damage = report.damage = ev.reason
                break
            if not isinstance(ev, Skipped | Damage):
                ev = bad_time(ev) or ev
            if isinstance(ev, Skipped):
                _skip(report, path, ev)
                continue
            if isinstance(ev, PoseMessage):
                track.add(ev.stamp_ns, ev.matrix)
            else:
                clouds += 1
                if (clouds - 1) % every:
                    continue
                try:
                    scan = _decode(ev, path, first=seq == 0 and not pending)
                except _Undecodable as exc:
                    first_failure = first_failure or str(exc)
                    _skip(report, path, Skipped(ev.log_time_ns, ev.topic, str(exc)))
                    continue
                if scan is None:
                    empty += 1
                    continue
                pending.append(scan)
            for scan in due(ev.log_time_ns, flush=not with_poses):
                yield scan
                pbar.update(1)
                if max_scans is not None and seq >= max_scans:
                    return
        for scan in due(0, flush=True):
            yield scan
            pbar.update(1)
            if max_scans is not None and seq >= max_scans:
                return
    if damage is not None:
        warnings.warn(DamagedLogWarning(f"{path}: {damage}; read {seq} complete scans before the damage"), stacklevel=2)
    if seq == 0 and first_failure is not None and not empty:
        raise InputError(f"{topic}: not one point cloud could be decoded ({first_failure})", path)
    if seq == 0 and empty:
        raise InputError(f"every point of every scan on {topic} is invalid (NaN or zero)", path)
    if empty:
        warnings.warn(
            DamagedLogWarning(f"{path}: skipped {empty} scans on {topic} without a valid point"), stacklevel=2
        )


class _Undecodable(Exception):
    """One point-cloud message that cannot be decoded (skipped by `assemble`)."""


def _skip(report: SourceReport, path: str | Path, ev: Skipped) -> None:
    report.skipped.append((ev.log_time_ns, ev.reason))
    warnings.warn(
        DamagedLogWarning(f"{path}: skipped the {ev.topic} message logged at {ev.log_time_ns} ns: {ev.reason}"),
        stacklevel=3,
    )


def _decode(ev: CloudMessage, path: str | Path, first: bool = False) -> Scan | None:
    """The scan of a cloud message; `_Undecodable` for a malformed message or a damaged file. The first one
    raises InputError instead when it is the input's fault as a whole (a topic without x/y/z, a single
    damaged file), so a run that cannot start says so in one line."""
    try:
        cloud = ev.decode()
        return columns_to_scan(
            cloud.columns,
            # a header stamp no signed 64-bit clock holds (a negative ROS 2 second) is no stamp: the log time stands
            stamp_ns=cloud.stamp_ns if cloud.stamp_ns and time_in_range(cloud.stamp_ns) else ev.log_time_ns,
            frame_id=cloud.frame_id,
            topic=ev.topic,
            log_time_ns=ev.log_time_ns,
        )
    except NoXYZError as exc:
        if first:
            raise InputError(f"{ev.topic}: {exc}", path) from None
        raise _Undecodable(f"cannot decode the point cloud: {exc}") from None
    except InputError as exc:  # a damaged file among a folder's scans: skipped like a bad message
        if first:
            raise
        raise _Undecodable(str(exc)) from None
    except MemoryError:
        raise _Undecodable("cannot decode the point cloud: it claims more memory than there is") from None
    except Exception as exc:  # decoders raise many kinds for malformed bytes; one bad message must not end the run
        raise _Undecodable(f"cannot decode the point cloud: {_reason(exc)}") from None
