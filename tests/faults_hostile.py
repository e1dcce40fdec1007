"""Hostile inputs of the second fault round: compression bombs, chunk headers and indexes that lie, log times past
2**63, and the child-process harness that measures what a command really took (peak RSS) under a memory limit.
"""

from __future__ import annotations

import base64
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from fixtures import chunk_offsets

ENV: Final = dict(os.environ, CI="true", RERUN_ANALYTICS="0", OMP_NUM_THREADS="1", NO_COLOR="1")
GiB: Final = 1 << 30
_ZSTD_MAGIC: Final = b"\x28\xb5\x2f\xfd"
_ZSTD_BLOCK: Final = 1 << 17

# bz2 (level 9) of 1 GiB of zero bytes: 785 bytes, made once with bz2.BZ2Compressor(9) (13 s); streams concatenate.
BZ2_GIB_OF_ZEROS: Final = base64.b64decode(
    "QlpoOTFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1kO"
    "CeLfAV+OQADAAAAIIAAwgE1GQqAlqQqAlzFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAA"
    "CCAAMIBNRkKgJakKgJcxQVkmU1kOCeLfAV+OQADAAAAIIAAwgE1GQqAlqQqAlzFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWp"
    "CoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1kOCeLfAV+OQADAAAAIIAAwgE1GQqAlqQqAlzFBWSZTWQ4J"
    "4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1kOCeLfAV+OQADAAAAI"
    "IAAwgE1GQqAlqQqAlzFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakK"
    "gJcxQVkmU1kOCeLfAV+OQADAAAAIIAAwgE1GQqAlqQqAlzFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni"
    "3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1kOCeLfAV+OQADAAAAIIAAwgE1GQqAlqQqAlzFBWSZTWQ4J4t8BX45AAMAAAAgg"
    "ADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1kOCeLfAV+OQADAAAAIIAAwgE1GQqAlqQqA"
    "lzFBWSZTWQ4J4t8BX45AAMAAAAggADCATUZCoCWpCoCXMUFZJlNZDgni3wFfjkAAwAAACCAAMIBNRkKgJakKgJcxQVkmU1lIfF/J"
    "AIpSyADAAAAEAAggADDMBSmmkSJDYUSJDxdyRThQkPaI5AI="
)


def zstd_zeros(nbytes: int, content_size: bool = True) -> bytes:
    """A zstd frame of `nbytes` zero bytes built from RLE blocks (4 bytes per 128 KiB): 3 GiB takes 98 KB. With
    `content_size` its header says how much it holds (one-call decoders allocate that at once); without, only
    streaming it tells how far it goes."""
    full, rest = divmod(nbytes, _ZSTD_BLOCK)
    sizes = [_ZSTD_BLOCK] * full + ([rest] if rest else [])
    blocks = b"".join(
        ((size << 3) | (1 << 1) | int(k == len(sizes) - 1)).to_bytes(3, "little") + b"\x00"
        for k, size in enumerate(sizes)
    )
    if content_size:  # descriptor: an 8-byte frame content size, no checksum; a 128 KiB window
        return _ZSTD_MAGIC + b"\xc0\x38" + struct.pack("<Q", nbytes) + blocks
    return _ZSTD_MAGIC + b"\x00\x38" + blocks


def _skippable(nbytes: int) -> bytes:
    """A zstd skippable frame of exactly `nbytes` bytes (decoders pass over it)."""
    assert nbytes >= 8
    return struct.pack("<II", 0x184D2A50, nbytes - 8) + b"\x00" * (nbytes - 8)


@dataclass(frozen=True, slots=True)
class ChunkFields:
    """Byte offsets of one MCAP chunk record's fields."""

    start: int  # the opcode
    usize: int  # uncompressed size (u64)
    crc: int  # uncompressed crc (u32)
    data: int  # first data byte
    data_length: int


def chunk_fields(path: Path, chunk: int) -> ChunkFields:
    start, _ = chunk_offsets(path)[chunk]
    raw = path.read_bytes()
    name_len = struct.unpack_from("<I", raw, start + 9 + 28)[0]
    at = start + 9 + 32 + name_len
    (data_length,) = struct.unpack_from("<Q", raw, at)
    return ChunkFields(start, start + 9 + 16, start + 9 + 24, at + 8, data_length)


def mcap_chunk_bomb(src: Path, dst: Path, chunk: int, *, inflates_to: int | None, declares: int | None) -> Path:
    """A copy of a zstd MCAP whose chunk `chunk` holds `inflates_to` zero bytes (None: its own data) and declares
    `declares` uncompressed bytes (None: what it declared); the record keeps its length, so index and summary
    still point right, and its CRC is 0 (not checked), as a writer may leave it."""
    f = chunk_fields(src, chunk)
    raw = bytearray(src.read_bytes())
    if inflates_to is not None:
        bomb = zstd_zeros(inflates_to)
        assert len(bomb) + 8 <= f.data_length, "the chunk is too small to hold the bomb"
        raw[f.data : f.data + f.data_length] = bomb + _skippable(f.data_length - len(bomb))
        raw[f.crc : f.crc + 4] = b"\x00" * 4
    if declares is not None:
        raw[f.usize : f.usize + 8] = struct.pack("<Q", declares)
    dst.write_bytes(bytes(raw))
    return dst


