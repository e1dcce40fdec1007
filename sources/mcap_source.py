"""Scans from MCAP files: ROS 2 and ROS 1 PointCloud2, foxglove.PointCloud, ground-truth PoseStamped.

An indexed file is read chunk by chunk through its summary (only the chunks holding the wanted topics
and time window). A file without a usable summary — a recording cut off mid-write — is read as a plain
stream up to the damage: every complete message before it is used, then a `DamagedLogWarning`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import heapq
import struct
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from aftershock.pipeline.errors import DamagedLogWarning, InputError
from aftershock.pipeline.limits import block_cap_bytes
from aftershock.pipeline.pointcloud2 import decode_pointcloud2, header_stamp_ns, pose_to_matrix
from aftershock.pipeline.progress import bar
from aftershock.pipeline.types import Scan
from aftershock.sources.common import (
    CloudMessage,
    Damage,
    DecodedCloud,
    Event,
    ReadOptions,
    Skipped,
    assemble,
    choose_pose_topic,
    choose_topic,
    pose_event,
)
from aftershock.sources.foxglove import decode_foxglove_pointcloud
from aftershock.sources.inflate import BlockTooLarge, inflate

MCAP_MAGIC: Final[bytes] = b"\x89MCAP0\r\n"
_RECORD_LIMIT: Final[int] = 1 << 30  # a record larger than 1 GiB in a LiDAR log means a corrupt length
_CHUNK_FIXED: Final[int] = 8 + 8 + 8 + 4 + 4  # start, end, uncompressed size, crc, compression name length


def _damage_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = [McapError, struct.error, EOFError, ValueError, KeyError, IndexError]
    try:
        import zstandard

        errors.append(zstandard.ZstdError)
    except ImportError:  # pragma: no cover - mcap depends on it
        pass
    try:
        import lz4.frame

        errors.append(RuntimeError)  # lz4 reports corrupt frames as RuntimeError
        del lz4
    except ImportError:
        pass
    return tuple(errors)


DAMAGE_ERRORS: Final[tuple[type[BaseException], ...]] = _damage_errors()
CHUNK_ERRORS: Final[tuple[type[BaseException], ...]] = (CRCValidationError, MemoryError, *DAMAGE_ERRORS)


def damage_reason(exc: BaseException, where: int, size: int | None = None) -> str:
    """One line on what went wrong where in a damaged log."""
    of = f" of {size}" if size is not None else ""
    if isinstance(exc, EndOfFile | EOFError):
        return f"the log is cut off at byte {where}{of} (it ends inside a record)"
    detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"the log is damaged near byte {where}{of} ({type(exc).__name__}{': ' + detail if detail else ''})"


def _record_limit() -> int:
    """The largest record read whole when a file is read through (a chunk's compressed bytes)."""
    return min(_RECORD_LIMIT, block_cap_bytes())


def is_mcap(path: Path) -> bool:
    with path.open("rb") as fh:
        return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC


@dataclass(slots=True)
class TopicInfo:
    name: str
    type: str  # schema name, e.g. sensor_msgs/msg/PointCloud2
    count: int = 0
    encoding: str = ""  # message encoding: cdr, ros1, protobuf


# (message encoding, schema) pairs of point clouds Rerun's own MCAP import decodes (ROS 2 CDR, Foxglove protobuf).
VIEWER_CLOUDS: Final[frozenset[tuple[str, str]]] = frozenset(
    {("cdr", "sensor_msgs/msg/PointCloud2"), ("protobuf", "foxglove.PointCloud")}
)
_FINGERPRINT_BYTES: Final = 1 << 16


def raw_in_log(topic: TopicInfo) -> bool:
    """Whether the viewer reads this topic's raw scans from the log itself (it shows its point clouds when it
    opens the MCAP), so a recording need not copy them (`RunInfo.raw_in_log`)."""
    return (topic.encoding, topic.type) in VIEWER_CLOUDS


def fingerprint(path: Path) -> str:
    """A short id of a log file from its size, head and tail (the MCAP summary lives there): cheap on a
    gigabyte log, and a recording made from another log will not carry it."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        size = fh.seek(0, 2)
        h.update(size.to_bytes(8, "little"))
        fh.seek(0)
        h.update(fh.read(_FINGERPRINT_BYTES))
        fh.seek(max(0, size - _FINGERPRINT_BYTES))
        h.update(fh.read(_FINGERPRINT_BYTES))
    return h.hexdigest()[:16]


@dataclass(slots=True)
class McapCatalog:
    """What is in an MCAP file, from its summary or (unindexed or damaged files) from one pass over it."""

    path: Path
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    indexed: bool = False
    damage: str | None = None
    profile: str = ""
    damage_note: str | None = None  # a damaged index, read past by reading the file through

    @property
    def types(self) -> dict[str, str]:
        return {name: t.type for name, t in self.topics.items()}

    @property
    def duration_s(self) -> float:
        return 0.0 if self.start_ns is None or self.end_ns is None else (self.end_ns - self.start_ns) * 1e-9


def _add_topic(cat: McapCatalog, channel: Channel, schema: Schema | None, count: int) -> None:
    info = cat.topics.get(channel.topic)
    if info is None:
        name = schema.name if schema is not None else "(no schema)"
        cat.topics[channel.topic] = TopicInfo(channel.topic, name, count, channel.message_encoding)
    else:  # several channels on one topic (a ROS 1 recorder does this): counts add up
        info.count += count


def _tail_is_magic(fh: IO[bytes]) -> bool:
    fh.seek(0, 2)
    if fh.tell() < 2 * len(MCAP_MAGIC):
        return False
    fh.seek(-len(MCAP_MAGIC), 2)
    ok = fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    fh.seek(0)
    return ok


def read_catalog(path: Path, progress: bool = False) -> McapCatalog:
    """Topics, types, counts and time span of an MCAP file; raises InputError if it is not one."""
    if not is_mcap(path):
        raise InputError("not an MCAP file (it does not start with the MCAP magic bytes)", path)
    cat = McapCatalog(path)
    with path.open("rb") as fh:
        summary = None
        if _tail_is_magic(fh):
            try:  # SeekingReader checks the magic where the handle stands: at the start
                summary = SeekingReader(fh, record_size_limit=_RECORD_LIMIT).get_summary()
                fh.seek(0)
                cat.profile = SeekingReader(fh, record_size_limit=_RECORD_LIMIT).get_header().profile
            except DAMAGE_ERRORS:
                summary = None
        bad_index = _bad_chunk_index(fh, summary.chunk_indexes) if summary is not None else None
        if bad_index is not None:  # offsets that lead nowhere: every intact chunk is found by reading the file through
            warnings.warn(DamagedLogWarning(f"{path}: {bad_index}; reading the file record by record"), stacklevel=2)
            cat.damage_note = bad_index
        elif summary is not None and summary.statistics is not None and summary.chunk_indexes:
            cat.indexed = True
            counts = summary.statistics.channel_message_counts
            for cid, channel in summary.channels.items():
                _add_topic(cat, channel, summary.schemas.get(channel.schema_id), counts.get(cid, 0))
            if summary.statistics.message_count:
                cat.start_ns = summary.statistics.message_start_time
                cat.end_ns = summary.statistics.message_end_time
            return cat
        fh.seek(0)
        _scan_stream(fh, cat, progress)
    return cat


def _bad_chunk_index(fh: IO[bytes], indexes: list[ChunkIndex]) -> str | None:
    """Why the summary's chunk index cannot be trusted (an entry that does not lead to a chunk record of its
    length inside the file), or None: a few bytes read per chunk."""
    size = fh.seek(0, 2)
    try:
        for ci in indexes:
            end = ci.chunk_start_offset + ci.chunk_length
            if ci.chunk_start_offset < len(MCAP_MAGIC) or ci.chunk_length < 9 + _CHUNK_FIXED or end > size:
                return f"the chunk index points at bytes {ci.chunk_start_offset}..{end} of {size}, where no chunk is"
            fh.seek(ci.chunk_start_offset)
            head = fh.read(9)
            if len(head) < 9 or head[0] != Opcode.CHUNK or struct.unpack_from("<Q", head, 1)[0] != ci.chunk_length - 9:
                return f"the chunk index points at byte {ci.chunk_start_offset}, where no chunk of its length starts"
    finally:
        fh.seek(0)
    return None


def _scan_stream(fh: IO[bytes], cat: McapCatalog, progress: bool) -> None:
    """Fill a catalog by reading every record up to the end or the damage (corrupt chunks are passed over)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    size = fh.seek(0, 2)
    fh.seek(0)
    try:
        with bar(size, desc=f"{cat.path.name} (no index)", unit="B", show=progress) as pbar:
            last = 0
            reader = StreamReader(fh, skip_magic=False, emit_chunks=True, record_size_limit=_record_limit())
            for outer in reader.records:
                try:
                    inner = _chunk_records(outer, fh.tell()) if isinstance(outer, Chunk) else [outer]
                except _BadChunk:
                    inner = []
                for record in inner:
                    if isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Message):
                        counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                        t = record.log_time
                        cat.start_ns = t if cat.start_ns is None else min(cat.start_ns, t)
                        cat.end_ns = t if cat.end_ns is None else max(cat.end_ns, t)
                    elif hasattr(record, "profile"):
                        cat.profile = record.profile
                pos = fh.tell()
                pbar.update(pos - last)
                last = pos
    except DAMAGE_ERRORS as exc:
        cat.damage = damage_reason(exc, fh.tell(), size)
    for cid, channel in channels.items():
        _add_topic(cat, channel, schemas.get(channel.schema_id), counts.get(cid, 0))


