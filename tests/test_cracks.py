"""Cracks: exact minimum-area rectangles, crack instances and their sizes, features and detectors, the
`cracks` command on the real damaged columns and slab, and bad input (sparse clouds, wrong masks)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import read_cloud, write_cloud
from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.damage.detectors import Detector, detect, grow, valley_threshold
from aftershock.pipeline.damage.features import FeatureSet, compute_features
from aftershock.pipeline.damage.measure import crack_shape, measure_cracks, min_area_rectangle, supported
from aftershock.pipeline.damage.report import find_cracks
from aftershock.pipeline.types import LabelledCloud


@pytest.mark.parametrize("angle_deg", [0.0, 17.0, 45.0, 90.0, 133.0])
def test_min_area_rectangle_is_exact_at_any_angle(angle_deg: float) -> None:
    rng = np.random.default_rng(0)
    uv = np.vstack([rng.uniform([-0.6, -0.02], [0.6, 0.02], (500, 2)), [[-0.6, -0.02], [0.6, 0.02], [0.6, -0.02]]])
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    rect = min_area_rectangle(uv @ rot.T + [3.0, -1.0])
    assert rect.length == pytest.approx(1.2, abs=1e-9)
    assert rect.width == pytest.approx(0.04, abs=1e-9)
    assert abs(abs(rect.axis @ rot[:, 0]) - 1) < 1e-9
    assert np.allclose(rect.center, [3.0, -1.0], atol=1e-9)


def test_min_area_rectangle_degenerate() -> None:
    line = np.c_[np.linspace(0, 1, 5), np.linspace(0, 1, 5)]
    assert min_area_rectangle(line).length == pytest.approx(np.sqrt(2))
    assert min_area_rectangle(line).width == 0.0
    assert min_area_rectangle(np.zeros((1, 2))).length == 0.0


def _plane_with_cracks(spacing: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """A 1 x 1 m wall in an arbitrary orientation with two straight cracks: 0.5 m x 10 mm and 0.3 m x 4 mm."""
    u, v = np.meshgrid(np.arange(0, 1, spacing), np.arange(0, 1, spacing), indexing="ij")
    uv = np.c_[u.ravel(), v.ravel()]
    c1 = (np.abs(uv[:, 1] - 0.3) <= 0.005) & (uv[:, 0] >= 0.2) & (uv[:, 0] <= 0.7)
    c2 = (np.abs(uv[:, 0] - 0.8) <= 0.002) & (uv[:, 1] >= 0.5) & (uv[:, 1] <= 0.8)
    q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))
    pts = np.c_[uv, np.zeros(len(uv))] @ q.T + [10.0, 5.0, 2.0]
    return pts, c1 | c2


def test_measure_cracks_on_a_rotated_wall() -> None:
    pts, mask = _plane_with_cracks()
    cracks, ids = measure_cracks(pts, mask, link_m=0.01, min_points=20, severe_width_m=0.0032, spacing_m=0.002)
    assert len(cracks) == 2
    assert set(np.unique(ids[mask])) == {1, 2}
    big, small = cracks
    assert big.length_m == pytest.approx(0.5, abs=0.004) and big.width_m == pytest.approx(0.01, abs=0.003)
    assert small.length_m == pytest.approx(0.3, abs=0.004) and small.width_m == pytest.approx(0.004, abs=0.003)
    assert big.severe
    assert abs(np.linalg.norm(big.normal) - 1) < 1e-9


def test_width_below_spacing_is_clamped_and_flagged() -> None:
    pts = np.c_[np.linspace(0, 0.5, 200), np.zeros(200), np.zeros(200)]  # a one-point-wide crack
    cracks, _ = measure_cracks(pts, np.ones(200, bool), 0.01, 20, 0.0032, spacing_m=0.005)
    assert cracks[0].width_m == pytest.approx(0.005) and not cracks[0].width_resolved
    assert not cracks[0].severe  # only a bound: not flagged severe


def _wavy_crack(width: float, wander: float, spacing: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """A 1 m crack of constant opening `width` whose centre line wanders by ±`wander` across a wall; its
    points drop 5 mm into the wall (a groove) and the wall around it is returned too."""
    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.arange(0, 1, spacing), np.arange(-0.15, 0.15, spacing), indexing="ij")
    uv = np.c_[u.ravel(), v.ravel()] + rng.uniform(-0.3, 0.3, (u.size, 2)) * spacing
    phase = uv[:, 0] * 2 * np.pi * 1.5
    slope = np.arctan(wander * 2 * np.pi * 1.5 * np.cos(phase))
    inside = np.abs(uv[:, 1] - wander * np.sin(phase)) * np.cos(slope) <= width / 2
    pts = np.c_[uv, np.where(inside, -0.005, 0.0)]
    return pts, inside


@pytest.mark.parametrize("width", [0.004, 0.01, 0.02])
def test_opening_width_of_a_wandering_crack(width: float) -> None:
    """The rectangle spans the whole wander (≈ 0.1 m); the opening is the crack's width. Measured on the
    wall's plane: the crack's own points are nearly a line, and their plane tilts into the groove."""
    pts, inside = _wavy_crack(width, wander=0.05)
    shape = crack_shape(pts[inside], 0.002, surface=pts)
    assert shape.length == pytest.approx(1.0, abs=0.01)
    assert shape.rect_width > 0.1
    assert shape.width == pytest.approx(width, abs=0.0025)  # about one spacing
    assert abs(shape.normal[2]) > 0.999


def test_support_removes_isolated_points_and_the_rim() -> None:
    pts, inside = _wavy_crack(0.01, wander=0.0)
    rng = np.random.default_rng(0)
    noise = rng.random(len(pts)) < 0.01  # scattered false positives on sound concrete
    rim = np.abs(pts[:, 1]) <= 0.009  # a 4 mm rim of sound concrete either side (what smoothing adds)
    kept = supported(pts, inside | noise | rim, 0.006, 0.5)
    assert kept[inside].all()
    assert not kept[noise & ~rim & ~inside].any()
    assert kept[rim & ~inside].mean() < 0.95  # only the rim's outer edge: the rest is rim all around
    core = supported(pts, kept, 0.006, 0.5, by=inside)  # support by the points detected before smoothing
    assert core[inside].all() and not core[rim & ~inside].any()


def test_blobs_are_not_cracks() -> None:
    """A round patch (a spall, or a cluster of false positives) is not reported as a crack; a thin one is."""
    u, v = np.meshgrid(np.arange(0, 1, 0.002), np.arange(0, 1, 0.002), indexing="ij")
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    blob = np.hypot(pts[:, 0] - 0.3, pts[:, 1] - 0.3) < 0.05
    thin = (np.abs(pts[:, 1] - 0.7) <= 0.003) & (pts[:, 0] > 0.2) & (pts[:, 0] < 0.8)
    cracks, ids = measure_cracks(pts, blob | thin, 0.005, 20, 0.0032, 0.002, min_elongation=3.0)
    assert len(cracks) == 1 and cracks[0].length_m == pytest.approx(0.6, abs=0.01)
    assert not ids[blob].any() and ids[thin].all()


def test_broad_patches_are_not_cracks() -> None:
    """A speckled stain (a round patch of which 80 % of the points score high) can pass the opening-based blob
    test, whose slices see strands as wide as the slices are long; its mean width (area over length) is about as
    large as its length, so the narrowness test drops it and keeps a thin crack (mean width ≈ its opening).
    A group holding half the element (a face lit differently) goes with `max_share`."""
    from aftershock.pipeline.damage.measure import keep_narrow

    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(0, 1, 0.003), np.arange(0, 1, 0.003), indexing="ij")
    pts = (
        np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
        + np.c_[rng.uniform(-0.0006, 0.0006, (u.size, 2)), np.zeros(u.size)]
    )
    stain = (np.hypot(pts[:, 0] - 0.3, pts[:, 1] - 0.3) < 0.1) & (rng.random(len(pts)) < 0.8)
    thin = (np.abs(pts[:, 1] - 0.75) <= 0.0045) & (pts[:, 0] > 0.15) & (pts[:, 0] < 0.85)
    cracks, ids = measure_cracks(pts, stain | thin, 0.01, 20, 0.0032, 0.003, min_elongation=3.0)
    assert len(cracks) == 2  # the stain passes the opening-based test
    crack = next(c for c in cracks if c.length_m > 0.6)
    assert crack.area_width_m == pytest.approx(0.009, abs=0.003)
    kept, kept_ids = keep_narrow(cracks, ids, len(pts), 1.0, 5.0)
    assert len(kept) == 1 and kept[0].length_m > 0.6 and kept_ids[thin].all() and not kept_ids[stain & ~thin].any()
    face, apart = pts[:, 0] < 0.5, thin & (pts[:, 0] > 0.55)
    cracks, ids = measure_cracks(pts, face | apart, 0.01, 20, 0.0032, 0.003)
    kept, kept_ids = keep_narrow(cracks, ids, len(pts), 0.2, 0.0)
    assert len(cracks) == 2 and len(kept) == 1 and not kept_ids[face].any() and kept_ids[apart].all()


def _patch(n: int = 4000, seed: int = 0) -> LabelledCloud:
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(0, 0.5, (n, 2)), rng.normal(0, 0.0005, n)]
    colors = np.full((n, 3), 200, np.uint8)
    dark = np.abs(pts[:, 0] - 0.25) < 0.01
    colors[dark] = 90
    return LabelledCloud(pts, colors, rng.normal(100, 5, n).astype(np.float32))


@pytest.mark.parametrize("features", list(FeatureSet))
def test_every_feature_set(features: FeatureSet) -> None:
    cloud = _patch()
    x = compute_features(cloud, features, CrackConfig())
    assert x.shape[0] == len(cloud) and x.dtype == np.float32 and np.isfinite(x).all()
    if features is FeatureSet.RGB:
        assert x.min() >= -0.5 and x.max() <= 0.5  # the one colour range everywhere


def test_crackembed_is_independent_of_batch_mates() -> None:
    from aftershock.models.crackembed import NEIGHBOURS, load_model

    model = load_model()
    rng = np.random.default_rng(0)
    nb = torch.from_numpy(rng.normal(size=(8, NEIGHBOURS, 7)).astype(np.float32))
    own = torch.from_numpy(rng.normal(size=(8, 3)).astype(np.float32))
    with torch.no_grad():
        together = model(nb, own)
        alone = model(nb[:1], own[:1])
    assert torch.allclose(together[:1], alone, atol=1e-6)
    assert torch.allclose(together.norm(dim=1), torch.ones(8), atol=1e-5)


# ridge and region work on orthoimages: test_cracks_ridge.py, test_cracks_region.py
@pytest.mark.parametrize("detector", [d for d in Detector if d not in (Detector.RIDGE, Detector.REGION)])
def test_every_detector_flags_planted_outliers(detector: Detector) -> None:
    """Anomaly detectors find scattered outliers; the clustering baselines find a small separate cluster."""
    rng = np.random.default_rng(0)
    clustering = detector in {Detector.KMEANS, Detector.GMM, Detector.MEAN_SHIFT}
    if clustering:
        odd = rng.normal(6, 0.3, (200, 2))
    elif detector is Detector.LOCAL_OUTLIER_FACTOR:  # LOF: isolated points beside a denser region
        angle, radius = rng.uniform(0, 2 * np.pi, 12), rng.uniform(4.0, 6.0, 12)
        odd = np.c_[radius * np.cos(angle), radius * np.sin(angle)]
    else:
        odd = rng.uniform(4, 9, (200, 2)) * rng.choice([-1, 1], (200, 2))
    x = np.vstack([rng.normal(0, 1, (1800, 2)), odd])
    truth = np.r_[np.zeros(1800, bool), np.ones(len(odd), bool)]
    mask = detect(x, detector, seed=0, clusters=2).mask
    recall = (mask & truth).sum() / truth.sum()
    precision = (mask & truth).sum() / max(mask.sum(), 1)
    assert recall >= {Detector.ONE_CLASS_SVM: 0.7, Detector.LOCAL_OUTLIER_FACTOR: 0.6}.get(detector, 0.9), recall
    assert precision >= 0.3, precision


def test_find_cracks_on_a_synthetic_wall() -> None:
    """A 0.3 m wall patch, tilted in space, with two dark recessed cracks (25 and 12 mm wide) covering ~10 %
    of it (as the field data's 5-15 %), far darker than the field's cracks (40 % against 10-20 %). The scores
    have a separate crack mode, so the threshold rises to its valley. Measured with the shipped CrackEmbed: F1 0.97
    without the rim growth (recall 1.0, lengths +2 / +1 mm, widths +3 / +1 mm); with it (the default) F1 0.91: the
    growth re-admits a rim of about one smoothing cell around such high-contrast cracks (lengths +36 / +7 mm,
    widths +9 / +15 mm; with the weights shipped before, F1 0.94 / 0.89 and lengths +25 mm)."""
    rng = np.random.default_rng(2)
    u, v = np.meshgrid(np.arange(0, 0.3, 0.002), np.arange(0, 0.3, 0.002), indexing="ij")
    uv = np.c_[u.ravel(), v.ravel()] + rng.uniform(-0.0004, 0.0004, (u.size, 2))
    c1 = (np.abs(uv[:, 1] - 0.08) <= 0.0125) & (uv[:, 0] >= 0.02) & (uv[:, 0] <= 0.27)
    c2 = (np.abs(uv[:, 0] - 0.2) <= 0.006) & (uv[:, 1] >= 0.14) & (uv[:, 1] <= 0.28)
    mask = c1 | c2
    depth = np.where(mask, -0.004, 0.0) + rng.normal(0, 0.0005, len(uv))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pts = np.c_[uv, depth] @ q.T + [1.0, 2.0, 1.5]
    colors = np.clip(np.where(mask, 120.0, 200.0)[:, None] + rng.normal(0, 10, (len(pts), 3)), 0, 255).astype(np.uint8)
    cloud = LabelledCloud(pts, colors)
    tight = find_cracks(cloud, CrackConfig(grow_m=0.0, detector="isolation-forest"), mask, resolution_m=0.001)
    s = tight.scores
    assert s is not None and s.f1 > 0.9 and s.recall > 0.95, s
    # The study's protocol (the detected part of the main true crack) flatters: near exact.
    assert s.study_length_error_m < 0.005 and s.study_width_error_m < 0.003
    # What a field team reads: the whole reported crack, false positives linked onto it included.
    assert s.true_cracks == s.found_cracks == 2
    assert s.length_error_m < 0.01 and s.width_error_m < 0.006
    assert all(abs(m.width_m - m.true_width_m) < 0.006 for m in s.matches)
    assert len(tight.cracks) == 2 and all(c.length_m > c.rect_width_m >= c.width_m > 0 for c in tight.cracks)
    default = find_cracks(cloud, CrackConfig(detector="isolation-forest"), mask, resolution_m=0.001)
    d = default.scores
    assert d is not None and d.f1 > 0.85 and d.recall > 0.95, d
    assert d.true_cracks == d.found_cracks == 2 and len(default.cracks) == 2
    assert d.length_error_m < 0.04 and all(0 <= m.width_m - m.true_width_m < 0.016 for m in d.matches)
    # no crack is lost and none is joined to the other
    assert default.mask[tight.mask].all() and len({m.crack_id for m in d.matches}) == 2


def test_valley_threshold_finds_a_separate_mode_and_only_then() -> None:
    """A separate high mode (5 % of the scores) moves the threshold into the gap before it; one skewed mode
    (a heavy tail, no second mode) leaves the detector's threshold; the threshold never drops below it."""
    rng = np.random.default_rng(0)
    sound = rng.normal(-0.1, 0.03, 19000)
    two = np.r_[sound, rng.normal(0.17, 0.015, 1000)]
    t = valley_threshold(two, 0.0)
    assert 0.02 < t < 0.14
    f1 = 2 * (two[19000:] > t).sum() / ((two > t).sum() + 1000)
    assert f1 > 0.97 and 2 * (two[19000:] > 0).sum() / ((two > 0).sum() + 1000) < f1
    assert valley_threshold(np.r_[sound, -0.1 + rng.exponential(0.08, 3000)], 0.0) == 0.0
    assert valley_threshold(two, 0.5) == 0.5
    assert valley_threshold(np.zeros(100), 0.0) == 0.0


def test_grow_joins_weak_points_near_a_crack_only() -> None:
    pts = np.c_[np.arange(10) * 0.01, np.zeros(10), np.zeros(10)]
    mask = np.zeros(10, bool)
    mask[:3] = True
    score = np.array([1, 1, 1, 0.5, 0.5, 0.5, -1, 0.5, 0.5, 0.5])
    # within 1.5 cm of the crack and above 0: point 3, then nothing further (one step, not a flood)
    assert np.flatnonzero(grow(pts, mask, score, 0.0, 0.015)).tolist() == [0, 1, 2, 3]
    assert np.flatnonzero(grow(pts, mask, score, 0.0, 0.035)).tolist() == [0, 1, 2, 3, 4, 5]
    assert np.array_equal(grow(pts, mask, score, 0.0, 0.0), mask)
    assert not grow(pts, np.zeros(10, bool), score, 0.0, 0.05).any()


@pytest.fixture(scope="module")
def crack_files(crack_dir: Path) -> dict[str, tuple[Path, Path]]:
    return {n: (crack_dir / f"{n}.ply", crack_dir / f"{n}_mask.npy") for n in ("column1", "column2", "slab2")}


# The old default (the point-feature path, `--detector isolation-forest`), measured with its settings and weights
# (chosen leave-one-object-out, `make bench-cracks`: shade+crackembed, isolation forest, valley threshold, 2 cm
# smoothing keeping each point's own score, support clean-up, 3 cm growth, crack points = points of reported cracks,
# no depth test; CrackEmbed as `aftershock train crackembed` builds it): F1 0.70 / 0.71 / 0.71 (the original method
# published 0.55 / 0.67 / about 0.75); main-crack width error 7.0 / 2.6 / 5.7 mm.
F1_AT_LEAST = {"column1": 0.68, "column2": 0.69, "slab2": 0.69}
WIDTH_ERROR_AT_MOST = {"column1": 0.008, "column2": 0.004, "slab2": 0.012}


@pytest.mark.parametrize("name", ["column1", "column2", "slab2"])
def test_cracks_command_on_real_elements(
    name: str, crack_files: dict[str, tuple[Path, Path]], capsys: pytest.CaptureFixture[str]
) -> None:
    ply, mask = crack_files[name]
    assert main(["cracks", str(ply), "--truth", str(mask), "--detector", "isolation-forest", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {"precision", "recall", "f1", "length_error_m", "width_error_m", "cracks"}
    assert out["f1"] >= F1_AT_LEAST[name]
    assert out["width_error_m"] <= WIDTH_ERROR_AT_MOST[name]
    assert out["resolution_m"] == (0.01 if name == "slab2" else 0.001)
    assert out["cracks"] and all({"length_m", "width_m", "position"} <= set(c) for c in out["cracks"])
    assert all({"depth_contrast", "chroma_contrast"} <= set(c) for c in out["cracks"])
    assert any(c["chroma_contrast"] is not None and c["chroma_contrast"] > 0 for c in out["cracks"])
    measured = [c for c in out["cracks"] if c["width_m"] is not None]
    assert all(c["width_m"] is not None or c["resolvable_mm"] > 0 for c in out["cracks"])
    assert all(c["width_m"] <= max(c["rectangle_width_m"], out["spacing_m"]) + 1e-4 for c in measured)
    assert {"study_width_error_m", "median_width_error_m", "error_definition", "true_crack_matches"} <= set(out)
    assert out["found_true_cracks"] >= 1


def test_mask_of_the_wrong_length_is_an_error(
    crack_files: dict[str, tuple[Path, Path]], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["cracks", str(crack_files["slab2"][0]), "--truth", str(crack_files["column1"][1])]) == 2
    err = capsys.readouterr().err
    assert "mask has shape (47804,) but the cloud has 29221 points" in err and "Traceback" not in err


def test_too_sparse_says_so(crack_files: dict[str, tuple[Path, Path]], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["cracks", str(crack_files["slab2"][0]), "--resolution", "0.05"]) == 2
    assert "too sparse for crack measurement" in capsys.readouterr().err


def test_box_and_report_file(
    crack_files: dict[str, tuple[Path, Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ply, mask = crack_files["column1"]
    cloud = read_cloud(ply)
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    box = ",".join(f"{v:.3f}" for v in [*lo, *(lo + (hi - lo) * [1, 1, 0.5])])
    report = tmp_path / "r.json"
    assert main(["cracks", str(ply), "--box", box, "--truth", str(mask), "--report", str(report)]) == 0
    assert "precision" in capsys.readouterr().out
    assert json.loads(report.read_text())["points"] > 0
    assert main(["cracks", str(ply), "--box", box, "--report", str(report)]) == 2  # exists, no --force
    assert main(["cracks", str(ply), "--box", "1,2,3"]) == 2


def test_pcd_input_without_color_needs_a_geometric_feature(tmp_path: Path) -> None:
    pts, _ = _plane_with_cracks(0.004)
    path = write_cloud(tmp_path / "c.ply", LabelledCloud(pts))
    assert main(["cracks", str(path), "--features", "curvature", "--json"]) == 0
    assert main(["cracks", str(path), "--features", "nonsense"]) == 2


def test_assess_damage_on_a_dense_simulated_column() -> None:
    """A labelled dense element: assessed as one structural instance; cracks reported with their sizes."""
    from aftershock.pipeline.config import Config
    from aftershock.pipeline.damage import assess_damage
    from aftershock.sources.simulator.cracks import cracked_element

    cloud, _, _ = cracked_element("column", 100, 0.004)
    report = assess_damage(cloud, Config())
    assert report.elements_checked == 1
    assert report.cracks and report.crack_points is not None and len(report.crack_points) > 0
    out = json.loads(json.dumps(report.to_json()))
    assert all(c["length_m"] > 0 and (c["width_m"] is None or c["width_m"] > 0) for c in out["cracks"])
    assert out["stories"] == [] or isinstance(out["stories"], list)


def test_extract_elements_by_size_and_box() -> None:
    """An unlabelled scene (floor, wall, a 0.4 x 0.4 x 2.6 m column): region growing on normals and colour
    cuts it into elements; picking by the column's size keeps only the column's faces."""
    from aftershock.pipeline.damage.components import COLUMN_DIMS_M, extract_elements

    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-2, 2, (40000, 2)), np.zeros(40000)]
    wall = np.c_[np.full(20000, -1.9), rng.uniform(-2, 2, 20000), rng.uniform(0, 2.6, 20000)]
    t, z, side = rng.uniform(-0.2, 0.2, 20000), rng.uniform(0.02, 2.6, 20000), rng.integers(0, 4, 20000)
    cx = np.where(side == 0, 0.2, np.where(side == 1, -0.2, t))
    cy = np.where(side == 2, 0.2, np.where(side == 3, -0.2, t))
    column = np.c_[cx + 0.5, cy, z]
    pts = np.vstack([floor, wall, column]) + rng.normal(0, 0.002, (80000, 3))
    colors = np.repeat(np.array([[90, 90, 90], [200, 200, 190], [170, 160, 150]], np.uint8), [40000, 20000, 20000], 0)
    cloud = LabelledCloud(pts, colors)
    cfg = CrackConfig()
    every = extract_elements(cloud, cfg)
    assert len(every) >= 3
    columns = extract_elements(cloud, cfg, dims=COLUMN_DIMS_M)
    assert 1 <= len(columns) <= 4
    picked = np.concatenate(columns)
    assert np.all(picked >= 60000)  # only column points
    assert len(picked) > 0.8 * 20000
    boxed = extract_elements(cloud, cfg, box=np.array([[0.25, -0.25, 0.01], [0.75, 0.25, 3.0]]))
    assert len(boxed) == 1 and np.all(boxed[0] >= 60000)


def test_thresholds_know_when_there_is_no_crack() -> None:
    """One population (sound concrete only): the mixture finds no second one and the threshold is the null
    rule's; a separate population of 6 % crack scores: the threshold falls between the two."""
    from aftershock.pipeline.damage.detectors import mixture_threshold, null_threshold

    rng = np.random.default_rng(0)
    sound = rng.normal(0.0, 1.0, 20000)
    null = null_threshold(sound, 3.0)
    assert null == pytest.approx(3.0, abs=0.1)
    assert (sound > null).mean() < 0.003
    assert mixture_threshold(sound, null, 0.03, 3.0) == null
    cracked = np.r_[sound, rng.normal(8.0, 1.0, 1300)]
    t = mixture_threshold(cracked, null_threshold(cracked, 2.0), 0.03, 3.0)
    assert 3.0 < t < 6.0
    assert (cracked[20000:] > t).mean() > 0.97 and (sound > t).mean() < 0.003


def test_edge_points_are_the_border_of_the_scan() -> None:
    from aftershock.pipeline.damage.detectors import edge_points

    u, v = np.meshgrid(np.arange(0, 1, 0.003), np.arange(0, 1, 0.003))
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    edge = edge_points(pts, 0.01)
    inner = np.abs(pts[:, :2] - 0.5).max(axis=1) < 0.48
    assert not edge[inner].any() and edge[~inner].mean() > 0.5


def _write_ply(path: Path, points: np.ndarray) -> Path:
    header = f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n"
    header += "property float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_text(header + "".join(f"{x} {y} {z}\n" for x, y, z in points))
    return path


@pytest.mark.parametrize(
    ("points", "problem"),
    [
        (np.zeros((0, 3)), "too few to look for cracks"),
        (np.zeros((1, 3)), "too few to look for cracks"),
        (np.full((500, 3), np.nan), "finite coordinates"),
    ],
)
def test_bad_clouds_are_one_line_and_exit_2(
    points: np.ndarray, problem: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write_ply(tmp_path / "bad.ply", points)
    assert main(["cracks", str(path), "--features", "curvature"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1
    assert "bad.ply" in err and problem in err


def test_nan_points_are_left_out_with_a_note() -> None:
    """NaN coordinates (a scanner's no-return) are dropped before any neighbourhood or fit, and said so."""
    pts, mask = _plane_with_cracks(0.004)
    pts = pts.copy()
    pts[::50] = np.nan
    result = find_cracks(LabelledCloud(pts), CrackConfig(), mask, features="curvature", resolution_m=0.004)
    assert result.notes and "non-finite" in result.notes[0]
    assert np.isfinite(result.cloud.points).all() and result.scores is not None


def test_a_flat_streak_is_not_recessed_a_crack_and_a_corner_are_told_apart() -> None:
    """A column's two faces: a 6 mm crack 3 mm deep on one, an equally dark flat dirt streak on the other, the
    corner between them. Detected as bands three times wider than they are (smoothing and growth), both are
    cracks to colour; only the crack lies behind the surface around it (in local noise units), so with a
    depth limit the streak is dropped and the crack is renumbered first."""
    from aftershock.pipeline.damage.recess import depth_z, keep_recessed

    rng = np.random.default_rng(0)
    s, z = np.meshgrid(np.arange(0, 0.3, 0.002), np.arange(0, 0.6, 0.002), indexing="ij")
    uv = np.c_[s.ravel(), z.ravel()]
    band = np.abs(uv[:, 0] - 0.15) <= 0.009
    crack = (np.abs(uv[:, 0] - 0.15) <= 0.003) & (uv[:, 1] < 0.5)  # shorter than the streak
    faces = [np.c_[0.3 - uv[:, 0], -0.003 * crack, uv[:, 1]], np.c_[np.zeros(len(uv)), uv[:, 0], uv[:, 1]]]
    pts = np.concatenate(faces) + rng.normal(0, 0.0004, (2 * len(uv), 3))
    on_crack = np.r_[band & (uv[:, 1] < 0.5), np.zeros(len(uv), bool)]
    on_streak = np.r_[np.zeros(len(uv), bool), band]
    zd = depth_z(pts, on_crack | on_streak, 0.02)
    corner = (np.abs(pts[:, 0]) < 0.004) | (np.abs(pts[:, 1]) < 0.004)
    assert np.median(zd[np.r_[crack, np.zeros(len(uv), bool)]]) > 4
    assert np.median(zd[on_streak]) < 1 and np.median(zd[corner]) < 1.5
    cracks, ids = measure_cracks(pts, on_crack | on_streak, 0.005, 20, 0.0032, 0.002, min_elongation=3.0)
    assert len(cracks) == 2 and ids[on_streak][0] == 1  # the streak's band is the larger group
    kept, kept_ids = keep_recessed(cracks, ids, zd, 0.0)  # no limit: both stay, each with its contrast
    assert len(kept) == 2 and kept[0].depth_contrast < 2.5 < 4 < kept[1].depth_contrast
    kept, kept_ids = keep_recessed(cracks, ids, zd, 3.0)
    assert len(kept) == 1 and kept[0].instance_id == 1 and kept[0].depth_contrast > 4
    assert (kept_ids[on_crack] == 1).all() and not kept_ids[on_streak].any()


def test_hue_tells_a_crack_from_shade_and_a_clipped_ring_is_not_judged() -> None:
    """A wall with three dark bands of the same brightness: a crack that also turns the surface brown (its hue
    shifts), a shaded band and a grey stain (all channels scaled alike). Only the crack has a hue contrast;
    with a limit the other two are dropped and the crack renumbered first. A band on a surface whose red channel
    is clipped at 255 on most points cannot be judged (NaN) and is never dropped for it."""
    from aftershock.pipeline.damage.tint import chroma_contrast, keep_tinted, measure_tint

    rng = np.random.default_rng(0)
    s, z = np.meshgrid(np.arange(0, 0.6, 0.002), np.arange(0, 0.5, 0.002), indexing="ij")
    pts = np.c_[s.ravel(), np.zeros(s.size), z.ravel()] + rng.normal(0, 0.0003, (s.size, 3))
    colors = np.array([200.0, 190.0, 170.0]) + rng.normal(0, 8, (s.size, 3))
    bands = [np.abs(pts[:, 0] - x) <= 0.006 for x in (0.1, 0.3, 0.5)]  # shade, crack, stain
    colors[bands[0]] *= 0.8
    colors[bands[1]] *= np.array([0.86, 0.8, 0.7])  # as dark on average, and browner
    colors[bands[2]] *= 0.8
    rgb = np.clip(np.round(colors), 0, 255).astype(np.uint8)
    mask = bands[0] | bands[1] | bands[2]
    cracks, ids = measure_cracks(pts, mask, 0.005, 20, 0.0032, 0.002, min_elongation=3.0)
    assert len(cracks) == 3
    measure_tint(cracks, pts, rgb, ids, ~mask)
    by_band = {i: cracks[ids[b][0] - 1].chroma_contrast for i, b in enumerate(bands)}
    assert by_band[1] > 3 and by_band[0] < 0.5 and by_band[2] < 0.5
    kept, kept_ids = keep_tinted(cracks, ids, 1.0)
    assert len(kept) == 1 and kept[0].instance_id == 1 and (kept_ids[bands[1]] == 1).all()
    assert not kept_ids[bands[0] | bands[2]].any()

    bright = rgb.copy()
    bright[~mask, 0] = 255  # the sound surface's red at the ceiling: its hue is not measured
    contrast = chroma_contrast(pts, bright, ids, ~mask)
    assert np.isnan(contrast[1:]).all()
    cracks, ids = measure_cracks(pts, mask, 0.005, 20, 0.0032, 0.002, min_elongation=3.0)
    measure_tint(cracks, pts, bright, ids, ~mask)
    assert len(keep_tinted(cracks, ids, 1.0)[0]) == 3
