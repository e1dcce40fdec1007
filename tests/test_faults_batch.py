"""A batch output folder edited by hand is read as untrusted: a `mission.json` that is `[]`, a string where a
number belongs, or a manifest that is no table makes the mission be redone or one line, never a traceback; and
the memory bound of a worker is the OS's (RLIMIT_AS) with the kernel's own peak."""

from __future__ import annotations

import json
import resource
from pathlib import Path

import pytest

from aftershock.pipeline.batch.folder import MANIFEST_FILE, MARKER_FILE, completed_row, prepare_output, taken_names
from aftershock.pipeline.batch.worker import MemoryBound
from aftershock.pipeline.errors import OutputError

GOOD = {"config_hash": "abc", "row": {"mission": "m", "source": "sim://hall", "status": "ok", "scans": 4}}


@pytest.mark.parametrize(
    "marker",
    [
        "[]",
        '"x"',
        "3",
        '{"row": []}',
        '{"config_hash": "abc", "row": {"source": 5, "status": "ok"}}',
        '{"config_hash": "abc", "row": {"source": "sim://hall", "status": "ok", "scans": "four"}}',
        '{"config_hash": "abc", "row": {"source": "sim://hall", "status": "ok", "recording": 7}}',
        "[" * 100_000,
    ],
    ids=["list", "string", "number", "row a list", "source a number", "scans a string", "path a number", "deep"],
)
def test_a_hand_edited_mission_json_is_redone_not_trusted(marker: str, tmp_path: Path) -> None:
    folder = tmp_path / "out" / "m"
    folder.mkdir(parents=True)
    (folder / MARKER_FILE).write_text(marker)
    assert completed_row(folder, "sim://hall", "abc") is None
    assert taken_names(tmp_path / "out") in ({}, {"m": "sim://hall"})  # the folder's name stays taken if it can
    (folder / MARKER_FILE).write_text(json.dumps(GOOD))
    assert completed_row(folder, "sim://hall", "abc") == GOOD["row"]


@pytest.mark.parametrize("manifest", ["[]", '{"config_hash": "other", "settings": "x"}'])
def test_a_hand_edited_manifest_is_one_line(manifest: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST_FILE).write_text(manifest)
    with pytest.raises(OutputError) as caught:
        prepare_output(out, "abc", {"map": {}}, force=False)
    assert "\n" not in str(caught.value) and str(out) in str(caught.value)


def test_the_worker_bound_is_the_address_space_and_comes_back_after() -> None:
    before = resource.getrlimit(resource.RLIMIT_AS)
    with MemoryBound(256 << 20) as bound:
        bound.arm()
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        assert soft != resource.RLIM_INFINITY
        with pytest.raises(MemoryError):
            bytearray(512 << 20)
        kept = bytearray(64 << 20)
        kept[::4096] = b"\x01" * len(kept[::4096])  # touched: resident
        peak = MemoryBound.peak_bytes()
        assert peak is not None and peak >= 64 << 20
    assert resource.getrlimit(resource.RLIMIT_AS) == before
