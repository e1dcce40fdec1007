"""Decompression with a bound: never more bytes than a block declares, nor more than this machine can spare.

A 100 KB zstd chunk can inflate to gigabytes and a chunk header can claim terabytes; the libraries' one-call
`decompress` trusts both (https://github.com/indygreg/python-zstandard/issues/82). Here every codec streams into at
most `limit + 1` bytes and a block past its bound raises `BlockTooLarge`, which readers treat as a damaged block.
rosbags (ROS 1 bz2/lz4 chunks, ROS 2 MCAP storage, per-message zstd) is given the same bounded codecs.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Callable
from typing import Any, Final

from aftershock.pipeline.limits import block_cap_bytes

_STEP: Final[int] = 1 << 24


class BlockTooLarge(ValueError):
    """A compressed block that would inflate past what it declares or past what one block may take here."""


def bound_for(declared: int | None) -> int:
    """The most bytes a block declaring `declared` (None: it declares nothing) may inflate to."""
    cap = block_cap_bytes()
    if declared is not None and declared > cap:
        raise BlockTooLarge(f"it declares {declared} uncompressed bytes, more than the {cap} one block may take here")
    return cap if declared is None else declared


def _check(got: int, limit: int, declared: int | None) -> None:
    if got > limit:
        what = f"the {declared} bytes it declares" if declared is not None else f"the {limit} one block may take here"
        raise BlockTooLarge(f"it inflates to more than {what}")
    if declared is not None and got < declared:
        raise BlockTooLarge(f"it inflates to {got} of the {declared} bytes it declares")


def inflate_zstd(data: bytes, declared: int | None = None) -> bytes:
    import zstandard

    limit = bound_for(declared)
    reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
    parts: list[bytes] = []
    got = 0
    while got <= limit:
        part = reader.read(min(limit + 1 - got, _STEP))
        if not part:
            break
        parts.append(part)
        got += len(part)
    _check(got, limit, declared)
    return b"".join(parts)


def inflate_lz4(data: bytes, declared: int | None = None) -> bytes:
    import lz4.frame

    limit = bound_for(declared)
    out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=limit + 1)
    _check(len(out), limit, declared)
    return out


def inflate_bz2(data: bytes, declared: int | None = None) -> bytes:
    limit = bound_for(declared)
    dec = bz2.BZ2Decompressor()
    parts: list[bytes] = []
    got = 0
    rest = data
    while got <= limit and not dec.eof:
        part = dec.decompress(rest, max_length=min(limit + 1 - got, _STEP))
        rest = b""
        if not part and dec.needs_input:
            break
        parts.append(part)
        got += len(part)
    _check(got, limit, declared)
    return b"".join(parts)


def inflate(data: bytes, compression: str, declared: int | None = None) -> bytes:
    """`data` decompressed by its codec name ("", "none", "zstd", "lz4", "bz2"), within its bound."""
    if compression in ("", "none"):
        return data
    codec = {"zstd": inflate_zstd, "lz4": inflate_lz4, "bz2": inflate_bz2}.get(compression)
    if codec is None:
        raise BlockTooLarge(f"unknown compression {compression!r}")
    return codec(data, declared)


# --------------------------------------------------------------------------------------------- rosbags

_installed: list[bool] = []


def bound_rosbags() -> None:
    """Give rosbags the bounded codecs (once per process): its readers decompress a whole chunk in one call."""
    if _installed:
        return
    _installed.append(True)
    import rosbags.rosbag1.reader as r1
    import rosbags.rosbag2.reader as r2
    import rosbags.rosbag2.storage_mcap as m2

    m2.DECOMPRESSORS.update({"lz4": inflate_lz4, "zstd": inflate_zstd})
    r1.decompressors.update({"bz2": inflate_bz2, "lz4": inflate_lz4})
    vars(r2)["zstd"] = _BoundedZstd(r2.zstd)  # per-message compression of ROS 2 bags: `zstd.decompress(data)`
    _bound_ros1_chunks(r1)


class _BoundedZstd:
    """rosbags' `zstd` module with a bounded `decompress` (its `open`, which streams to a file, kept)."""

    def __init__(self, module: Any) -> None:
        self.open = module.open

    @staticmethod
    def decompress(data: bytes) -> bytes:
        return inflate_zstd(data)


def _bound_ros1_chunks(r1: Any) -> None:
    """ROS 1 chunk records declare their uncompressed `size`: each chunk's codec is bound to it."""
    original: Callable[[Any], Any] = r1.Reader.read_chunk

    def read_chunk(self: Any) -> Any:
        at = self.bio.tell()
        chunk = original(self)
        declared = _ros1_chunk_size(self.bio, at)
        codec = chunk.decompressor
        if codec in (inflate_bz2, inflate_lz4):
            chunk = chunk._replace(decompressor=lambda data, codec=codec: codec(data, declared))
        return chunk

    r1.Reader.read_chunk = read_chunk


def _ros1_chunk_size(bio: Any, at: int) -> int | None:
    """The `size` field of the ROS 1 chunk record header at `at` (None if it has none)."""
    back = bio.tell()
    try:
        bio.seek(at)
        (length,) = struct.unpack("<I", bio.read(4))
        header = bio.read(min(length, 1 << 16))
        pos = 0
        while pos + 4 <= len(header):
            (n,) = struct.unpack_from("<I", header, pos)
            name, _, value = header[pos + 4 : pos + 4 + n].partition(b"=")
            if name == b"size" and len(value) == 4:
                return int(struct.unpack("<I", value)[0])
            pos += 4 + n
        return None
    finally:
        bio.seek(back)