def ros1_bz2_bomb(path: Path, clouds: Sequence[dict], *, bomb_chunk: int = 1, gib: int = 3) -> Path:
    """A ROS 1 bag (bz2 chunks) whose chunk `bomb_chunk` holds `gib` GiB of zeros while its header declares the
    size of the messages it was meant to hold: a few KB on disk."""
    from fixtures import PERIOD_NS, T0_NS, _rosbags_cloud
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.LATEST)
    msgtype = "sensor_msgs/msg/PointCloud2"
    w = Writer(path)
    w.set_compression(Writer.CompressionFormat.BZ2)
    w.chunk_threshold = 1  # one message per chunk
    with w:
        compress = w.compressor
        seen = [0]

        def lying(data: bytes) -> bytes:
            seen[0] += 1
            return BZ2_GIB_OF_ZEROS * gib if seen[0] - 1 == bomb_chunk else compress(data)

        w.compressor = lying
        conn = w.add_connection("/points", msgtype, typestore=ts)
        for k, cols in enumerate(clouds):
            t = T0_NS + k * PERIOD_NS
            w.write(conn, t, ts.serialize_ros1(_rosbags_cloud(ts, cols, t, "lidar"), msgtype))
    return path


@dataclass(frozen=True, slots=True)
class Finished:
    returncode: int
    stdout: str
    stderr: str
    peak_rss_mb: float  # the child's own peak resident memory (getrusage of that child)


# The child is started by a small launcher that forks it and reports its rusage: Linux counts the RSS a process had
# when it was forked into its child's ru_maxrss, so a child forked from pytest itself would carry pytest's size.
_LAUNCHER: Final = """
import os, resource, signal, sys
limit, report, argv = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
pid = os.fork()
if pid == 0:
    if limit:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    os.execv(argv[0], argv)
signal.signal(signal.SIGINT, signal.SIG_IGN)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as f:
    f.write(str(usage.ru_maxrss))
code = os.waitstatus_to_exitcode(status)
if code < 0:
    signal.signal(-code, signal.SIG_DFL)
    os.kill(os.getpid(), -code)
sys.exit(code)
"""


def cli_measured(args: list[str], *, address_space: int | None = None, timeout: float = 120) -> Finished:
    """The command line in a child process, under an address-space limit (RLIMIT_AS) if given, with its own peak
    RSS from wait4 (taken by a launcher, see above)."""
    with tempfile.NamedTemporaryFile("r", suffix=".maxrss") as report:
        cmd = [sys.executable, "-c", _LAUNCHER, str(address_space or 0), report.name]
        cmd += [sys.executable, "-m", "aftershock.pipeline", *args]
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, start_new_session=True
        )
        streams: dict[str, str] = {}

        def drain(name: str) -> None:
            streams[name] = getattr(proc, name).read()

        readers = [threading.Thread(target=drain, args=(n,), daemon=True) for n in ("stdout", "stderr")]
        for t in readers:
            t.start()
        timed_out: list[bool] = []

        def kill() -> None:
            timed_out.append(True)
            os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the command it started

        killer = threading.Timer(timeout, kill)
        killer.start()
        try:
            proc.wait()
        finally:
            killer.cancel()
        for t in readers:
            t.join(10)
        assert not timed_out, f"{args} did not end in {timeout} s: {streams.get('stderr', '')[-2000:]}"
        maxrss_kb = int(report.read() or 0)
    return Finished(proc.returncode, streams.get("stdout", ""), streams.get("stderr", ""), maxrss_kb / 1024)


def repoint_chunk_index(src: Path, dst: Path, chunk: int, to: int) -> Path:
    """A copy whose summary's index entry for chunk `chunk` says it starts at byte `to` (the chunk stays put)."""
    start, _ = chunk_offsets(src)[chunk]
    raw = bytearray(src.read_bytes())
    end = max(s + n for s, n in chunk_offsets(src))
    at = raw.find(struct.pack("<Q", start), end)  # the ChunkIndex record in the summary, after every chunk
    assert at > 0
    raw[at : at + 8] = struct.pack("<Q", to)
    dst.write_bytes(bytes(raw))
    return dst


def log_with_late_times(path: Path, scans: int = 10, late: Sequence[int] = (4,), points: int = 3000) -> Path:
    """A ROS 2 MCAP of hall scans where the messages of scans `late` are logged at 2**63 ns or later (past what a
    signed 64-bit time can hold: year 2262), header stamps too."""
    from faults_data import hall_clouds, pose_stamped_message
    from fixtures import PERIOD_NS, T0_NS
    from mcap.writer import Writer

    from aftershock.pipeline.pointcloud2 import (
        POINTCLOUD2_MSGDEF,
        POSE_STAMPED_MSGDEF,
        encode_pointcloud2,
        serialize_pointcloud2,
        serialize_pose_stamped,
    )

    clouds, poses = hall_clouds(scans, points)
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="aftershock-tests")
        cs = w.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", POINTCLOUD2_MSGDEF.encode())
        ps = w.register_schema("geometry_msgs/msg/PoseStamped", "ros2msg", POSE_STAMPED_MSGDEF.encode())
        cc = w.register_channel("/points", "cdr", cs)
        pc = w.register_channel("/ground_truth/pose", "cdr", ps)
        for k, cols in enumerate(clouds):
            t = T0_NS + k * PERIOD_NS
            log_t = (1 << 63) + k if k in late else t
            w.add_message(
                pc, log_time=log_t, data=serialize_pose_stamped(pose_stamped_message(poses[k], t)), publish_time=log_t
            )
            msg = encode_pointcloud2(cols, stamp_ns=t, frame_id="lidar")
            w.add_message(cc, log_time=log_t, data=serialize_pointcloud2(msg), publish_time=log_t)
        w.finish()
    return path
