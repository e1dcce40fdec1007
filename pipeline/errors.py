"""Errors a user can cause and fix: the CLI prints them as one line and exits non-zero, without a traceback."""

from __future__ import annotations

from pathlib import Path

from aftershock.pipeline.text import safe


class AftershockError(Exception):
    """A problem with the user's input or environment, explained in one line: names taken from files and paths
    (a topic holding a newline or an ANSI escape) are printed with their control characters escaped."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = str(path) if path is not None else None
        super().__init__(safe(f"{path}: {message}" if path is not None else message))


class InputError(AftershockError):
    """The input (log, file, folder, weights) cannot be read as asked."""


class OutputError(AftershockError):
    """An output cannot be written (exists without --force, not writable, the disk is full).

    `process_stuck`: a library thread writing it is wedged for good (Rerun's file writer after a full disk), so
    the process cannot end normally; the command line ends it at once after printing the error."""

    def __init__(self, message: str, path: str | Path | None = None, process_stuck: bool = False) -> None:
        super().__init__(message, path)
        self.process_stuck = process_stuck


class DamagedLogWarning(UserWarning):
    """A log was read up to a damaged part; what came before is valid."""
