"""`aftershock report DIR`: the site assessment report over real pipeline outputs -- `run --export --damage` on
the bundled sample recording (one slab: drift not measured, with the reason), on a simulated frame with
storeys and known drift (`simulator.frames`, a seed no setting was chosen on), and a `batch` with a mission
that fails; report.json's promised keys; the HTML opened in headless Chromium; bad input in one line."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.config import ReportConfig
from aftershock.pipeline.mission import SAMPLE
from aftershock.pipeline.types import LabelledCloud

CLI = [sys.executable, "-m", "aftershock.pipeline"]
ENV = os.environ | {"CI": "true", "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
FAST = ["--labeller", "region-growing"]  # the report reads what any labeller wrote
STATUSES = {"found", "none", "not_assessable"}
ITEMS = [
    "collapse or partial collapse",
    "building or storey leaning",
    "columns",
    "walls",
    "floors and slabs",
    "debris blocking exits",
]
STOREY_KEYS = {"drift_mm", "drift_ratio", "tilt_deg", "tilt_uncertainty_deg", "uncertainty_mm", "reason"}


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sample recording through `run --export --damage --save` (one floor slab in view)."""
    out = tmp_path_factory.mktemp("export") / "sample"
    cmd = [*CLI, "run", str(SAMPLE), "--export", str(out), "--damage", "--save", str(out / "recording.rrd"), "-q"]
    subprocess.run([*cmd, *FAST], check=True, capture_output=True, env=ENV, timeout=300)
    return out


def _check_promise(data: dict) -> None:
    """The keys report.json promises other tools."""
    assert data["missions"]
    for m in data["missions"]:
        assert {"name", "status", "storeys", "checklist", "posting"} <= set(m)
        if m["status"] == "failed":
            assert m["error"]
            continue
        for s in m["storeys"]:
            assert set(s) >= STOREY_KEYS
            for key in ("drift_mm", "drift_ratio", "tilt_deg", "tilt_uncertainty_deg", "uncertainty_mm"):
                if s[key] is None:
                    assert s["reason"], (key, s)
        assert [i["item"] for i in m["checklist"]] == ITEMS
        for i in m["checklist"]:
            assert i["status"] in STATUSES and i["evidence"]
            for w in i["where"]:
                assert w["entity"].startswith("world/") and w["timeline"] == "scan" and w["position"] >= 0
        p = m["posting"]
        assert p["suggested"] in {"inspected", "restricted use", "unsafe"} and p["rule"] and p["advisory"] is True


def _chromium_ok(html: Path, shot: Path | None = None, pdf: Path | None = None) -> str:
    """Opens the report in headless Chromium: no console error, nothing asked of the network, every image
    loaded. Returns the page's text."""
    pytest.importorskip("playwright")
    from report_browser import CHROMIUM, render

    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} is not installed")
    page = render(html, shot, pdf)
    assert page.console_errors == []
    assert all(u.startswith(("file:", "data:")) for u in page.requests), page.requests
    assert page.image_widths and all(w > 0 for w in page.image_widths), page.image_widths
    return page.text


