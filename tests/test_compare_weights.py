"""`make train`'s last step: rebuilt weights against the shipped files."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from aftershock.models.compare_weights import main
from aftershock.models.weights_file import WEIGHTS_DIR


def test_shipped_files_equal_themselves_and_a_changed_tensor_shows(tmp_path: Path, capsys) -> None:
    for name in ("lrgnet.pt", "crackembed.pt"):
        shutil.copy(WEIGHTS_DIR / name, tmp_path / name)
    blob = torch.load(tmp_path / "lrgnet.pt", weights_only=True)
    first = next(iter(blob["state_dict"]))
    blob["state_dict"][first] = blob["state_dict"][first] + 0.5
    torch.save(blob, tmp_path / "lrgnet.pt")
    assert main([str(WEIGHTS_DIR), str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("crackembed.pt: same, tensor for tensor")
    assert lines[1].startswith("lrgnet.pt: differs: 1 of ") and "largest difference 0.5" in lines[1]


def test_nothing_to_compare_is_a_usage_error(tmp_path: Path, capsys) -> None:
    assert main([str(WEIGHTS_DIR), str(tmp_path)]) == 2
    assert "no weights files" in capsys.readouterr().err


def test_an_unreadable_file_is_one_line_and_the_others_are_still_compared(tmp_path: Path, capsys) -> None:
    shutil.copy(WEIGHTS_DIR / "crackembed.pt", tmp_path / "crackembed.pt")
    (tmp_path / "lrgnet.pt").write_bytes(b"not a weights file")
    assert main([str(WEIGHTS_DIR), str(tmp_path)]) == 2
    out, err = capsys.readouterr()
    assert out.startswith("crackembed.pt: same, tensor for tensor")
    assert err.count("\n") == 1 and err.startswith("lrgnet.pt:") and "lrgnet.pt" in err[len("lrgnet.pt:") :]
