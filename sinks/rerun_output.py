"""Where a recording goes: an .rrd file, a spawned viewer and/or a remote viewer over gRPC, and what is done when
the file cannot be written (a full disk, a writer that stopped).

Rerun's file writer cannot recover from a full disk: its thread dies and every later flush, disconnect and even
the interpreter's exit wait for ever. So the recording stops while MIN_FREE_BYTES are left (a batch in flight
plus a scan's layers fit), and a flush that makes no progress for FLUSH_STALL_S is given up.

The file is written as `NAME.part` beside NAME and renamed over NAME when the recording is closed complete: at
the end of a run, after Ctrl-C/SIGTERM (the stream ends and closes its sinks), and when it was stopped while the
disk still had room. A writer that failed (the disk filled at once, a stall) leaves NAME as it was and the cut
file as `NAME.part`, which Rerun reads up to the cut; so does a SIGKILL (pipeline/outputs.py).
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from pathlib import Path
from typing import Final
from urllib.parse import urlsplit

import rerun as rr
import rerun.blueprint as rrb

from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.outputs import check_output, commit, not_regular, part_path
from aftershock.sinks.rrd_compact import compact

SPAWN_PORT: Final = 9876
BATCH_SECONDS: Final = 1.0
BATCH_BYTES: Final = 16 * 2**20
MIN_FREE_BYTES: Final = 3 * BATCH_BYTES
FLUSH_POLL_S: Final = 0.5
FLUSH_STALL_S: Final = 10.0
_WRITE_FAILED: Final = "writing the recording failed"
RECORDING_ID_PREFIX: Final = "aftershock-"
# A finished .rrd ends with Rerun's footer: the magic, then its version (4 bytes). A writer whose last write found
# the disk full says nothing, so a file without it is a cut one (rerun `crates/store/re_log_encoding`, `rrd/footer`).
RRD_FOOTER_MAGIC: Final = b"RRF2FOOT"
RRD_FOOTER_TAIL: Final = len(RRD_FOOTER_MAGIC) + 4


def recording_id_for(log_id: str) -> str:
    """A fresh recording id that names the log it was made from (`view` checks it): aftershock-<log>-<run>."""
    run = uuid.uuid4().hex[:12]
    return f"{RECORDING_ID_PREFIX}{log_id}-{run}" if log_id else f"{RECORDING_ID_PREFIX}{run}"


def log_id_of(recording_id: str) -> str | None:
    """The log fingerprint a recording id carries (None for recordings of inputs without one)."""
    if not recording_id.startswith(RECORDING_ID_PREFIX):
        return None
    parts = recording_id[len(RECORDING_ID_PREFIX) :].split("-")
    return parts[0] if len(parts) == 2 else None


def listening(url: str, timeout_s: float = 2.0) -> bool:
    """Whether something accepts TCP connections at the host and port of a Rerun gRPC URL (True if no port)."""
    parts = urlsplit(url.replace("rerun+", "", 1))
    if parts.hostname is None or parts.port is None:
        return True
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout_s):
            return True
    except OSError:
        return False


class RecordingOutput:
    """The recording stream and its outputs. The file's path and the viewer's URL are checked here; the file is
    made and the viewer spawned in `start`."""

    def __init__(
        self,
        save: Path | None,
        spawn: bool,
        connect: str | None,
        force: bool = False,
        application_id: str = "aftershock",
        compact_above_mb: float = 64.0,
    ) -> None:
        if save is None and not spawn and connect is None:
            raise ValueError("RerunSink needs at least one of save, spawn or connect")
        self.path = check_output(save, force) if save is not None else None
        self.part = part_path(self.path) if self.path is not None else None  # where the file grows until closed
        self.spawn = spawn
        self.compact_above_mb = compact_above_mb
        self._sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self.path is not None and self.part is not None:
            self._check_part()
            self._sinks.append(rr.FileSink(self.part))
        self.viewer_url = connect or f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"
        if connect is not None:
            try:
                self._sinks.append(rr.GrpcSink(connect))
            except (ValueError, RuntimeError) as exc:
                raise OutputError(f"not a Rerun gRPC URL ({exc})", connect) from None
            if not listening(connect):
                raise OutputError("no Rerun viewer is listening there (start one with `rerun`)", connect)
        # Larger, rarer chunks than the default (200 ms, 2 MiB): the file's footer keeps ~0.4 kB per chunk in
        # memory until the end, so fewer chunks keep a long mission's memory flat; live viewers lag <= 1 s.
        self._batcher = rr.ChunkBatcherConfig(flush_tick=BATCH_SECONDS, flush_num_bytes=BATCH_BYTES)
        self._application_id = application_id
        self.rec = self._new_stream("")
        self.started = False
        self.closed = False

    def _new_stream(self, log_id: str) -> rr.RecordingStream:
        rec = rr.RecordingStream(
            self._application_id, recording_id=recording_id_for(log_id), batcher_config=self._batcher
        )
        rr.set_log_time_enabled(False, recording=rec)  # wall-clock time of logging says nothing here
        return rec

    def name_after(self, log_id: str) -> None:
        """Before `start`: a recording id that carries the log's fingerprint."""
        if not self.started and log_id:
            self.rec = self._new_stream(log_id)

    def start(self, blueprint: rrb.Blueprint) -> None:
        """Make the file, spawn the viewer if asked (the one already there is reused) and connect them."""
        self.started = True
        self._check_part()  # something may have been put there since the checks
        if self.part is not None and (self.part.is_symlink() or self.part.exists()):
            self.part.unlink()  # a killed run's leftover: a fresh file, never written through a link
        if self.spawn:  # a viewer of this environment on 127.0.0.1
            from aftershock.sinks.rerun_viewer import start_viewer

            self._sinks.append(rr.GrpcSink(start_viewer(port=SPAWN_PORT).grpc_url))
        self.rec.set_sinks(*self._sinks, default_blueprint=blueprint)

    def close(self) -> None:
        """Flush and disconnect, then put the finished file in place (a large one compacted first when the disk
        has room for it). OutputError when the file could not be finished (it stays `NAME.part`, NAME as it
        was) or the viewer not reached (the file is still put in place)."""
        self.closed = True
        try:
            self._flush()
        except RuntimeError as exc:  # a viewer that went away or never came: the file is still finished
            self.rec.disconnect()
            self._put_in_place()
            raise OutputError(f"the Rerun viewer could not be reached ({exc})", self.viewer_url) from None
        self.rec.disconnect()
        self._put_in_place()

    def _put_in_place(self) -> None:
        """The finished `NAME.part`, compacted when large and the disk has room, renamed over NAME; OutputError
        when it was cut (no footer: it stays `NAME.part`)."""
        if self.path is None or self.part is None or not self.part.is_file():
            return  # never started: nothing was made
        if not has_rrd_footer(self.part):  # the footer's write failed (the disk filled as it closed)
            raise self._write_failed(self._why())
        size = self.part.stat().st_size
        free = self.free_bytes()
        if size > self.compact_above_mb * 1e6 and (free is None or free > size + MIN_FREE_BYTES):
            compact(self.part)
        try:
            commit(self.part, self.path)
        except OSError as exc:
            raise OutputError(f"cannot put the recording in place: {exc.strerror or exc}", self.path) from None

    def _check_part(self) -> None:
        what = not_regular(self.part) if self.part is not None else None
        if what is not None and self.part is not None:
            raise OutputError(f"{self.part.name} beside it is {what}; remove it", self.path)

    # ------------------------------------------------------------------------------------------ errors

    def free_bytes(self) -> int | None:
        if self.path is None:
            return None
        try:
            st = os.statvfs(self.path.parent)
        except OSError:
            return None
        return st.f_bavail * st.f_frsize

    def room_error(self) -> OutputError | None:
        """The error to stop on when the disk lacks the room a recording keeps (see MIN_FREE_BYTES), else None.
        Whoever asks closes the recording before raising it (when its file exists), so it stays readable."""
        free = self.free_bytes()
        if free is None or free >= MIN_FREE_BYTES or self.closed:
            return None
        what = "the recording was stopped here and stays readable" if self.file_made else "nothing was written"
        return OutputError(
            f"the disk is nearly full ({free / 2**20:.1f} MiB free, a recording needs {MIN_FREE_BYTES // 2**20} MiB "
            f"of room); {what}",
            self.path,
        )

    @property
    def file_made(self) -> bool:
        """Whether this run's file exists yet (it is made when the sinks are set; an older NAME does not count)."""
        return self.started and self.part is not None and self.part.exists()

    def _flush(self) -> None:
        """Flush, giving up with OutputError when the file writer died (it says so, or the file stops growing for
        FLUSH_STALL_S); RuntimeError from a viewer that cannot be reached."""
        if self.part is None:
            self.rec.flush()
            return
        last_size, last_change = -1, time.monotonic()
        while True:
            try:
                self.rec.flush(timeout_sec=FLUSH_POLL_S)
                return
            except RuntimeError as exc:
                if "file" in str(exc).lower():  # "File-writer thread shut down prematurely"
                    error = self._write_failed(f"{self._why()} ({exc})")
                    self.rec.disconnect()  # returns at once here; Rerun says its piece now, before our line
                    raise error from None
                if "timed out" not in str(exc):
                    raise
            size = self.part.stat().st_size if self.part.exists() else 0
            now = time.monotonic()
            if size != last_size:
                last_size, last_change = size, now
            elif now - last_change > FLUSH_STALL_S and (self._why() != _WRITE_FAILED or not self._viewers):
                # The file stopped growing: its writer is dead. (With a viewer attached, a flush may just be
                # waiting for a slow viewer while the file is complete; only a full disk then says otherwise.)
                raise self._write_failed(self._why(), process_stuck=True)

    @property
    def _viewers(self) -> bool:
        return any(isinstance(s, rr.GrpcSink) for s in self._sinks)

    def _why(self) -> str:
        free = self.free_bytes()
        return "the disk is full" if free is not None and free < MIN_FREE_BYTES else _WRITE_FAILED

    def _write_failed(self, why: str, process_stuck: bool = False) -> OutputError:
        """The error of a writer that failed: its cut file stays `NAME.part` (never under NAME, which stays as it
        was), for Rerun reads it up to the cut."""
        part = self.part
        size = part.stat().st_size if part is not None and part.exists() else 0
        where = f"left as {part.name}" if part is not None else "left"
        return OutputError(
            f"{why}; the recording stopped at {size} bytes, {where}, which Rerun reads up to there",
            self.path,
            process_stuck,
        )


def has_rrd_footer(path: Path) -> bool:
    """Whether the .rrd file at `path` ends with Rerun's footer (it was closed complete)."""
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            if f.tell() < RRD_FOOTER_TAIL:
                return False
            f.seek(-RRD_FOOTER_TAIL, os.SEEK_END)
            return f.read(len(RRD_FOOTER_MAGIC)) == RRD_FOOTER_MAGIC
    except OSError:
        return False