def test_one_slab_export_drift_not_measured_with_the_reason(
    export_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site.html"
    code, stdout, err = _run(["report", str(export_dir), "--out", str(out), "--json"], capsys)
    assert code == 0, err
    data = json.loads(stdout)
    assert json.loads((tmp_path / "site.json").read_text()) == data  # the file and stdout: the same report
    _check_promise(data)
    m = data["missions"][0]
    assert m["status"] == "ok" and m["scans"] == 22 and m["path_length_m"] > 1.0
    [storey] = m["storeys"]
    assert storey["drift_mm"] is None and storey["drift_ratio"] is None and storey["tilt_deg"] is None
    assert "one slab found" in storey["reason"]
    items = {i["item"]: i for i in m["checklist"]}
    assert items["building or storey leaning"]["status"] == "not_assessable"
    assert items["columns"]["status"] == "not_assessable"  # the labelled map holds no column
    assert m["posting"]["suggested"] == "restricted use"  # leaning could not be assessed: never "inspected"
    assert m["recording"] == str(export_dir / "recording.rrd")
    assert not m["cracks"]["assessed"] and "too sparse" in m["cracks"]["reason"]
    text = _chromium_ok(out)
    assert "not measured" in text and not re.search(r"(?<![\d.])0\.0 mm", text)
    assert "RESTRICTED USE" in text.upper() and "Advisory" in text


def _frame_export(tmp_path: Path, layout: str, seed: int) -> tuple[Path, np.ndarray]:
    from aftershock.sources.simulator.frames import drift_frame

    frame = drift_frame(layout, seed, 0.1)
    ply = write_cloud(tmp_path / "frame.ply", LabelledCloud(frame.points))
    out = tmp_path / "frame"
    cmd = [*CLI, "run", str(ply), "--export", str(out), "--damage", "-q", *FAST]
    subprocess.run(cmd, check=True, capture_output=True, env=ENV, timeout=300)
    truth = np.array([(lv.drift_x_mm, lv.drift_y_mm) for lv in frame.levels])
    return out, np.diff(truth, axis=0)


def test_a_frame_with_storeys_gets_drift_ratios_flags_and_a_posting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A frame of a seed no report setting was chosen on: every storey's drift within the stated uncertainty
    of the truth, its ratio the drift over the storey height, its flag by the limits, the posting by the rule."""
    folder, steps = _frame_export(tmp_path, "partial-collapse", 12)
    code, stdout, err = _run(["report", str(folder), "--json"], capsys)
    assert code == 0, err
    data = json.loads(stdout)
    _check_promise(data)
    m = data["missions"][0]
    limits = ReportConfig()
    assert len(m["storeys"]) == len(steps)
    worst = "inspected"
    for s, truth in zip(m["storeys"], steps, strict=True):
        assert s["drift_mm"] is not None and s["reason"] is None
        error = np.hypot(s["drift_x_mm"] - truth[0], s["drift_y_mm"] - truth[1])
        print(f"storey {s['index']}: drift {s['drift_mm']:.1f} mm, truth {np.hypot(*truth):.1f}, error {error:.1f}")
        assert error <= s["uncertainty_mm"]
        assert s["drift_ratio"] == pytest.approx(s["drift_mm"] / 1000 / s["height_m"], rel=1e-3)
        assert s["drift_ratio_text"] == f"1/{round(1 / s['drift_ratio'])}"
        assert s["tilt_uncertainty_deg"] > 0  # measured from the slabs' own points
        # evidence of exceeding a limit: value - uncertainty above it
        ratio = s["drift_ratio"] - s["uncertainty_mm"] / 1000 / s["height_m"]
        tilt = s["tilt_deg"] - s["tilt_uncertainty_deg"]
        if ratio > limits.drift_unsafe_ratio or tilt > limits.tilt_unsafe_deg:
            assert s["flag"] == "unsafe"
            worst = "unsafe"
        elif ratio > limits.drift_restricted_ratio or tilt > limits.tilt_restricted_deg:
            assert s["flag"] == "restricted use"
            worst = worst if worst == "unsafe" else "restricted use"
        else:
            assert s["flag"] in {"within limits", "within measurement uncertainty of the limit"}
    leaning = next(i for i in m["checklist"] if i["item"] == "building or storey leaning")
    assert leaning["status"] in {"found", "none"} and "mm" in leaning["evidence"]
    if worst != "inspected":
        assert m["posting"]["suggested"] in {worst, "unsafe"}
    kinds = [(f["kind"], f["storey"]) for f in m["findings"]]
    for s in m["storeys"]:  # every storey over a limit is a numbered finding
        ratio = s["drift_ratio"] - s["uncertainty_mm"] / 1000 / s["height_m"]
        assert (("drift", s["index"]) in kinds) == (ratio > limits.drift_restricted_ratio)
        assert (("tilt", s["index"]) in kinds) == (
            s["tilt_deg"] - s["tilt_uncertainty_deg"] > limits.tilt_restricted_deg
        )
    assert [f["number"] for f in m["findings"]] == list(range(1, len(m["findings"]) + 1))
    _chromium_ok(folder / "report.html")


def test_a_batch_with_a_failed_mission(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A log cut after its header fails in the batch; the report shows it failed, with its error, and the
    other mission in full."""
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(SAMPLE.read_bytes()[:3000])
    out = tmp_path / "site"
    cmd = [*CLI, "batch", str(SAMPLE), str(broken), "--out", str(out), "--damage", "--workers", "1", *FAST]
    done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=300)
    assert done.returncode == 1, done.stderr  # some missions failed
    code, stdout, err = _run(["report", str(out)], capsys)
    assert code == 0, err
    assert "broken: failed:" in stdout and f"report: {out / 'report.html'}" in stdout
    data = json.loads((out / "report.json").read_text())
    _check_promise(data)
    by = {m["name"]: m for m in data["missions"]}
    assert by["broken"]["status"] == "failed" and "point-cloud topic" in by["broken"]["error"]
    assert by["sample"]["status"] == "ok" and by["sample"]["recording"].endswith("recording.rrd")
    import pyarrow.parquet as pq

    rows = {r["mission"]: r for r in pq.read_table(out / "missions.parquet").to_pylist()}
    assert rows["sample"]["worst_drift_mm"] is None  # one slab: not measured, never 0.0 in the site index
    assert data["site"] == data["site"] | {"kind": "batch", "missions": 2, "failed": 1}
    pdf = tmp_path / "site.pdf"
    text = _chromium_ok(out / "report.html", pdf=pdf)  # and printed to PDF, as a field team would
    assert "point-cloud topic" in text
    assert pdf.read_bytes()[:5] == b"%PDF-" and pdf.stat().st_size > 20_000