class _Decoders:
    """Message decoders per schema, from the mcap support libraries (ROS 2 CDR, ROS 1, protobuf)."""

    def __init__(self) -> None:
        self._cache: dict[int, Callable[[bytes], Any]] = {}

    def get(self, schema: Schema | None, channel: Channel) -> Callable[[bytes], Any]:
        if schema is None:
            raise InputError(f"topic {channel.topic} has no schema, its messages cannot be decoded")
        fn = self._cache.get(schema.id)
        if fn is None:
            factory: McapDecoderFactory
            if schema.encoding == "ros2msg":
                from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

                factory = Ros2Decoders()
            elif schema.encoding == "ros1msg":
                from mcap_ros1.decoder import DecoderFactory as Ros1Decoders

                factory = Ros1Decoders()
            elif schema.encoding == "protobuf":
                from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders

                factory = ProtobufDecoders()
            else:
                raise InputError(f"topic {channel.topic}: unsupported schema encoding {schema.encoding!r}")
            decoder = factory.decoder_for(channel.message_encoding, schema)
            if decoder is None:
                raise InputError(
                    f"topic {channel.topic}: no decoder for {channel.message_encoding!r} messages of {schema.name}"
                )
            fn = self._cache[schema.id] = decoder
        return fn


def _decode_cloud(decoder: Callable[[bytes], Any], data: bytes, schema_name: str) -> DecodedCloud:
    msg = decoder(data)
    if schema_name == "foxglove.PointCloud":
        return decode_foxglove_pointcloud(msg)
    cloud = decode_pointcloud2(msg)
    return DecodedCloud(cloud.columns, header_stamp_ns(msg), str(msg.header.frame_id), cloud.fields, cloud.height)


