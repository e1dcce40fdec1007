"""Hostile inputs for the fault tests: logs with single bad messages (malformed PointCloud2, truncated CDR, zero
or NaN pose quaternions), corrupted chunks, size bombs, and a small tmpfs to fill a disk.

Every log is written message by message with the project's own CDR serialisers, so a test controls each byte.
"""

from __future__ import annotations

import os
import struct
import subprocess
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Final

import numpy as np
from fixtures import PERIOD_NS, T0_NS, chunk_offsets
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from aftershock.pipeline.pointcloud2 import (
    encode_pointcloud2,
    pose_stamped_message,
    register_cloud_and_pose,
    serialize_pointcloud2,
    serialize_pose_stamped,
)

CLOUD_TOPIC: Final = "/points"
POSE_TOPIC: Final = "/ground_truth/pose"

# One bad PointCloud2 message: the message dict changed (malformed fields) or its CDR bytes cut (truncated).
MsgEdit = Callable[[dict], dict]
MALFORMED: Final[dict[str, MsgEdit]] = {
    "short data": lambda m: {**m, "data": m["data"][: len(m["data"]) // 2]},
    "point_step 0": lambda m: {**m, "point_step": 0},
    "unknown datatype": lambda m: {
        **m,
        "fields": [{**f, "datatype": 42} if f["name"] == "x" else f for f in m["fields"]],
    },
    "field past the step": lambda m: {
        **m,
        "fields": [{**f, "offset": m["point_step"]} if f["name"] == "z" else f for f in m["fields"]],
    },
}


def hall_clouds(scans: int, points: int = 4000, seed: int = 0) -> tuple[list[dict[str, np.ndarray]], list[np.ndarray]]:
    """Scans of a 12 x 8 x 3 m hall (floor, ceiling, walls, boxes) from a sensor moving along it, with true poses."""
    rng = np.random.default_rng(seed)
    parts = []
    x, y, z = np.eye(3)
    for origin, u, v, n in (
        ([0, 0, 0], 12 * x, 8 * y, 60_000),
        ([0, 0, 3], 12 * x, 8 * y, 60_000),
        ([0, 0, 0], 12 * x, 3 * z, 20_000),
        ([0, 8, 0], 12 * x, 3 * z, 20_000),
        ([0, 0, 0], 8 * y, 3 * z, 15_000),
        ([12, 0, 0], 8 * y, 3 * z, 15_000),
        ([3, 2, 0], 0.8 * x, 0.7 * z, 3000),
        ([7, 5, 0], 0.8 * y, 0.9 * z, 3000),
    ):
        a = rng.uniform(0, 1, (n, 2))
        parts.append(np.asarray(origin, float) + a[:, :1] * u + a[:, 1:] * v)
    world = np.vstack(parts)
    clouds, poses = [], []
    for k in range(scans):
        pose = np.eye(4)
        pose[:3, 3] = [2.0 + 0.1 * k, 4.0, 1.0]
        pick = rng.integers(0, len(world), points)
        local = world[pick] - pose[:3, 3] + rng.normal(0, 0.003, (points, 3))
        clouds.append({a: local[:, i].astype(np.float32) for i, a in enumerate("xyz")})
        poses.append(pose)
    return clouds, poses


def write_log(
    path: Path,
    scans: int = 12,
    *,
    bad_clouds: Mapping[int, MsgEdit | int | Callable[[bytes], bytes]] | None = None,
    bad_poses: Mapping[int, tuple[float, float, float, float]] | None = None,
    chunk_size: int = 1 << 20,
    compression: CompressionType = CompressionType.ZSTD,
    points: int = 4000,
) -> Path:
    """A ROS 2 MCAP of hall scans with true poses. `bad_clouds[k]`: an edit of message k's dict, or an int n to cut
    its CDR bytes to n; `bad_poses[k]`: the (x, y, z, w) quaternion pose k carries instead of its own."""
    clouds, poses = hall_clouds(scans, points)
    with path.open("wb") as fh:
        w = McapWriter(fh, chunk_size=chunk_size, compression=compression)
        w.start(profile="ros2", library="aftershock-tests")
        cc, pc = register_cloud_and_pose(w, CLOUD_TOPIC, POSE_TOPIC)
        for k, cols in enumerate(clouds):
            t = T0_NS + k * PERIOD_NS
            pose = pose_stamped_message(poses[k], t)
            if bad_poses and k in bad_poses:
                qx, qy, qz, qw = bad_poses[k]
                pose["pose"]["orientation"] = {"x": qx, "y": qy, "z": qz, "w": qw}
            w.add_message(pc, log_time=t, data=serialize_pose_stamped(pose), publish_time=t)
            msg = encode_pointcloud2(cols, stamp_ns=t, frame_id="lidar")
            edit = (bad_clouds or {}).get(k)
            raw_edit = getattr(edit, "raw", False)
            if callable(edit) and not raw_edit:
                msg = edit(msg)
            data = serialize_pointcloud2(msg)
            if isinstance(edit, int):
                data = data[:edit]
            elif raw_edit:
                data = edit(data)
            w.add_message(cc, log_time=t + PERIOD_NS // 2, data=data, publish_time=t)
        w.finish()
    return path


def _claim_2_31_bytes(data: bytes) -> bytes:
    """CDR bytes of a PointCloud2 whose data array declares 2**31 bytes but holds 16."""
    at = _data_length_at(data)
    return data[:at] + struct.pack("<I", 2**31) + data[at + 4 : at + 4 + 16] + data[-1:]


def _data_length_at(data: bytes) -> int:
    """Offset of the data array's length field: it is followed by the data and the is_dense byte."""
    for at in range(len(data) - 5, 0, -1):
        if struct.unpack_from("<I", data, at)[0] == len(data) - at - 5:
            return at
    raise ValueError("no data length field")


_claim_2_31_bytes.raw = True  # type: ignore[attr-defined]


def huge_data_length(path: Path, scans: int = 6, at: int = 3) -> Path:
    """A log whose message `at` declares a data array of 2**31 bytes (and holds 16)."""
    return write_log(path, scans, bad_clouds={at: _claim_2_31_bytes})


def corrupt_chunk(src: Path, dst: Path, chunk: int) -> Path:
    """A copy of an uncompressed MCAP with one byte flipped in the middle of chunk `chunk` (its CRC now fails)."""
    start, length = chunk_offsets(src)[chunk]
    raw = bytearray(src.read_bytes())
    raw[start + length // 2] ^= 0xFF
    dst.write_bytes(bytes(raw))
    return dst


def strip_summary(src: Path, dst: Path) -> Path:
    """A copy without summary and footer (a recorder that died before finishing): read as a plain stream."""
    with src.open("rb") as fh:
        from mcap.reader import make_reader

        summary = make_reader(fh).get_summary()
    assert summary is not None
    end = max(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    dst.write_bytes(src.read_bytes()[:end])
    return dst


def pcd_size_bomb(path: Path, points: int = 2**28) -> Path:
    """A 138-byte-class PCD claiming `points` xyz float points in binary_compressed LZF data it does not hold."""
    header = (
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {points}\nHEIGHT 1\nPOINTS {points}\nDATA binary_compressed\n"
    ).encode()
    path.write_bytes(header + struct.pack("<II", 16, points * 12) + b"\x00" * 16)
    return path


# --------------------------------------------------------------------------------------------- a small disk


def can_mount() -> str | None:
    """Why a tmpfs cannot be mounted here (None: it can)."""
    if os.geteuid() != 0:
        return "mounting a tmpfs needs root"
    return None


@contextmanager
def small_disk(where: Path, size: str = "2m") -> Iterator[Path]:
    """A tmpfs of `size` mounted at `where` for the block's duration."""
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    if done.returncode != 0:
        import pytest

        pytest.skip(f"cannot mount a tmpfs: {done.stderr.decode().strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def fill_disk(where: Path, leave_bytes: int) -> None:
    """Fill the file system of `where` until `leave_bytes` are free."""
    with (where / "filler").open("wb") as fh:
        taken = 0
        for _ in range(100):  # the run writes meanwhile: take what is free, until the rest is left
            st = os.statvfs(where)
            want = st.f_bavail * st.f_frsize - leave_bytes
            if want <= 0:
                return
            try:
                os.posix_fallocate(fh.fileno(), taken, want)
                taken += want
            except OSError:
                want //= 2
