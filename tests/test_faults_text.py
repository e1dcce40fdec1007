"""Hostile text never reaches the terminal raw: names taken from files (topics, frame ids, paths) are printed with
their control characters escaped, so a newline cannot split a one-line error and an ANSI escape cannot recolour
the user's terminal; every error is exactly one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from aftershock.pipeline.cli import main
from aftershock.pipeline.pointcloud2 import POINTCLOUD2_MSGDEF, encode_pointcloud2, serialize_pointcloud2
from aftershock.pipeline.text import safe

HOSTILE = "/evil\n\x1b[31mred\x1b[0m\u202etxt.gpj"


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def _clean(text: str) -> None:
    assert "\x1b" not in text and "\u202e" not in text and "Traceback" not in text, text


def test_safe_escapes_controls_and_keeps_printable_text() -> None:
    assert safe("a\nb\tc\x1b[31m\x00\x7f\u2028") == "a\\nb\\tc\\x1b[31m\\x00\\x7f\\u2028"
    assert safe("Straße 日本 /ouster/points") == "Straße 日本 /ouster/points"
    assert "\n" not in safe(HOSTILE) and "\x1b" not in safe(HOSTILE)


def _log_with_topic(path: Path, topic: str) -> Path:
    rng = np.random.default_rng(0)
    cols = {a: rng.uniform(1, 5, 500).astype(np.float32) for a in "xyz"}
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="aftershock-tests")
        schema = w.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", POINTCLOUD2_MSGDEF.encode())
        for name in (topic, "/second"):
            channel = w.register_channel(name, "cdr", schema)
            for k in range(2):
                t = 1_700_000_000_000_000_000 + k * 100_000_000
                msg = encode_pointcloud2(cols, stamp_ns=t, frame_id=HOSTILE)
                w.add_message(channel, log_time=t, data=serialize_pointcloud2(msg), publish_time=t)
        w.finish()
    return path


def test_a_topic_with_a_newline_and_ansi_escapes_is_printed_escaped(tmp_path: Path, capsys) -> None:
    log = _log_with_topic(tmp_path / "log.mcap", HOSTILE)
    code, out, err = cli(["info", str(log), "-q"], capsys)
    assert code == 0, err
    _clean(out)
    assert safe(HOSTILE) in out
    code, out, _ = cli(["info", str(log), "-q", "--json"], capsys)  # JSON escapes by itself, and keeps the name
    assert code == 0 and HOSTILE in {t["name"] for t in json.loads(out)["topics"]}
    code, _, err = cli(["run", str(log), "--labeller", "region-growing", "-q"], capsys)  # two topics: choose one
    assert code == 2
    _clean(err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aftershock: error:") and safe(HOSTILE) in lines[0]


def test_a_file_name_with_control_characters_is_one_escaped_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "scan\n\x1b[2Jgone.pcd"
    bad.write_text("not a pcd")
    code, _, err = cli(["info", str(bad)], capsys)
    assert code == 2
    _clean(err)
    assert len(err.strip().splitlines()) == 1 and "scan\\n\\x1b[2Jgone.pcd" in err
