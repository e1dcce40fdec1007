"""No traceback from settings, whatever their size: one line naming the setting or file, exit 2, before any work.

Parsers' own limits (recursion depth, Python's 4300-digit integer limit) and values whose memory would exceed the
machine (a simulated mission of 10**15 s, a billion context points) are refused where they enter.
"""

from __future__ import annotations

from pathlib import Path

import cli_errors
import pytest
from cli_errors import RG, cli
from faults_data import write_log

DEEP = 100_000


def one_error_line(err: str, *names: object) -> str:
    """The error is all of stderr."""
    return cli_errors.one_error_line(err, *names, alone=True, escapes=True)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_log(tmp_path_factory.mktemp("set") / "log.mcap", 4, points=1000)


CONFIGS = {
    "deep.json": ('{"map": ' * DEEP + "1" + "}" * DEEP, "nests deeper"),
    "deep.toml": ("a = " + "[" * DEEP + "]" * DEEP + "\n", "nests deeper"),
    "digits.toml": ("[map]\ncontext_points = " + "9" * 5000 + "\n", "more than 4300 digits"),
    "digits.json": ('{"map": {"context_points": ' + "9" * 5000 + "}}", "more than 4300 digits"),
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_a_config_past_what_a_parser_holds_is_one_line(name: str, log: Path, tmp_path: Path, capsys) -> None:
    text, named = CONFIGS[name]
    path = tmp_path / name
    path.write_text(text)
    code, _, err = cli(["run", str(log), *RG, "-q", "--config", str(path)], capsys)
    assert code == 2
    one_error_line(err, path, named)


@pytest.mark.parametrize(
    ("value", "named"),
    [("9" * 5000, "more than 4300 digits"), ("[" * DEEP, "nests deeper"), ("1e-9", "greater than or equal to 0.001")],
)
def test_a_set_value_past_what_a_parser_holds_is_one_line(value: str, named: str, log: Path, capsys) -> None:
    code, _, err = cli(["run", str(log), *RG, "-q", "--set", f"map.voxel_size_m={value}"], capsys)
    assert code == 2
    one_error_line(err, "map.voxel_size_m", named)


@pytest.mark.parametrize("where", ["a folder", "/dev/stdin"])
def test_config_on_something_that_is_no_file_says_what_it_is(where: str, log: Path, tmp_path: Path, capsys) -> None:
    path = tmp_path if where == "a folder" else Path(where)
    code, _, err = cli(["run", str(log), *RG, "-q", "--config", str(path)], capsys)
    assert code == 2
    line = one_error_line(err, path)
    assert "not found" not in line and ("is a folder" in line or "not a regular file" in line)


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["run", "{log}", "--start", "1e300"], "--start"),
        (["run", "{log}", "--set", "map.context_points=1000000000"], "map.context_points"),
        (["run", "sim://hall?seed=-1", "--max-scans", "2"], "seed must be between 0 and"),
        (["simulate", "--seed", "-1", "--out", "{tmp}/s.mcap"], "seed must be between 0 and"),
        (["run", "sim://disaster?duration=1e15", "--max-scans", "2"], "duration"),
        (["run", "sim://disaster", "--end", "9e8", "--max-scans", "2"], "--end"),
    ],
    ids=["--start 1e300", "context points 1e9", "sim seed -1", "simulate --seed -1", "duration 1e15", "--end 9e8"],
)
def test_values_that_cannot_be_or_would_exceed_memory_are_refused_naming_the_setting(
    args: list[str], named: str, log: Path, tmp_path: Path, capsys
) -> None:
    args = [a.format(log=log, tmp=tmp_path) for a in args]
    code, _, err = cli([*args, *RG, "-q"] if args[0] == "run" else args, capsys)
    assert code == 2
    one_error_line(err, named)
    assert not (tmp_path / "s.mcap").exists()


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["train", "mcpnet", "--epochs", "-1", "--out", "{tmp}/w.pt"], "--epochs -1"),
        (["train", "lrgnet", "--seed", "-1", "--out", "{tmp}/w.pt"], "--seed -1"),
        (["batch", "sim://hall?scans=2", "--out", "{tmp}/b", "--worker-memory", "inf"], "--worker-memory inf"),
    ],
    ids=["train --epochs -1", "train --seed -1", "batch --worker-memory inf"],
)
def test_command_options_out_of_range_are_one_line_before_any_work(
    args: list[str], named: str, tmp_path: Path, capsys
) -> None:
    code, _, err = cli([a.format(tmp=tmp_path) for a in args], capsys)
    assert code == 2
    one_error_line(err, named)
    assert not (tmp_path / "w.pt").exists() and not (tmp_path / "b").exists()
