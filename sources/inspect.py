"""What `aftershock info` reports about a log before it is replayed: topics, span, and for each point-cloud
topic its fields, points per scan, per-point time and ground truth. Walks the whole log, one cloud at a time."""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aftershock.pipeline.errors import DamagedLogWarning, InputError
from aftershock.pipeline.pointcloud2 import (
    CLASS_FIELD,
    INSTANCE_FIELD,
    TIME_FIELDS,
    Field,
    PointFieldType,
    colors_from_columns,
    find_time_field,
    valid_mask,
)
from aftershock.pipeline.progress import bar
from aftershock.sources import SourceKind, kind_of
from aftershock.sources.common import (
    POINTCLOUD_TYPES,
    POSE_TYPES,
    CloudMessage,
    Damage,
    DecodedCloud,
    Event,
    Skipped,
    bad_time,
    choose_topic,
)


@dataclass(slots=True)
class TopicSummary:
    name: str
    type: str
    count: int


@dataclass(slots=True)
class FieldSummary:
    name: str
    datatype: str  # PointField name (FLOAT32 …) or the numpy dtype for files
    count: int = 1


@dataclass(slots=True)
class CloudTopicSummary:
    topic: str
    type: str
    scans: int = 0
    fields: list[FieldSummary] = field(default_factory=list)
    organized: str = ""  # "128 x 1024" when height > 1
    points_min: int = 0
    points_median: float = 0.0
    points_max: int = 0
    points_total: int = 0
    invalid_points_total: int = 0  # NaN or all-zero rows, dropped on reading
    per_point_time: str | None = None  # the field used, e.g. "t"
    time_convention: str | None = None
    intensity: bool = False
    color: bool = False
    ground_truth_classes: bool = False
    ground_truth_instances: bool = False
    has_xyz: bool = True


@dataclass(slots=True)
class LogSummary:
    path: str
    kind: str
    duration_s: float
    start_ns: int | None
    end_ns: int | None
    topics: list[TopicSummary]
    point_clouds: list[CloudTopicSummary]
    pose_topics: list[str]
    damage: str | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _field_summaries(cloud: DecodedCloud) -> list[FieldSummary]:
    if cloud.fields is not None:
        return [FieldSummary(f.name, PointFieldType(f.datatype).name, f.count) for f in cloud.fields]
    out = []
    for name, arr in cloud.columns.items():
        try:
            kind = PointFieldType.of(arr.dtype).name
        except ValueError:
            kind = str(arr.dtype)
        out.append(FieldSummary(name, kind, 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))))
    return out


def _valid_count(cols: dict[str, np.ndarray]) -> int | None:
    lower = {k.lower(): k for k in cols}
    if not all(a in lower for a in ("x", "y", "z")):
        return None
    # a column of several values per point (COUNT > 1) counts by its first; an empty cloud has no shape to infer
    firsts = [cols[lower[a]] if cols[lower[a]].ndim == 1 else cols[lower[a]][:, 0] for a in ("x", "y", "z")]
    xyz = np.stack(firsts, axis=1)
    return int(valid_mask(xyz).sum())


def summarise_clouds(
    evs: Iterable[Event], types: dict[str, str], total: int | None, progress: bool, name: str, path: str = ""
) -> tuple[list[CloudTopicSummary], str | None]:
    """Walk cloud events, decoding each once; returns per-topic summaries and the damage, if any."""
    summaries = {t: CloudTopicSummary(t, ty) for t, ty in sorted(types.items()) if ty in POINTCLOUD_TYPES}
    counts: dict[str, list[int]] = {t: [] for t in summaries}
    damage = None
    with bar(total, desc=name, show=progress) as pbar:
        for ev in evs:
            if isinstance(ev, Damage):
                damage = ev.reason
                break
            if not isinstance(ev, Skipped | Damage):
                ev = bad_time(ev) or ev
            if isinstance(ev, Skipped):  # a corrupt chunk or an impossible time: what it held is not counted
                warnings.warn(DamagedLogWarning(f"{path or name}: {ev.reason}"), stacklevel=2)
                continue
            if not isinstance(ev, CloudMessage):
                continue
            s = summaries[ev.topic]
            cloud = _decode(ev, path or name)
            if s.scans == 0:
                s.fields = _field_summaries(cloud)
                names = list(cloud.columns)
                lower = {n.lower() for n in names}
                s.per_point_time = find_time_field(names)
                s.time_convention = TIME_FIELDS[s.per_point_time.lower()].value if s.per_point_time else None
                s.intensity = bool(lower & {"intensity", "i", "signal", "reflectivity"})
                s.color = colors_from_columns({k: v[:1] for k, v in cloud.columns.items()}) is not None
                s.ground_truth_classes = CLASS_FIELD in lower
                s.ground_truth_instances = INSTANCE_FIELD in lower
                width = len(next(iter(cloud.columns.values()))) // max(cloud.height, 1) if cloud.columns else 0
                s.organized = f"{cloud.height} x {width}" if cloud.height > 1 else ""
            s.scans += 1
            n_all = len(next(iter(cloud.columns.values()))) if cloud.columns else 0
            valid = _valid_count(cloud.columns)
            if valid is None:
                s.has_xyz = False
                valid = 0
            counts[ev.topic].append(valid)
            s.invalid_points_total += n_all - valid
            pbar.update(1)
    for t, s in summaries.items():
        c = np.asarray(counts[t], dtype=np.int64)
        if len(c):
            s.points_min, s.points_max = int(c.min()), int(c.max())
            s.points_median, s.points_total = float(np.median(c)), int(c.sum())
    return list(summaries.values()), damage