class _BadChunk(Exception):
    """A chunk whose bytes do not decompress or do not match their CRC; `where` is its file offset."""

    def __init__(self, where: int, start_ns: int, exc: BaseException) -> None:
        what = f"is refused: {exc}" if isinstance(exc, BlockTooLarge) else f"is corrupt ({_reason(exc)})"
        super().__init__(f"the chunk at byte {where} {what}; its messages are skipped")
        self.start_ns = start_ns


def _reason(exc: BaseException) -> str:
    detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}{': ' + detail if detail else ''}"


def _chunk_records(chunk: Chunk, where: int) -> list[Any]:
    """The records of a chunk, its CRC checked (a writer that left it 0 chose not to have one)."""
    try:
        data = inflate(chunk.data, chunk.compression, chunk.uncompressed_size if chunk.compression else None)
        plain = dataclasses.replace(chunk, compression="", data=data)
        return breakup_chunk(plain, validate_crc=True)
    except CHUNK_ERRORS as exc:
        raise _BadChunk(where, chunk.message_start_time, exc) from None


def _read_chunk(fh: IO[bytes], ci: ChunkIndex) -> Chunk:
    """The chunk record an index entry points at (checked by `_bad_chunk_index`), its data no longer than the
    record: a compressed length claiming terabytes reads nothing."""
    fh.seek(ci.chunk_start_offset + 1 + 8)
    stream = ReadDataStream(fh)
    start, end, size, crc, name_length = struct.unpack("<QQQII", stream.read(_CHUNK_FIXED))
    room = ci.chunk_length - 9 - _CHUNK_FIXED
    if name_length > room - 8:
        raise ValueError(f"a compression name of {name_length} bytes")
    compression = stream.read(name_length).decode("utf-8", "replace")
    data_length = stream.read8()
    if data_length > room - name_length - 8:
        raise ValueError(f"{data_length} data bytes in a record of {ci.chunk_length}")
    data = stream.read(data_length) if data_length else b""
    return Chunk(compression, data, end, start, crc, size)


_Item = tuple[Schema | None, Channel, Message] | _BadChunk


