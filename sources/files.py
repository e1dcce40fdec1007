"""Scans from point-cloud files: a folder or glob of `.pcd`, `.ply` and KITTI `.bin`, read in name order.

Files carry no time: scan k is stamped k * FILE_PERIOD_NS (a 10 Hz sensor), which is also the time
`--start/--end` refer to.
"""

from __future__ import annotations

import glob
import os
import re
import struct
import warnings
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Final

import numpy as np

from aftershock.pipeline.errors import DamagedLogWarning, InputError
from aftershock.pipeline.limits import block_cap_bytes
from aftershock.pipeline.types import Scan
from aftershock.sources.common import CloudMessage, DecodedCloud, Event, ReadOptions, assemble

SUFFIXES: Final[tuple[str, ...]] = (".pcd", ".ply", ".bin")
FILE_PERIOD_NS: Final[int] = 100_000_000
FILES_TOPIC: Final[str] = "files"
KITTI_FIELDS: Final[tuple[str, ...]] = ("x", "y", "z", "intensity")
_PCD_TYPES: Final[dict[tuple[str, int], str]] = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
}


def is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def _natural_key(p: Path) -> list[int | str]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", p.name)]


def list_files(path_or_glob: str | Path) -> list[Path]:
    """The readable point-cloud files of a folder, a glob or a single file, in (natural) name order."""
    text = str(path_or_glob)
    if is_glob(text) and not Path(text).exists():  # a real folder named `run[1]` is that folder, not a pattern
        found = [Path(p) for p in glob.glob(text) if Path(p).is_file()]
    else:
        p = Path(text)
        if p.is_dir():
            try:
                found = [q for q in p.iterdir() if q.is_file()]
            except OSError as exc:
                raise InputError(f"cannot list the folder ({exc.strerror})", p) from None
        elif p.is_file():
            found = [p]
        else:  # a device, a pipe, a symlink to /dev/zero: reading it would never end
            raise InputError("not a regular file or folder", p)
    files = sorted((f for f in found if f.suffix.lower() in SUFFIXES), key=_natural_key)
    if not files:
        raise InputError("nothing readable here: no .mcap, ROS bag, .pcd, .ply or KITTI .bin files", path_or_glob)
    for f in files:  # refused now, not after minutes of work on the files before it
        if not os.access(f, os.R_OK):
            raise InputError("cannot read the file (permission denied)", f)
    return files


# --------------------------------------------------------------------------------------------- PCD


