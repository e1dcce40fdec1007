"""Drift and tilt that could not be measured are null with a reason and read "not measured" -- never 0.0 --
in `drift`'s JSON and text, in `run --damage`'s text, in damage.json and in the Rerun recording (issue 29)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from rrd_read import read_rrd

from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.config import DriftConfig, RerunConfig
from aftershock.pipeline.damage.drift import measure_drift
from aftershock.pipeline.mission import SAMPLE
from aftershock.pipeline.types import DamageFound, LabelledCloud
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks.rerun_sink import RerunSink

ZERO = re.compile(r"(?<![\d.])0\.0+ ?(mm|°)")  # a drift or tilt of exactly zero, as a number


def _one_slab(rng: np.random.Generator) -> np.ndarray:
    """A 10 x 8 m floor with walls standing on it, and no ceiling."""
    xy = rng.uniform([-5, -4], [5, 4], size=(40000, 2))
    floor = np.c_[xy, rng.normal(0, 0.002, len(xy))]
    z, t, side = rng.uniform(0, 2.5, 30000), rng.uniform(-1, 1, 30000), rng.integers(0, 4, 30000)
    x = np.where(side < 2, np.where(side == 0, -5.0, 5.0), t * 5)
    y = np.where(side < 2, t * 4, np.where(side == 2, -4.0, 4.0))
    return np.vstack([floor, np.c_[x, y, z]])


def _two_slabs(rng: np.random.Generator) -> np.ndarray:
    pts = _one_slab(rng)
    xy = rng.uniform([-5, -4], [5, 4], size=(40000, 2))
    return np.vstack([pts, np.c_[xy + 0.01, 3.0 + rng.normal(0, 0.002, len(xy))]])


def test_one_slab_has_no_drift_and_says_why() -> None:
    result = measure_drift(_one_slab(np.random.default_rng(0)), DriftConfig())
    [only] = result.stories
    assert only.drift_mm is None and only.drift_x_mm is None and only.tilt_deg is None and only.tilt_x_deg is None
    assert "one slab" in (only.reason or "")
    two = measure_drift(_two_slabs(np.random.default_rng(0)), DriftConfig()).stories
    assert len(two) == 2 and two[0].drift_mm == 0.0 and "reference" in (two[0].reason or "")
    assert two[1].drift_mm is not None and two[1].reason is None


def test_drift_command_json_and_text(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_cloud(tmp_path / "floor.ply", LabelledCloud(_one_slab(np.random.default_rng(1))))
    assert main(["drift", str(path), "--json"]) == 0
    [story] = json.loads(capsys.readouterr().out)["stories"]
    assert story["drift_mm"] is None and story["tilt_deg"] is None and "one slab" in story["reason"]
    assert main(["drift", str(path)]) == 0
    text = capsys.readouterr().out
    assert "not measured" in text and not ZERO.search(text), text


def test_run_damage_text_and_damage_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The sample recording sees one floor slab."""
    out = tmp_path / "export"
    args = ["run", str(SAMPLE), "--damage", "--export", str(out), "--labeller", "region-growing", "-q"]
    assert main(args) == 0
    text = capsys.readouterr().out
    story_lines = [line for line in text.splitlines() if line.strip().startswith("story")]
    assert story_lines and all("not measured" in line and not ZERO.search(line) for line in story_lines), text
    [story] = json.loads((out / "damage.json").read_text())["stories"]
    assert story["drift_mm"] is None and story["reason"]


def test_the_viewer_says_not_measured_and_draws_no_arrow(tmp_path: Path) -> None:
    path = tmp_path / "one.rrd"
    sink = RerunSink(path, False, None, RerunConfig())
    [story] = measure_drift(_one_slab(np.random.default_rng(2)), DriftConfig()).stories
    sink.damage(DamageFound(stories=[story]))
    sink.close()
    rec = read_rrd(path)
    [label] = rec.texts(f"{L.STORIES}/s0/label", "Points3D:labels", static=True)
    assert "not measured" in label and not ZERO.search(label)
    assert L.DRIFT not in rec.entities


def test_the_legend_names_every_class_in_its_colour(tmp_path: Path) -> None:
    """The legend (visible in the default layout's "site" tab) holds one disc per class in the class colour and
    each class's name, then unlabelled and the colour uncertain voxels are drawn in."""
    from aftershock.pipeline.classes import CLASS_COLORS, CLASS_NAMES, UNCERTAIN_COLOR

    path = tmp_path / "legend.rrd"
    sink = RerunSink(path, False, None, RerunConfig())
    sink.damage(DamageFound())
    sink.close()
    rec = read_rrd(path)
    names = rec.texts(L.LEGEND_NAMES, "Points2D:labels", static=True)
    assert names == [*CLASS_NAMES, "unlabelled", "uncertain label"]
    [colors] = rec.rows(L.LEGEND_SWATCHES, "Points2D:colors", static=True)
    rgba = np.array(colors, dtype=np.uint32)
    rgb = np.stack([(rgba >> 24) & 255, (rgba >> 16) & 255, (rgba >> 8) & 255], axis=1)
    assert np.array_equal(rgb[: len(CLASS_NAMES)], CLASS_COLORS)
    assert np.array_equal(rgb[-1], UNCERTAIN_COLOR)


def test_the_default_layout_opens_on_the_site_with_a_plan_and_the_legend() -> None:
    """First tab: the 3D map, the plan (seen from straight above) and the legend; the engineering plots and the
    log on the second tab."""
    import rerun.blueprint as rrb

    tabs = L.default_blueprint().root_container
    assert isinstance(tabs, rrb.Tabs)
    site, engineering = tabs.contents
    assert site.name == "site" and engineering.name == "engineering"
    main_view, side = site.contents
    plan, legend = side.contents
    assert isinstance(main_view, rrb.Spatial3DView) and isinstance(plan, rrb.Spatial3DView)
    assert plan.name.startswith("plan") and isinstance(legend, rrb.Spatial2DView) and legend.origin == L.LEGEND
    kinds = [type(v).__name__ for v in engineering.contents]
    assert kinds == ["TimeSeriesView", "TimeSeriesView", "TextLogView"]


def test_crack_labels_do_not_pile_up(tmp_path: Path) -> None:
    """Two cracks 10 cm apart and one far away: the severe one of the pair and the far one carry full labels,
    the other of the pair its number only."""
    from aftershock.pipeline.types import Crack

    def crack(i: int, at: tuple[float, float, float], length: float, severe: bool) -> Crack:
        return Crack(i, np.array(at), length, 0.004, 50, np.array([0, 0, 1.0]), np.array([1.0, 0, 0]), severe)

    path = tmp_path / "cracks.rrd"
    sink = RerunSink(path, False, None, RerunConfig())
    cracks = [crack(1, (0, 0, 1), 0.2, False), crack(2, (0, 0, 1.1), 0.1, True), crack(3, (0, 0, 3), 0.3, False)]
    sink.damage(DamageFound(cracks))
    sink.close()
    labels = read_rrd(path).texts(L.CRACKS, "Boxes3D:labels", static=True)
    assert labels[0] == "crack 1" and labels[1].startswith("crack 2: 10.0 cm long") and "wide" in labels[2]
