"""Logs and files that lie about themselves: indexes pointing nowhere, log times past 2**63, empty clouds, bag
metadata that cannot be read or parsed, PLY and PCD headers whose counts do not match their bodies. Each is read
as far as it is true, with one warning, or refused in one line; never a traceback.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from cli_errors import RG, cli, one_error_line
from faults_data import write_log
from faults_hostile import ENV, log_with_late_times, repoint_chunk_index
from fixtures import write_bag


@pytest.fixture(scope="module")
def log12(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_log(tmp_path_factory.mktemp("logs") / "log.mcap", 12, chunk_size=150_000)


@pytest.mark.parametrize("to", [0, 1000], ids=["offset 0", "into the file"])
def test_a_chunk_index_pointing_where_no_chunk_is_reads_every_intact_chunk(
    to: int, log12: Path, tmp_path: Path, capsys
) -> None:
    log = repoint_chunk_index(log12, tmp_path / "index.mcap", 1, to)
    code, out, err = cli(["info", str(log), "-q", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["point_clouds"][0]["scans"] == 12
    assert "the chunk index points at byte" in err and "reading the file record by record" in err


def test_log_times_past_2_63_are_skipped_where_they_enter_and_the_outputs_kept(tmp_path: Path, capsys) -> None:
    log = log_with_late_times(tmp_path / "late.mcap", 10, late=(4,))
    code, out, err = cli(["info", str(log), "-q", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["point_clouds"][0]["scans"] == 9 and "past 2**63 ns" in err
    exp, mcap = tmp_path / "exp", tmp_path / "out.mcap"
    code, out, err = cli(["run", str(log), *RG, "-q", "--json", "--export", str(exp), "--mcap-out", str(mcap)], capsys)
    assert code == 0, err
    assert json.loads(out)["scans"] == 9 and "past 2**63 ns" in err
    assert json.loads((exp / "summary.json").read_text())["scans"] == 9
    code, out, err = cli(["info", str(mcap), "-q", "--json"], capsys)
    assert code == 0 and "DAMAGED" not in out, err


def test_info_on_a_log_with_an_empty_pointcloud2_counts_it(tmp_path: Path, capsys) -> None:
    def empty(m: dict) -> dict:
        return {**m, "data": b"", "width": 0, "row_step": 0}

    log = write_log(tmp_path / "empty.mcap", 4, bad_clouds={1: empty}, points=500)
    code, out, err = cli(["info", str(log), "-q", "--json"], capsys)
    assert code == 0, err
    cloud = json.loads(out)["point_clouds"][0]
    assert cloud["scans"] == 4 and cloud["points_min"] == 0 and cloud["points_max"] == 500


@pytest.fixture(scope="module")
def ros2_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rng = np.random.default_rng(0)
    clouds = [{a: rng.uniform(1, 5, 200).astype(np.float32) for a in "xyz"} for _ in range(3)]
    return write_bag(tmp_path_factory.mktemp("bag") / "bag", clouds, ros2=True)


@pytest.mark.parametrize(
    "text",
    ["rosbag2_bagfile_information: [1, 2\n  - {{{\n", "3", "rosbag2_bagfile_information: {version: x}", "\xff\x00"],
    ids=["broken YAML", "a number", "wrong types", "binary"],
)
def test_garbage_bag_metadata_is_one_line(text: str, ros2_bag: Path, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(ros2_bag, bag)
    (bag / "metadata.yaml").write_bytes(text.encode("utf-8", "surrogateescape"))
    for cmd in (["info", str(bag)], ["run", str(bag), *RG, "-q"]):
        code, _, err = cli(cmd, capsys)
        assert code == 2, err
        one_error_line(err, bag, "cannot open the ROS bag")


@pytest.mark.skipif(os.geteuid() != 0, reason="drops to another user to be refused a file (needs root)")
@pytest.mark.parametrize("locked", ["metadata.yaml", "the folder above"])
def test_unreadable_bag_metadata_or_folder_is_one_line(locked: str, ros2_bag: Path) -> None:
    top = Path(tempfile.mkdtemp(prefix="aftershock-locked-"))  # pytest's own folders are closed to others
    bag = top / "bag"
    shutil.copytree(ros2_bag, bag)
    if locked == "metadata.yaml":
        (bag / "metadata.yaml").chmod(0)
        top.chmod(0o755)
    else:
        top.chmod(0o700)
    if shutil.which("setpriv") is None:
        pytest.skip("needs setpriv (util-linux) to run as another user")
    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
    reach = subprocess.run([*nobody, sys.executable, "-c", "import aftershock.pipeline"], capture_output=True, env=ENV)
    if reach.returncode != 0:  # e.g. a checkout inside `mktemp -d` (mode 700): the other user cannot run us at all
        shutil.rmtree(top)
        pytest.skip("another user cannot import aftershock from this checkout (a folder above it is closed)")
    cmd = [*nobody, sys.executable, "-m", "aftershock.pipeline", "info", str(bag), "-q"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=60)
    finally:
        shutil.rmtree(top)
    assert done.returncode == 2, done.stderr
    one_error_line(done.stderr, bag, "ermission denied")


def test_a_ply_declaring_10_vertices_over_500_rows_says_so(tmp_path: Path, capsys) -> None:
    ply = tmp_path / "short.ply"
    rows = "\n".join(f"{x:.3f} {2 * x:.3f} {1 + x:.3f}" for x in np.linspace(1, 5, 500))
    header = "ply\nformat ascii 1.0\nelement vertex 10\nproperty float x\nproperty float y\nproperty float z\n"
    ply.write_text(header + "end_header\n" + rows + "\n")
    code, out, err = cli(["info", str(ply), "-q", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["point_clouds"][0]["points_max"] == 10
    assert "declares 10 rows but the file holds 500" in err


@pytest.mark.parametrize(("points", "named"), [(9 * 10**12, "holds 3 rows"), (2, "holds 3 rows; read 2")])
def test_an_ascii_pcd_whose_point_count_does_not_match_its_rows(points: int, named: str, tmp_path: Path, capsys):
    pcd = tmp_path / "liar.pcd"
    header = f"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\n"
    pcd.write_text(header + f"POINTS {points}\nDATA ascii\n1 2 3\n2 3 4\n3 4 5\n")
    code, out, err = cli(["info", str(pcd), "-q", "--json"], capsys)
    if points > 3:
        assert code == 2
        one_error_line(err, pcd, f"declares {points} points", named)
    else:
        assert code == 0 and named in err, err
        assert json.loads(out)["point_clouds"][0]["points_max"] == 2


def test_a_real_folder_named_like_a_glob_is_that_folder(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "run[1]"
    folder.mkdir()
    rng = np.random.default_rng(1)
    for k in range(2):
        pts = rng.uniform(1, 5, (300, 4)).astype("<f4")
        (folder / f"{k:06d}.bin").write_bytes(pts.tobytes())
    (tmp_path / "run1").mkdir()  # what the pattern `run[1]` would match instead
    code, out, err = cli(["info", str(folder), "-q", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["point_clouds"][0]["scans"] == 2


@pytest.mark.parametrize("poison", ["nan", "a string state"])
def test_weights_full_of_nan_or_of_the_wrong_type_are_one_line(poison: str, log12: Path, tmp_path: Path, capsys):
    import torch

    from aftershock.models.mcpnet import default_weights

    blob = torch.load(default_weights(), map_location="cpu", weights_only=True)
    if poison == "nan":
        blob["state"] = {
            k: torch.full_like(v, float("nan")) if v.is_floating_point() else v for k, v in blob["state"].items()
        }
    else:
        blob["state"] = "weights"
    bad = tmp_path / "bad.pt"
    torch.save(blob, bad)
    code, _, err = cli(["run", str(log12), "-q", "--max-scans", "2", "--set", f"label.weights={bad}"], capsys)
    assert code == 2
    one_error_line(err, bad, "NaN" if poison == "nan" else "not a table of tensors")