def _stream_messages(fh: IO[bytes], topics: set[str], lo: int | None, hi: int | None) -> Iterator[_Item]:
    """Messages of the wanted topics in file order, reading every record; corrupt chunks come as `_BadChunk`."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}

    def wanted(record: Message) -> Channel | None:
        channel = channels.get(record.channel_id)
        if channel is None or channel.topic not in topics:
            return None
        if (lo is not None and record.log_time < lo) or (hi is not None and record.log_time >= hi):
            return None
        return channel

    reader = StreamReader(fh, skip_magic=False, emit_chunks=True, record_size_limit=_record_limit())
    for record in reader.records:
        if isinstance(record, Chunk):
            try:
                inner = _chunk_records(record, fh.tell())
            except _BadChunk as bad:
                yield bad
                continue
        else:
            inner = [record]
        for rec in inner:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message) and (channel := wanted(rec)) is not None:
                yield schemas.get(channel.schema_id), channel, rec


def _indexed_messages(fh: IO[bytes], topics: set[str], lo: int | None, hi: int | None) -> Iterator[_Item]:
    """Messages of the wanted topics in log-time order through the chunk index (as `SeekingReader` reads
    them), each chunk's CRC checked: a corrupt chunk comes as `_BadChunk` and the rest is read."""
    summary = SeekingReader(fh, record_size_limit=_RECORD_LIMIT).get_summary()
    assert summary is not None
    wanted_ids = {cid for cid, ch in summary.channels.items() if ch.topic in topics}
    heap: list[tuple[int, int, int, Any]] = []
    for ci in summary.chunk_indexes:
        if not wanted_ids & set(ci.message_index_offsets):
            continue
        if (lo is not None and ci.message_end_time < lo) or (hi is not None and ci.message_start_time >= hi):
            continue
        heapq.heappush(heap, (ci.message_start_time, ci.chunk_start_offset, -1, ci))
    while heap:
        _, offset, index, item = heapq.heappop(heap)
        if index >= 0:
            yield item
            continue
        try:
            records = _chunk_records(_read_chunk(fh, item), offset)
        except _BadChunk as bad:
            yield bad
            continue
        except DAMAGE_ERRORS as exc:
            yield _BadChunk(offset, item.message_start_time, exc)
            continue
        for k, rec in enumerate(records):
            if not isinstance(rec, Message) or rec.channel_id not in wanted_ids:
                continue
            if (lo is not None and rec.log_time < lo) or (hi is not None and rec.log_time >= hi):
                continue
            channel = summary.channels[rec.channel_id]
            schema = summary.schemas.get(channel.schema_id) if channel.schema_id else None
            heapq.heappush(heap, (rec.log_time, offset, k, (schema, channel, rec)))


def events(
    cat: McapCatalog,
    cloud_topics: set[str],
    pose_topic: str | None = None,
    lo: int | None = None,
    hi: int | None = None,
) -> Iterator[Event]:
    """Cloud (lazily decoded), pose, skipped and damage events of the given topics in log-time order."""
    decoders = _Decoders()
    topics = cloud_topics | ({pose_topic} if pose_topic else set())
    with cat.path.open("rb") as fh:
        try:
            reader = _indexed_messages if cat.indexed else _stream_messages
            for item in reader(fh, topics, lo, hi):
                if isinstance(item, _BadChunk):
                    yield Skipped(item.start_ns, "(chunk)", str(item))
                    continue
                schema, channel, message = item
                try:
                    decoder = decoders.get(schema, channel)
                except InputError as exc:  # a topic that cannot be decoded at all: named with the file
                    raise InputError(str(exc), cat.path) from None
                if channel.topic in cloud_topics:
                    name = schema.name if schema is not None else ""
                    decode = partial(_decode_cloud, decoder, message.data, name)
                    yield CloudMessage(message.log_time, channel.topic, decode)
                else:
                    yield pose_event(message.log_time, channel.topic, partial(_decode_pose, decoder, message.data))
        except DAMAGE_ERRORS as exc:
            yield Damage(damage_reason(exc, fh.tell()))
            return
    if not cat.indexed and cat.damage is not None:
        yield Damage(cat.damage)


def _decode_pose(decoder: Callable[[bytes], Any], data: bytes) -> tuple[int, np.ndarray]:
    pose = decoder(data)
    return header_stamp_ns(pose), pose_to_matrix(pose.pose)


def open_mcap(path: Path, options: ReadOptions) -> Iterator[Scan]:
    """Scans of one point-cloud topic of an MCAP file (checked now, read lazily); what was skipped and
    the damage, if any, go into `options.report` as it reads."""
    cat = read_catalog(path, progress=options.progress)
    chosen = choose_topic(cat.types, options.topic, path)
    pose = choose_pose_topic(cat.types, options.pose_topic, path)
    lo, hi = options.window_ns(cat.start_ns)
    total = cat.topics[chosen].count if options.start_s is None and options.end_s is None else None
    return assemble(
        events(cat, {chosen}, pose, lo, hi), options, path=path, topic=chosen, with_poses=pose is not None, total=total
    )
