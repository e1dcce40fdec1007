"""Everything that yields `Scan`s: MCAP logs, ROS bags, point-cloud files and the simulator.

    for scan in sources.open("mission.mcap", topic="/ouster/points", every=2):
        ...

The reader is chosen from the input: `sim://…` URIs go to the simulator, folders with a
`metadata.yaml` are ROS 2 bags, files are recognised by their first bytes (MCAP, ROS 1 bag) or
suffix (.pcd, .ply, .bin), other folders and globs are read as point-cloud files in name order.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Scan

SIM_SCHEME = "sim://"


class SourceKind(StrEnum):
    MCAP = "mcap"
    BAG = "bag"
    FILES = "files"
    SIM = "sim"


@dataclass(frozen=True, slots=True)
class SourceDescription:
    """What the run command records about its input (`RunInfo.source_kind`, `topic`, `log_start_ns`)."""

    kind: SourceKind
    topic: str = ""
    log_start_ns: int | None = None
    raw_in_log: bool = False  # the viewer reads the raw scans from the log itself (MCAP, ROS 2 / Foxglove clouds)
    log_id: str = ""  # fingerprint of the log file (`mcap_source.fingerprint`)


def kind_of(path_or_uri: str | Path) -> SourceKind:
    """Which reader handles this input; InputError for a missing path or something unreadable."""
    text = str(path_or_uri)
    if text.startswith(SIM_SCHEME):
        return SourceKind.SIM
    from aftershock.sources.files import SUFFIXES, is_glob

    if is_glob(text) and not Path(text).exists():
        return SourceKind.FILES
    path = Path(text)
    try:
        path.stat()
    except FileNotFoundError:
        raise InputError("no such file or directory", path) from None
    except OSError as exc:  # a name over 255 bytes, a folder on the way that may not be entered
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    if path.is_dir():
        from aftershock.sources.bag import is_ros2_bag

        return SourceKind.BAG if is_ros2_bag(path) else SourceKind.FILES
    from aftershock.sources.bag import is_ros1_bag
    from aftershock.sources.mcap_source import is_mcap

    try:
        if is_mcap(path):
            return SourceKind.MCAP
        if is_ros1_bag(path):
            return SourceKind.BAG
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", path) from None
    if path.suffix.lower() in SUFFIXES:
        return SourceKind.FILES
    if path.suffix.lower() == ".mcap":
        raise InputError("not an MCAP file (it does not start with the MCAP magic bytes)", path)
    if path.suffix.lower() == ".bag":
        raise InputError("not a ROS 1 bag (it does not start with '#ROSBAG V2.0')", path)
    raise InputError("not an MCAP file, ROS bag or point-cloud file (.pcd, .ply, .bin)", path)


def open(path_or_uri: str | Path, **options: Any) -> Iterator[Scan]:
    """Scans from any supported input. Options (the fields of `common.ReadOptions`, names of `SourceConfig`):
    topic, pose_topic, start_s, end_s, max_scans, every; plus progress (a bar on stderr) and report (a
    `SourceReport` the reader fills with the messages it skipped and the damage that ended the log). Problems
    with the input raise InputError here, before the first scan; a message that cannot be decoded is skipped
    with a warning; a log damaged part-way yields what precedes the damage, then warns."""
    kind = kind_of(path_or_uri)
    options = {k: v for k, v in options.items() if v is not None}
    if kind is SourceKind.SIM:
        from aftershock.sources.simulated import open_simulated

        options.pop("report", None)  # the simulator has nothing to skip
        return open_simulated(str(path_or_uri), **options)
    from aftershock.sources.common import ReadOptions

    read = ReadOptions(**options)
    if kind is SourceKind.MCAP:
        from aftershock.sources.mcap_source import open_mcap

        return open_mcap(Path(path_or_uri), read)
    if kind is SourceKind.BAG:
        from aftershock.sources.bag import open_bag

        return open_bag(Path(path_or_uri), read)
    from aftershock.sources.files import open_files

    return open_files(path_or_uri, read)


def describe(path_or_uri: str | Path, topic: str | None = None) -> SourceDescription:
    """Kind, chosen point-cloud topic and log start of an input, without reading its scans."""
    kind = kind_of(path_or_uri)
    if kind is SourceKind.MCAP:
        from aftershock.sources.common import choose_topic
        from aftershock.sources.mcap_source import fingerprint, raw_in_log, read_catalog

        cat = read_catalog(Path(path_or_uri))
        chosen = choose_topic(cat.types, topic, path_or_uri)
        readable = raw_in_log(cat.topics[chosen]) if chosen in cat.topics else False
        return SourceDescription(kind, chosen, cat.start_ns, readable, fingerprint(Path(path_or_uri)))
    if kind is SourceKind.BAG:
        from aftershock.sources.bag import read_catalog as read_bag_catalog
        from aftershock.sources.common import choose_topic

        bag = read_bag_catalog(Path(path_or_uri))
        return SourceDescription(kind, choose_topic(bag.types, topic, path_or_uri), bag.start_ns)
    if kind is SourceKind.FILES:
        from aftershock.sources.files import FILES_TOPIC, list_files

        list_files(path_or_uri)
        return SourceDescription(kind, FILES_TOPIC, 0)
    return SourceDescription(kind, topic or "")


__all__ = ["SourceDescription", "SourceKind", "describe", "kind_of", "open"]
