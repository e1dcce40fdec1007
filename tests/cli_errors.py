"""The command line run in-process, and what its one-line errors must look like; shared by the fault and
config tests."""

from __future__ import annotations

from typing import Final

import pytest

from aftershock.pipeline.cli import main

RG: Final[tuple[str, ...]] = ("--labeller", "region-growing")  # the network-free labeller: fast and deterministic
PREFIX: Final = "aftershock: error:"


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """`aftershock ARGS` in this process: exit code, stdout, stderr."""
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str, *names: object, alone: bool = False, escapes: bool = False) -> str:
    """stderr has no traceback and exactly one `aftershock: error:` line, its last, naming each of `names`; with
    `alone` that line is all of stderr; unless `escapes`, no terminal escape reached it. Returns the line."""
    assert "Traceback" not in err, err
    assert escapes or "\x1b" not in err, err
    lines = err.strip().splitlines()
    errors = [ln for ln in lines if ln.startswith(PREFIX)]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    assert not alone or len(lines) == 1, err
    for name in names:
        assert str(name) in errors[0], (name, errors[0])
    return errors[0]
