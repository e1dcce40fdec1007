"""Outputs are regular files this command creates: checked before any work, written beside and renamed, locked.

- An output path that exists and is not a regular file (a device such as /dev/null, a named pipe, a socket, a
  folder where a file is meant) is refused, `--force` or not: writing there would replace a system file, hang on
  a pipe, or write nowhere.
- An output that is one of the inputs (through links too) or another output of the same command is refused.
- Where a file is made is tried at once (a probe file in its folder): /proc, a read-only mount or a folder without
  permission is one line before any work, not a "disk full" after it.
- Every output is written under `NAME.part` beside it and renamed over NAME when complete, so a failed or
  interrupted command leaves the old file as it was; a stream killed by SIGKILL leaves its `.part`, readable up to
  the kill.
- An export folder is locked while a command writes it (`.aftershock.lock` holding the PID, an flock held on it):
  a second command is refused naming the holder; a lock left by a process that died is taken over.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import IO, Any, Final

from aftershock.pipeline.errors import OutputError

PART_SUFFIX: Final = ".part"
LOCK_FILE: Final = ".aftershock.lock"
NAME_MAX: Final = 255  # bytes in one path component (Linux, macOS)


def part_path(path: Path, hidden: bool = False) -> Path:
    """Where `path` is written until it is complete: `NAME.part` for a stream (a SIGKILL leaves it, readable up to
    the kill, where the user sees it), `.NAME.part` for a file written in one go (it never holds anything)."""
    return path.with_name(("." if hidden else "") + path.name + PART_SUFFIX)


def not_regular(path: Path) -> str | None:
    """What `path` is when it exists and is not a regular file ("a device", "a folder" ...), else None."""
    try:
        mode = os.stat(path).st_mode  # follows links: a link to /dev/null is a device
    except FileNotFoundError:
        return "a link to nowhere" if os.path.islink(path) else None
    except OSError:
        return None  # the probe in `check_output` names the problem
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def check_name(path: Path, what: type[Exception] = OutputError) -> None:
    """A path whose components the file system cannot hold (over 255 bytes) is one line naming it."""
    for part in path.parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise what(f"a name in this path is {len(os.fsencode(part))} bytes, over the {NAME_MAX} allowed", path)


def same_file(a: Path, b: Path) -> bool:
    """Whether `a` and `b` are one file (or `a` lies in folder `b`), through links, existing or not."""
    try:
        if a.exists() and b.exists() and os.path.samefile(a, b):
            return True
    except OSError:
        pass
    ra, rb = os.path.realpath(a), os.path.realpath(b)
    return ra == rb or (os.path.isdir(rb) and ra.startswith(rb.rstrip(os.sep) + os.sep) and os.path.exists(ra))


def check_output(
    path: str | Path, force: bool = False, inputs: Iterable[str | Path] = (), others: Iterable[str | Path] = ()
) -> Path:
    """The output path, checked before any work (see the module docstring); makes its parent folder."""
    p = Path(path)
    check_name(p)
    what = not_regular(p)
    if what is not None:
        raise OutputError(f"is {what}, not a regular file; outputs are only files this command creates", p)
    for src in inputs:
        if same_file(p, Path(src)):
            raise OutputError(f"is the input {src}; choose another output", p)
    for other in others:
        if same_file(p, Path(other)):
            raise OutputError(f"is also given as another output ({other}); give each output its own file", p)
    if p.exists() and not force:
        raise OutputError("already exists (pass --force to overwrite)", p)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror}", p.parent) from None
    _probe(p)
    return p


def check_distinct(outputs: Mapping[str, str | Path | None]) -> None:
    """Refuse two options naming one file (`--save P --mcap-out P`), through links."""
    given = [(option, Path(p)) for option, p in outputs.items() if p is not None]
    for i, (option, a) in enumerate(given):
        for other, b in given[i + 1 :]:
            if same_file(a, b) or same_file(b, a):
                raise OutputError(f"is given to both {option} and {other}; give each output its own file", a)


def _probe(path: Path) -> None:
    """Make and remove a file beside `path`: the folder takes files (not /proc, not read-only, permitted)."""
    probe = path.with_name(f".{path.name[: NAME_MAX - 32]}.{os.getpid()}.probe")
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return
    except OSError as exc:
        raise OutputError(f"no file can be made in this folder ({exc.strerror or exc})", path.parent) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def commit(part: Path, path: Path) -> None:
    """Rename a finished `part` over `path`, unless `path` became something else than a regular file meanwhile."""
    what = not_regular(path)
    if what is not None:
        part.unlink(missing_ok=True)
        raise OutputError(f"became {what} while it was written; nothing was put there", path)
    os.replace(part, path)


def write_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """`write(tmp)` into `NAME.part` beside `path`, then rename it over `path`: a full disk or an interruption
    leaves the old file (if any) as it was, never half a file. OutputError names `path`."""
    tmp = part_path(path, hidden=True)
    try:
        if not_regular(tmp) is not None:
            raise OutputError(f"{tmp.name} beside it is not a regular file; remove it", path)
        write(tmp)
        commit(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write: {exc.strerror or exc}", path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class StreamedOutput:
    """A file written for the whole run (poses, an MCAP, a recording): opened as `NAME.part`, renamed over NAME
    by `close` (also after Ctrl-C); `discard` removes it."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.part = part_path(self.path)
        self.file: IO[Any] | None = None

    def open(self, mode: str = "wb") -> IO[Any]:
        what = not_regular(self.part)
        if what is not None:
            raise OutputError(f"{self.part.name} beside it is {what}; remove it", self.path)
        self.file = open(self.part, mode)  # noqa: SIM115 (kept open for the whole run)
        return self.file

    def close(self) -> None:
        """Close and put the file in place; OSError from the close itself is left to the caller's handling."""
        f, self.file = self.file, None
        if f is None:
            return
        try:
            f.close()
        finally:
            if self.part.exists():
                commit(self.part, self.path)

    def discard(self) -> None:
        f, self.file = self.file, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.close()
        self.part.unlink(missing_ok=True)


class FolderLock:
    """An export folder held by one command: `.aftershock.lock` with the holder's PID, flock-ed while held (the
    kernel drops the flock when the holder dies, so a stale lock is simply taken over)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> FolderLock:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise OutputError(f"cannot lock the folder ({exc.strerror or exc})", self.folder) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                raise OutputError(
                    f"is being written by another aftershock command (PID {holder}, lock {LOCK_FILE}); "
                    "wait for it or choose another folder",
                    self.folder,
                ) from None
            raise OutputError(f"cannot lock the folder ({exc.strerror or exc})", self.folder) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        os.close(fd)

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