def lzf_decompress(src: bytes, size: int) -> bytes:
    """LZF decompression (PCD `binary_compressed`): one step per literal run or back reference."""
    out = bytearray(size)
    i = o = 0
    n = len(src)
    while i < n:
        ctrl = src[i]
        i += 1
        if ctrl < 32:
            length = ctrl + 1
            out[o : o + length] = src[i : i + length]
            i += length
        else:
            length = ctrl >> 5
            if length == 7:
                length += src[i]
                i += 1
            length += 2
            ref = o - ((ctrl & 0x1F) << 8) - src[i] - 1
            i += 1
            if ref < 0:
                raise ValueError("corrupt LZF data (reference before the start)")
            if ref + length <= o:
                out[o : o + length] = out[ref : ref + length]
            else:  # overlapping copy repeats the pattern between ref and o
                pattern = bytes(out[ref:o])
                out[o : o + length] = (pattern * (length // len(pattern) + 1))[:length]
        o += length
        if o > size:
            raise ValueError("corrupt LZF data (output longer than announced)")
    if o != size:
        raise ValueError(f"corrupt LZF data ({o} of {size} bytes)")
    return bytes(out)


def read_pcd(path: Path) -> dict[str, np.ndarray]:
    """Columns of a PCD file (ascii, binary or binary_compressed); `_` padding fields are skipped."""
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise InputError("not a PCD file: the header has no DATA line", path)
        line = raw[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    try:
        names = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = [t.upper() for t in header["TYPE"]]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        n = int(header["POINTS"][0]) if "POINTS" in header else int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
        kind = header["DATA"][0].lower()
        bases = [np.dtype("<" + _PCD_TYPES[(t, s)]) for t, s in zip(types, sizes, strict=True)]
    except (KeyError, ValueError, IndexError) as exc:
        raise InputError(f"not a valid PCD header ({type(exc).__name__}: {exc})", path) from None
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError("PCD header: FIELDS, SIZE, TYPE and COUNT differ in length", path)
    if min(counts, default=0) < 1:
        raise InputError(f"PCD header: COUNT {' '.join(map(str, counts))} has a field of no values", path)
    if n < 0:
        raise InputError(f"PCD header: {n} points", path)
    body = raw[pos:]
    point_bytes = sum(b.itemsize * c for b, c in zip(bases, counts, strict=True))
    _check_pcd_sizes(kind, body, n, point_bytes, path)
    cols: dict[str, np.ndarray] = {}
    try:
        if kind == "ascii":
            table = np.loadtxt(body.decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
            if len(table) < n:
                raise InputError(f"PCD declares {n} points but its ascii data holds {len(table)} rows", path)
            if len(table) > n:
                warnings.warn(
                    DamagedLogWarning(f"{path}: PCD declares {n} points but holds {len(table)} rows; read {n}"),
                    stacklevel=2,
                )
            table = table[:n]
            start = 0
            for name, base, c in zip(names, bases, counts, strict=True):
                if name != "_":
                    block = table[:, start : start + c].astype(base)
                    cols[name] = block[:, 0] if c == 1 else block
                start += c
        elif kind == "binary":
            layout = [
                (f"_{i}" if name == "_" else name, base, (c,)) if c > 1 else (f"_{i}" if name == "_" else name, base)
                for i, (name, base, c) in enumerate(zip(names, bases, counts, strict=True))
            ]
            rec = np.frombuffer(body, dtype=np.dtype(layout), count=n)
            cols = {name: rec[name].copy() for name in rec.dtype.names or () if not name.startswith("_")}
        elif kind == "binary_compressed":
            packed, size = struct.unpack_from("<II", body)
            data = lzf_decompress(body[8 : 8 + packed], size)
            start = 0
            for name, base, c in zip(names, bases, counts, strict=True):  # field-major layout
                nbytes = base.itemsize * c * n
                arr = np.frombuffer(data, dtype=base, count=c * n, offset=start).reshape(n, c)
                start += nbytes
                if name != "_":
                    cols[name] = arr[:, 0].copy() if c == 1 else arr.copy()
        else:
            raise InputError(f"PCD DATA {kind!r} is not ascii, binary or binary_compressed", path)
    except (ValueError, struct.error) as exc:
        raise InputError(f"PCD data is damaged or shorter than the header says ({exc})", path) from None
    return cols


_LZF_MAX_RATIO: Final[int] = 88  # LZF's best case: a 3-byte back reference expands to 264 bytes


def _check_pcd_sizes(kind: str, body: bytes, n: int, point_bytes: int, path: Path) -> None:
    """The sizes a PCD header declares, against the bytes the file holds, before anything is allocated: a
    138-byte file claiming gigabytes of points is refused at once."""
    if kind == "binary" and len(body) < n * point_bytes:
        raise InputError(f"PCD declares {n} points ({n * point_bytes} bytes) but holds {len(body)} bytes", path)
    if kind != "binary_compressed":
        return
    if len(body) < 8:
        raise InputError("PCD binary_compressed data has no size header", path)
    packed, size = struct.unpack_from("<II", body)
    if size != n * point_bytes:
        raise InputError(f"PCD declares {n} points of {point_bytes} bytes but {size} uncompressed bytes", path)
    if packed > len(body) - 8:
        raise InputError(f"PCD declares {packed} compressed bytes but holds {len(body) - 8}", path)
    if size > packed * _LZF_MAX_RATIO + 64:
        raise InputError(f"PCD claims {size} bytes from {packed} compressed ones, more than LZF can give", path)
    if size > (cap := block_cap_bytes()):
        raise InputError(f"PCD claims {size} uncompressed bytes, more than the {cap} one file may take here", path)


# --------------------------------------------------------------------------------------------- PLY, KITTI


def read_ply(path: Path) -> dict[str, np.ndarray]:
    from plyfile import PlyData, PlyParseError

    from aftershock.pipeline.cloud_io import check_ply_body

    check_ply_body(path)
    try:
        vertex = PlyData.read(str(path))["vertex"].data
    except (PlyParseError, KeyError, ValueError, EOFError, UnicodeDecodeError) as exc:
        raise InputError(f"not a readable PLY point cloud ({exc})", path) from None
    return {name: np.asarray(vertex[name]) for name in vertex.dtype.names}


def read_kitti_bin(path: Path) -> dict[str, np.ndarray]:
    size = path.stat().st_size
    if size % 16:
        raise InputError(f"not a KITTI .bin scan: {size} bytes is not a multiple of 16 (x y z intensity float32)", path)
    data = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    return {name: data[:, i] for i, name in enumerate(KITTI_FIELDS)}


def read_file(path: Path) -> dict[str, np.ndarray]:
    """Columns of one point-cloud file, by its suffix; InputError naming the file for anything unreadable."""
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError("not a regular file", path)
    try:
        if suffix == ".pcd":
            return read_pcd(path)
        if suffix == ".ply":
            return read_ply(path)
        if suffix == ".bin":
            return read_kitti_bin(path)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    except MemoryError:
        raise InputError("the file claims more points than fit in memory", path) from None
    raise InputError(f"unknown point-cloud file type {suffix!r}", path)


def events(files: list[Path], lo: int | None, hi: int | None) -> Iterator[Event]:
    for k, f in enumerate(files):
        t = k * FILE_PERIOD_NS
        if (lo is not None and t < lo) or (hi is not None and t >= hi):
            continue
        yield CloudMessage(t, FILES_TOPIC, partial(_decode_file, f, t))


def _decode_file(path: Path, stamp_ns: int) -> DecodedCloud:
    cols = read_file(path)
    if not {"x", "y", "z"} <= {k.lower() for k in cols}:
        raise InputError(f"no x/y/z fields (fields: {', '.join(cols) or 'none'})", path)
    return DecodedCloud(cols, stamp_ns, "")


def open_files(path: str | Path, options: ReadOptions) -> Iterator[Scan]:
    """Scans from a folder, glob or single point-cloud file. `topic`/`pose_topic` do not apply to files."""
    files = list_files(path)
    lo, hi = options.window_ns(0)
    total = len(files) if lo is None and hi is None else None
    return assemble(events(files, lo, hi), options, path=path, topic=FILES_TOPIC, with_poses=False, total=total)