def test_bad_input_is_one_line_naming_the_file(
    export_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = _run(["report", str(empty)], capsys)
    assert code == 2 and err.count("\n") == 1 and str(empty) in err and "no mission results" in err
    code, _, err = _run(["report", str(tmp_path / "nowhere")], capsys)
    assert code == 2 and "no such folder" in err
    damaged = tmp_path / "damaged"
    shutil.copytree(export_dir, damaged)
    (damaged / "summary.json").write_text('{"scans": 22, ')
    code, _, err = _run(["report", str(damaged)], capsys)
    assert code == 2 and err.count("\n") == 1 and str(damaged / "summary.json") in err
    shutil.copy(export_dir / "summary.json", damaged / "summary.json")
    (damaged / "map.ply").write_bytes((export_dir / "map.ply").read_bytes()[:600])
    code, _, err = _run(["report", str(damaged)], capsys)
    assert code == 2 and err.count("\n") == 1 and str(damaged / "map.ply") in err
    (damaged / "map.ply").write_bytes((export_dir / "map.ply").read_bytes())
    code, _, err = _run(["report", str(damaged)], capsys)
    assert code == 0, err
    before = (damaged / "report.html").read_bytes()
    code, _, err = _run(["report", str(damaged)], capsys)
    assert code == 2 and err.count("\n") == 1 and str(damaged / "report.html") in err
    assert (damaged / "report.html").read_bytes() == before
    code, _, err = _run(["report", str(damaged), "--force"], capsys)
    assert code == 0, err


def _room(ceiling_tilt_deg: float, sag_m: float = 0.0, seed: int = 0) -> np.ndarray:
    """A 6 m x 5 m room, 3 m high, at 5 cm spacing with 3 mm range noise: a level floor, four walls and a ceiling
    turned by `ceiling_tilt_deg` about x that sags `sag_m` in its middle (a warped slab)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(-3.0, 3.0, 0.05), np.arange(-2.5, 2.5, 0.05))
    x, y = x.ravel(), y.ravel()
    floor = np.c_[x, y, np.zeros_like(x)]
    sag = sag_m * (1.0 - (x / 3.0) ** 2 - (y / 2.5) ** 2)
    ceiling = np.c_[x, y, 3.0 + y * np.tan(np.deg2rad(ceiling_tilt_deg)) - sag]
    walls = []
    for h in np.arange(0.05, 2.95, 0.05):
        xs, ys = np.arange(-3.0, 3.0, 0.05), np.arange(-2.5, 2.5, 0.05)
        walls += [
            np.c_[xs, np.full_like(xs, -2.5), np.full_like(xs, h)],
            np.c_[xs, np.full_like(xs, 2.45), np.full_like(xs, h)],
        ]
        walls += [
            np.c_[np.full_like(ys, -3.0), ys, np.full_like(ys, h)],
            np.c_[np.full_like(ys, 2.95), ys, np.full_like(ys, h)],
        ]
    pts = np.concatenate([floor, ceiling, *walls])
    return pts + rng.normal(0.0, 0.003, pts.shape)


def _assess_room(points: np.ndarray) -> dict:
    from aftershock.pipeline.config import Config
    from aftershock.pipeline.report.assess import assess_mission
    from aftershock.pipeline.report.gather import MissionData

    entry, _ = assess_mission(MissionData("room", "ok", cloud=LabelledCloud(points)), Config())
    return entry


def test_a_slab_tilted_well_beyond_the_limit_is_flagged() -> None:
    limits = ReportConfig()
    m = _assess_room(_room(2.0))
    [s] = m["storeys"]
    print(f"tilt {s['tilt_deg']:.3f} ± {s['tilt_uncertainty_deg']:.3f}°")
    assert s["tilt_deg"] == pytest.approx(2.0, abs=0.05)
    assert 0 < s["tilt_uncertainty_deg"] < 0.1  # a flat slab's normal is known to a few hundredths of a degree
    assert s["tilt_deg"] - s["tilt_uncertainty_deg"] > limits.tilt_unsafe_deg and s["flag"] == "unsafe"
    assert ("tilt", 0) in [(f["kind"], f["storey"]) for f in m["findings"]]
    slabs = next(i for i in m["checklist"] if i["item"] == "floors and slabs")
    assert slabs["status"] == "found" and "± " in slabs["evidence"]
    assert m["posting"]["suggested"] == "unsafe"


def test_a_slab_within_its_uncertainty_of_the_limit_is_not_flagged() -> None:
    """A ceiling tilted a little over the limit that sags 3 cm: the quadrants' planes disagree by more than the
    tilt's distance to the limit, so the tilt is no evidence either way -- said so, and not escalated on."""
    limit = ReportConfig().tilt_restricted_deg
    m = _assess_room(_room(limit + 0.06, sag_m=0.03))
    [s] = m["storeys"]
    print(f"tilt {s['tilt_deg']:.3f} ± {s['tilt_uncertainty_deg']:.3f}°")
    assert s["tilt_deg"] > limit and s["tilt_deg"] - s["tilt_uncertainty_deg"] <= limit
    assert s["flag"] == "within measurement uncertainty of the limit"
    assert "tilt" not in [f["kind"] for f in m["findings"]]
    slabs = next(i for i in m["checklist"] if i["item"] == "floors and slabs")
    assert "within measurement uncertainty of the limit" in slabs["evidence"]
    assert slabs["status"] == "not_assessable"  # no crack assessment, and the tilt settles nothing
    assert not any("limit" in r for r in m["posting"]["reasons"]), m["posting"]
    assert "within measurement uncertainty of the limit" in m["posting"]["rule"]


def test_tilt_uncertainty_is_null_with_the_reason_where_not_measured() -> None:
    """Slabs read from damage.json (no map, so no slab points): the tilt is there, its uncertainty is not."""
    from aftershock.pipeline.config import Config
    from aftershock.pipeline.report.assess import assess_mission
    from aftershock.pipeline.report.gather import MissionData

    tilted = [np.sin(np.deg2rad(1.0)), 0.0, np.cos(np.deg2rad(1.0)), -3.0]
    stories = [
        {"index": 0, "height_m": 0.0, "plane": [0.0, 0.0, 1.0, 0.0], "drift_x_mm": 0.0, "drift_y_mm": 0.0},
        {"index": 1, "height_m": 3.0, "plane": tilted, "drift_x_mm": 2.0, "drift_y_mm": 0.0},
    ]
    entry, _ = assess_mission(MissionData("room", "ok", damage={"stories": stories, "notes": []}), Config())
    [s] = entry["storeys"]
    assert s["tilt_deg"] == pytest.approx(1.0, abs=1e-3) and s["tilt_uncertainty_deg"] is None
    assert "tilt uncertainty not measured" in s["reason"] and "damage.json" in s["reason"]
    assert s["flag"] == "unsafe"  # no uncertainty stated: the value alone is compared