def _decode(ev: CloudMessage, name: str) -> DecodedCloud:
    """A cloud message decoded, or InputError naming the message: `info` reports what a log holds, and a
    message that does not decode is a fact about the log to fix (the run skips it with a warning)."""
    try:
        return ev.decode()
    except InputError:
        raise
    except MemoryError:
        what = f"{ev.topic}: the message logged at {ev.log_time_ns} ns claims more memory than there is"
        raise InputError(what, name) from None
    except Exception as exc:  # decoders raise many kinds for malformed bytes
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise InputError(
            f"{ev.topic}: the message logged at {ev.log_time_ns} ns cannot be decoded ({type(exc).__name__}"
            f"{': ' + detail if detail else ''}); `run` skips it",
            name,
        ) from None


def _cloud_topics(types: dict[str, str], topic: str | None, path: str | Path) -> set[str]:
    if topic is not None:
        return {choose_topic(types, topic, path)}
    clouds = {t for t, ty in types.items() if ty in POINTCLOUD_TYPES}
    if not clouds:
        choose_topic(types, None, path)  # raises the "no point-cloud topic" error with the topics listed
    return clouds


def _check_replayable(point_clouds: list[CloudTopicSummary], path: str | Path) -> None:
    """The same refusals as reading scans: no x/y/z, or not one valid point, on every topic asked about."""
    if not point_clouds or any(pc.has_xyz and pc.points_total > 0 for pc in point_clouds):
        return
    pc = point_clouds[0]
    if not pc.has_xyz:
        names = ", ".join(f.name for f in pc.fields) or "none"
        raise InputError(f"{pc.topic}: point cloud has no x/y/z fields (fields: {names})", path)
    if pc.scans:
        raise InputError(f"every point of every scan on {pc.topic} is invalid (NaN or zero)", path)


def inspect(path_or_glob: str | Path, progress: bool = False, topic: str | None = None) -> LogSummary:
    """Everything `info` reports, for every point-cloud topic or only `topic`.

    InputError for inputs that cannot be replayed at all: unreadable, no point-cloud topic, a missing
    `topic`, or clouds without x/y/z or without a single valid point (what `run` would refuse too).
    """
    kind = kind_of(path_or_glob)
    name = Path(str(path_or_glob)).name
    if kind is SourceKind.MCAP:
        from aftershock.sources.mcap_source import events, read_catalog

        cat = read_catalog(Path(path_or_glob), progress=progress)
        types = cat.types
        topics = [TopicSummary(t.name, t.type, t.count) for t in sorted(cat.topics.values(), key=lambda t: t.name)]
        clouds = _cloud_topics(types, topic, path_or_glob)
        total = sum(cat.topics[t].count for t in clouds)
        evs: Iterator[Event] = events(cat, clouds)
        start, end, duration = cat.start_ns, cat.end_ns, cat.duration_s
    elif kind is SourceKind.BAG:
        from aftershock.sources.bag import events as bag_events
        from aftershock.sources.bag import read_catalog as read_bag

        bag = read_bag(Path(path_or_glob))
        types = bag.types
        topics = [TopicSummary(t, ty, n) for t, (ty, n) in sorted(bag.topics.items())]
        clouds = _cloud_topics(types, topic, path_or_glob)
        total = sum(bag.topics[t][1] for t in clouds)
        evs = bag_events(Path(path_or_glob), clouds)
        start, end, duration = bag.start_ns, bag.end_ns, bag.duration_s
    elif kind is SourceKind.FILES:
        from aftershock.sources.files import FILE_PERIOD_NS, FILES_TOPIC, list_files
        from aftershock.sources.files import events as file_events

        files = list_files(path_or_glob)
        suffixes = sorted({f.suffix.lower().lstrip(".") for f in files})
        types = {FILES_TOPIC: "sensor_msgs/msg/PointCloud2"}
        topics = [TopicSummary(FILES_TOPIC, "files: " + ", ".join(suffixes), len(files))]
        total = len(files)
        evs = file_events(files, None, None)
        start, end, duration = 0, (len(files) - 1) * FILE_PERIOD_NS, (len(files) - 1) * FILE_PERIOD_NS * 1e-9
        clouds = {FILES_TOPIC}
    else:
        raise InputError("`info` reads logs and files; a simulator URI has nothing to inspect", path_or_glob)
    point_clouds, damage = summarise_clouds(
        evs, {t: types[t] for t in clouds}, total, progress, name, str(path_or_glob)
    )
    if kind is SourceKind.FILES:
        point_clouds[0].type = topics[0].type
    _check_replayable(point_clouds, path_or_glob)
    if damage is not None:
        warnings.warn(DamagedLogWarning(f"{path_or_glob}: {damage}; counted what precedes it"), stacklevel=2)
    return LogSummary(
        path=str(path_or_glob),
        kind=kind.value,
        duration_s=duration,
        start_ns=start,
        end_ns=end,
        topics=topics,
        point_clouds=point_clouds,
        pose_topics=sorted(t for t, ty in types.items() if ty in POSE_TYPES),
        damage=damage,
    )


__all__ = ["CloudTopicSummary", "Field", "LogSummary", "TopicSummary", "inspect"]
