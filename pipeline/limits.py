"""How much memory this process may use, and the bound one decompressed block or one setting may take.

Memory comes from the tightest of: what the kernel says is available (/proc/meminfo MemAvailable), the address-space
limit (`ulimit -v`, RLIMIT_AS, which `batch --worker-memory` sets), and the cgroup's memory.max (a container).
"""

from __future__ import annotations

import os
import resource
from pathlib import Path
from typing import Final

from aftershock.pipeline.errors import InputError

BLOCK_MAX_BYTES: Final[int] = 1 << 30  # a compressed block holding more than 1 GiB in a LiDAR log means a lie
_BLOCK_SHARE: Final[int] = 4  # one block may take a quarter of what is free: the pipeline needs the rest
_SETTING_SHARE: Final[int] = 2  # one setting's arrays may take half of it


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        return max(0, int(limit) - used)
    except (OSError, ValueError):
        return None


def _address_space_room() -> int | None:
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:  # what the process has mapped already counts against the limit
        pages = int(Path("/proc/self/statm").read_text().split()[0])
        mapped = pages * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        mapped = 0
    return max(0, soft - mapped)


def available_bytes() -> int:
    """Bytes this process could still allocate, by the tightest bound known (a large figure if none is)."""
    rooms = [r for r in (_meminfo_available(), _cgroup_room(), _address_space_room()) if r is not None]
    return min(rooms) if rooms else 1 << 40


def block_cap_bytes() -> int:
    """The most one decompressed block (an MCAP chunk, a bag chunk, a PCD body) may take."""
    return max(1 << 20, min(BLOCK_MAX_BYTES, available_bytes() // _BLOCK_SHARE))


def check_allocation(nbytes: float, setting: str, what: str) -> None:
    """InputError naming `setting` when `nbytes` (what its value implies) exceeds what this machine can hold."""
    room = available_bytes() // _SETTING_SHARE
    if not nbytes <= room:  # also refuses NaN
        raise InputError(
            f"{setting}: {what} would need {_size(nbytes)}, more than this machine can give ({_size(room)} free)"
        )


def _size(nbytes: float) -> str:
    if nbytes != nbytes or nbytes == float("inf"):
        return "unbounded memory"
    for unit, scale in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} bytes"
