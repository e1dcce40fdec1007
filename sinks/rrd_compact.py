"""A finished recording rewritten in fewer, larger chunks (`rerun rrd optimize`), so that a viewer takes it in
quickly.

A recording is written as it streams, a chunk per entity about every second: a long mission makes thousands
of chunks, and Rerun's web viewer (single-threaded WebAssembly) then stays unresponsive for minutes while it
takes them in, however small they are; the same data in a few hundred chunks opens
(docs/benchmarks/long-mission.md). The rewrite goes to a file beside the recording that replaces it only
when complete, so an interrupted or failed rewrite leaves the recording as it was."""

from __future__ import annotations

import contextlib
import logging
import os
import subprocess
from pathlib import Path
from typing import Final

from aftershock.sinks.rerun_viewer import rerun_command

log = logging.getLogger(__name__)

# `rerun rrd optimize` holds the whole recording in memory (about 1.7x the file): larger ones stay as written.
MAX_BYTES: Final = 2 * 2**30
TIMEOUT_S: Final = 600.0


def compact(path: Path) -> bool:
    """Rewrite the recording at `path` in fewer, larger chunks; False (the file as it was) if that failed."""
    size = path.stat().st_size
    if size > MAX_BYTES:
        log.warning("%s: %.1f GB, left as written (compacting would hold it all in memory)", path, size / 1e9)
        return False
    tmp = path.with_name(f".{path.name}.compacting")
    cmd = [rerun_command(), "rrd", "optimize", str(path), "-o", str(tmp)]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=TIMEOUT_S)
        ok = done.returncode == 0 and tmp.is_file() and tmp.stat().st_size > 0
        if ok:
            os.replace(tmp, path)
            return True
        log.warning("%s: left as written (rerun rrd optimize: %s)", path, done.stderr.strip()[-300:])
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.warning("%s: left as written (%s)", path, exc)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return False
