"""The crack study on the real damaged elements (`make bench-cracks`): every feature with the isolation forest,
every detector on the best feature, speed on the 90,000-point column, unseen simulated elements, and the plots
of F1 against point spacing, crack width and share of crack points (docs/cracks_*.png). Also the story drift
and tilt errors on simulated damaged buildings.

The default setting is chosen on unseen simulated elements (`test_setting_selection`), never on the real ones.

Protocol: each element is reduced to one point per voxel of 1 mm (columns) or 1 cm (slab); a voxel is crack
when at least half of its points are; precision/recall/F1 count the points of that reduced cloud. Length and
width errors in the tables are those of the main true crack against the whole reported crack holding most of
it (widths are openings); `test_per_crack_sizes` gives them per crack, and the study's protocol beside them.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import numpy as np
import pytest
from cracks_common import far_share, sim_spacing

from aftershock.pipeline.cloud_io import read_cloud
from aftershock.pipeline.config import CrackConfig, DriftConfig
from aftershock.pipeline.damage.detectors import Detector
from aftershock.pipeline.damage.features import FeatureSet
from aftershock.pipeline.damage.report import CrackResult, find_cracks
from aftershock.pipeline.types import Crack, LabelledCloud
from aftershock.sources.simulator.damage import CrackTruth

pytestmark = pytest.mark.timeout(7200)

OBJECTS: Final = ("column1", "column2", "slab2")
DOCS: Final = Path(__file__).resolve().parents[2] / "docs"
# The study's isolation-forest F1 (mean of 7 columns / 2 slabs) per feature, and per detector on CrackEmbed.
PUBLISHED_FEATURE: Final = {
    "rgb": ".36 / .63",
    "intensity": ".21 / .60",
    "normal": ".30 / .45",
    "curvature": ".34 / .44",
    "fpfh": ".13 / .14",
    "crackembed": ".50 / .71",
    "shade": "(new)",
    "shade+crackembed": "(new)",
}
PUBLISHED_DETECTOR: Final = {
    "isolation-forest": ".50",
    "robust-covariance": ".52",
    "one-class-svm": ".41",
    "lof": ".12",
    "kmeans": ".43",
    "gmm": ".19",
    "mean-shift": ".27",
}
PUBLISHED_OBJECT: Final = {"column1": 0.55, "column2": 0.67, "slab2": 0.75}


@pytest.fixture(scope="module")
def elements(crack_dir: Path) -> dict[str, tuple[LabelledCloud, np.ndarray]]:
    return {n: (read_cloud(crack_dir / f"{n}.ply"), np.load(crack_dir / f"{n}_mask.npy")) for n in OBJECTS}


def _row(label: str, results: list[CrackResult]) -> tuple[str, float]:
    cells, f1s = [], []
    for r in results:
        s = r.scores
        assert s is not None
        f1s.append(s.f1)
        cells.append(
            f"{s.precision:.2f} {s.recall:.2f} {s.f1:.2f} {s.length_error_m * 1000:4.0f} {s.width_error_m * 1000:6.0f}"
        )
    le = np.nanmean([r.scores.length_error_m for r in results]) * 1000  # type: ignore[union-attr]
    we = np.nanmean([r.scores.width_error_m for r in results]) * 1000  # type: ignore[union-attr]
    mean = float(np.mean(f1s))
    return f"{label:18s} | " + " | ".join(cells) + f" | {mean:.3f} {le:5.0f} {we:4.0f}", mean


_HEADER: Final = (
    "{:18s} | "
    + " | ".join(f"{n:^24s}" for n in OBJECTS)
    + " | mean F1 len wid\n"
    + " " * 18
    + " | "
    + " | ".join(["P    R    F1  len mm wid"] * 3)
)


def _finish_f1(fig: Any, ax: Any, name: str, xlabel: str, title: str) -> None:
    """Label the axes of an F1 plot, add the legend and write the figure to docs/NAME."""
    import matplotlib.pyplot as plt

    ax.set(xlabel=xlabel, ylabel="F1", title=title, ylim=(0, 1))
    ax.legend()
    fig.tight_layout()
    fig.savefig(DOCS / name, dpi=120)
    plt.close(fig)


def test_tables(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    cfg = CrackConfig()
    print(
        "\n\nTable 1 — every feature with the isolation forest (valley threshold, 2 cm smoothing keeping each "
        "point's own score, support clean-up, 3 cm growth)"
    )
    print(_HEADER.format("feature"))
    means: dict[str, float] = {}
    for feature in FeatureSet:
        results = [
            find_cracks(c, cfg, m, features=feature, detector=Detector.ISOLATION_FOREST) for c, m in elements.values()
        ]
        line, means[feature.value] = _row(feature.value, results)
        print(line + f"   published {PUBLISHED_FEATURE[feature.value]}")
    best = max(means, key=means.__getitem__)
    print(f"\nTable 2 — every detector on the best feature ({best})")
    print(_HEADER.format("detector"))
    for detector in Detector:
        results = [find_cracks(c, cfg, m, features=best, detector=detector) for c, m in elements.values()]
        line, _ = _row(detector.value, results)
        print(line + f"   published (CrackEmbed, columns) {PUBLISHED_DETECTOR[detector.value]}")
    print(
        "\nPublished per object (original, isolation forest on its embedding): "
        + ", ".join(f"{k} {v:.2f}" for k, v in PUBLISHED_OBJECT.items())
    )


def test_speed_on_the_90k_column(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    """Wall and CPU seconds of the whole crack assessment of the 90,000-point column (one thread). On a machine
    shared with other jobs the wall time says more about the load than about the method: the CPU time is the
    figure against the 5 s target."""
    cloud, mask = elements["column2"]
    for feature in (FeatureSet.SHADE_CRACKEMBED, FeatureSet.SHADE, FeatureSet.CRACKEMBED):
        t0, c0 = time.perf_counter(), time.process_time()
        result = find_cracks(cloud, CrackConfig(), mask, features=feature)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(
            f"\nspeed: column2 ({len(cloud)} points) with {feature.value}: {cpu:.2f} s CPU, {seconds:.2f} s wall "
            f"(load average {os.getloadavg()[0]:.1f}) {result.timings_s}"
        )
        assert cpu < 10


def test_plots(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    DOCS.mkdir(exist_ok=True)
    cfg = CrackConfig()
    spacings = [0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1]
    print("\nF1 against point spacing (grid):")
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, (cloud, mask) in elements.items():
        f1 = []
        for res in spacings:
            try:
                f1.append(find_cracks(cloud, cfg, mask, resolution_m=res, check_spacing=False).scores.f1)  # type: ignore[union-attr]
            except Exception as exc:  # too few points left at 10 cm
                print(f"  {name} at {res} m: {exc}")
                f1.append(np.nan)
        print(f"  {name}: " + " ".join(f"{r * 1000:g}mm {v:.2f}" for r, v in zip(spacings, f1, strict=True)))
        ax.plot(np.array(spacings) * 1000, f1, marker="o", label=name)
    ax.set_xscale("log")
    _finish_f1(fig, ax, "cracks_spacing.png", "grid spacing (mm)", "F1 against point spacing")

    print("\nF1 against the share of crack points (crack points dropped at random):")
    fig, ax = plt.subplots(figsize=(5, 3.5))
    shares = [0.03, 0.05, 0.075, 0.1, 0.125, 0.15]
    rng = np.random.default_rng(0)
    for name, (cloud, mask) in elements.items():
        f1 = []
        for share in shares:
            crack = np.flatnonzero(mask)
            need = int(share * (~mask).sum() / (1 - share))
            if need > len(crack):
                f1.append(np.nan)
                continue
            keep = np.sort(np.r_[np.flatnonzero(~mask), rng.choice(crack, need, replace=False)])
            f1.append(find_cracks(cloud.select(keep), cfg, mask[keep]).scores.f1)  # type: ignore[union-attr]
        print(f"  {name}: " + " ".join(f"{s:.3f} {v:.2f}" for s, v in zip(shares, f1, strict=True)))
        ax.plot(np.array(shares) * 100, f1, marker="o", label=name)
    _finish_f1(fig, ax, "cracks_share.png", "crack points (%)", "F1 against the share of crack points")

    from aftershock.sources.simulator.cracks import cracked_element

    print("\nF1 against crack width (unseen simulated elements, seeds 100+):")
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for kind in ("column", "wall", "slab"):
        widths, f1 = [], []
        for seed in range(100, 106):
            cloud, mask, truth = cracked_element(kind, seed, 0.004 if kind != "slab" else 0.008)
            widths.append(np.average([c.width_m for c in truth], weights=[c.length_m for c in truth]) * 1000)
            f1.append(find_cracks(cloud, cfg, mask).scores.f1)  # type: ignore[union-attr]
        print(f"  {kind}: " + " ".join(f"{w:.1f}mm {v:.2f}" for w, v in zip(widths, f1, strict=True)))
        ax.scatter(widths, f1, label=kind)
    _finish_f1(fig, ax, "cracks_width.png", "mean crack width of the element (mm)", "F1 against crack width")


def test_unseen_simulated_elements() -> None:
    """Elements never trained on (simulator seeds 100+; CrackEmbed trains on seeds below 100)."""
    from aftershock.sources.simulator.cracks import cracked_element

    print("\nUnseen simulated elements (F1, mean of seeds 100-104; width errors per true crack, median):")
    for feature in (FeatureSet.SHADE_CRACKEMBED, FeatureSet.SHADE, FeatureSet.CRACKEMBED):
        for kind in ("column", "wall", "slab"):
            f1, we, ws = [], [], []
            for seed in range(100, 105):
                cloud, mask, _ = cracked_element(kind, seed, 0.004 if kind != "slab" else 0.008)
                s = find_cracks(cloud, CrackConfig(), mask, features=feature).scores
                assert s is not None
                f1.append(s.f1)
                we.append(s.median_width_error_m)
                ws.append(s.study_width_error_m)
            print(
                f"  {feature.value:16s} {kind:6s} F1 {np.mean(f1):.3f} (min {np.min(f1):.2f}) "
                f"width error {np.nanmean(we) * 1000:.1f} mm (study's protocol: {np.nanmean(ws) * 1000:.1f} mm)"
            )


# Candidate settings for the default: every combination of the threshold rule and the depth test (off, or at
# the limit calibrated on simulated intact elements for that rule: `_calibrate_limit`); crack points are those of
# reported cracks. Chosen leave-one-object-out (below). Scan-edge suppression lost the previous leave-one-out
# (it cost column2 and slab2 up to 0.2 F1) and is no longer a candidate.
RULES: Final = {
    "valley": {"threshold": "valley", "null_sigmas": 0.0},
    "valley, null 1": {"threshold": "valley", "null_sigmas": 1.0},
    "null 3": {"threshold": "null", "null_sigmas": 3.0},
    "mixture": {"threshold": "mixture", "null_sigmas": 1.5, "mixture_separation": 2.0},
}
# CrackEmbed weights compared (label: path, None = the shipped file); `BENCH_CRACKEMBED=label=path,...` adds others
WEIGHTS: Final = {
    "shipped": None,
    **dict(w.split("=", 1) for w in os.environ.get("BENCH_CRACKEMBED", "").split(",") if "=" in w),
}
# `BENCH_NARROW=1` adds the face rule (`max_share`) and the narrowness test (with `min_area_elongation`) to the
# candidates: tried, the narrowness test cost slab2's left-out F1 (0.71 -> 0.27; README), so the default list
# leaves both out
NARROW: Final = os.environ.get("BENCH_NARROW", "") == "1"
# `BENCH_TINT=1` adds the hue test (`min_chroma_contrast`, damage/tint.py) to the candidates, its limit calibrated
# as the depth limit is (README: the real elements' false candidates are tinted as much as their cracks)
TINT: Final = os.environ.get("BENCH_TINT", "") == "1"
LEFT_OUT_F1_TARGET: Final = 0.65  # issue 13: left-out F1 on each real element
SIM_KINDS: Final = ("column", "wall", "slab", "beam")
INTACT_MAX: Final = 0.01  # at most 1 % of an intact element's points flagged
CALIBRATION_SEEDS: Final = (101, 102, 103)  # elements the depth limit and the narrowness test are calibrated on
# intact elements in the choice's merit (`BENCH_MERIT_SEEDS=100,104,105,106` adds others: tried, the slab2 fold
# then picks the depth test and scores 0.00; README)
MERIT_INTACT_SEEDS: Final = tuple(int(x) for x in os.environ.get("BENCH_MERIT_SEEDS", "100").split(","))
TEST_SEEDS: Final = tuple(range(110, 115))  # intact elements scored once, with the chosen default only
DEPTH_GRID: Final = tuple(np.round(np.arange(1.0, 8.01, 0.25), 2))
TINT_GRID: Final = tuple(np.round(np.arange(0.1, 5.01, 0.1), 2))  # min_chroma_contrast candidates, % chromaticity
SHARE_GRID: Final = (1.0, 0.5, 0.3, 0.2, 0.15, 0.1)  # max_share candidates, loosest first
ELONGATION_GRID: Final = (0.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)  # min_area_elongation candidates, loosest first
MAX_F1_LOSS: Final = 0.01  # the narrowness test may cost the simulated cracked calibration elements this much F1


def _flagged_at(result: CrackResult, limit: float, contrast: Callable[[Crack], float]) -> float:
    """Share of the points that would be flagged with a limit on each crack's `contrast` (its depth or hue
    contrast, from a run without the limit; a crack whose contrast is NaN, not judged, stays)."""
    kept = sum(c.num_points for c in result.cracks if not contrast(c) < limit)
    return kept / len(result.cloud)


def _calibrate_limit(intact: list[CrackResult], grid: tuple[float, ...], contrast: Callable[[Crack], float]) -> float:
    """The smallest limit on `grid` at which no simulated intact calibration element has more than `INTACT_MAX`
    of its points flagged (runs without the limit: each candidate's contrast is known), or the grid's end."""
    for limit in grid:
        if max(_flagged_at(r, limit, contrast) for r in intact) <= INTACT_MAX:
            return float(limit)
    return float(grid[-1])


def _depth(c: Crack) -> float:
    return c.depth_contrast


def _hue(c: Crack) -> float:
    return c.chroma_contrast


def _narrow_outcome(result: CrackResult, max_share: float, min_elongation: float) -> float:
    """F1 (an element with cracks) or share of points flagged (an intact one) had the narrowness test
    (`measure.keep_narrow`) been applied to a run without it; crack points are those of reported cracks."""
    n = len(result.cloud)
    keep = np.r_[
        False, [c.num_points <= max_share * n and c.length_m >= min_elongation * c.area_width_m for c in result.cracks]
    ]
    flagged = keep[result.crack_ids]
    truth = result.truth
    assert truth is not None
    if not truth.any():
        return float(flagged.mean())
    tp = float((flagged & truth).sum())
    return 2 * tp / max(float(flagged.sum() + truth.sum()), 1.0)


def _calibrate_narrow(
    cracked: list[CrackResult], intact: list[CrackResult], elongations: tuple[float, ...] = ELONGATION_GRID
) -> tuple[float, float]:
    """(max_share, min_area_elongation) on `SHARE_GRID` x `ELONGATION_GRID` that flags the fewest points of the
    simulated intact calibration elements while costing their cracked twins at most `MAX_F1_LOSS` mean F1 (runs
    without the test; the loosest pair wins a tie)."""
    base = np.mean([_narrow_outcome(r, 1.0, 0.0) for r in cracked])
    best, best_flag = (1.0, 0.0), np.inf
    for share in SHARE_GRID:
        for k in elongations:
            if base - np.mean([_narrow_outcome(r, share, k) for r in cracked]) > MAX_F1_LOSS:
                continue
            flag = float(np.mean([_narrow_outcome(r, share, k) for r in intact]))
            if flag < best_flag - 1e-12:
                best, best_flag = (share, k), flag
    return best


def _narrow_effect(
    intact: list[CrackResult], cracked: list[CrackResult], max_share: float, min_area_elongation: float
) -> str:
    """What the narrowness test does to the calibration elements: intact flagged and cracked F1, without -> with."""

    def mean(runs: list[CrackResult], share: float, k: float) -> float:
        return float(np.mean([_narrow_outcome(r, share, k) for r in runs]))

    return (
        f"calibration elements (seeds {CALIBRATION_SEEDS[0]}-{CALIBRATION_SEEDS[-1]}): intact flagged "
        f"{mean(intact, 1.0, 0.0) * 100:.2f} % -> {mean(intact, max_share, min_area_elongation) * 100:.2f} %, "
        f"cracked F1 {mean(cracked, 1.0, 0.0):.3f} -> {mean(cracked, max_share, min_area_elongation):.3f}"
    )


def _choose(table: dict[str, dict[str, dict[str, float]]], reals: list[str], sims: list[str], intact: list[str]) -> str:
    """The setting with the best mean F1 (the given real elements and the simulated cracked ones weighing half
    each) less the mean share of the intact simulated elements' points it flags and the share by which it
    flags more than 1 % of the given real elements' points far from their cracks: a point flagged on sound
    concrete costs as much as a point of F1 (first listed wins a tie)."""

    def merit(label: str) -> float:
        row = table[label]
        f1 = 0.5 * np.mean([row[n]["f1"] for n in sims]) + 0.5 * np.mean([row[n]["f1"] for n in reals])
        flagged = float(np.mean([row[n]["flag"] for n in intact]))
        over = float(np.mean([max(row[n]["far"] - INTACT_MAX, 0.0) for n in reals]))
        return float(f1 - flagged - over)

    return max(table, key=merit)


def test_leave_one_object_out(
    elements: dict[str, tuple[LabelledCloud, np.ndarray]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every crack setting chosen with the element it is reported on left out: for each real element, the
    setting that is best on the other two and on simulated elements (cracked: seed 100 of each kind, which
    CrackEmbed never trained on; intact: `MERIT_INTACT_SEEDS`), then scored once on the left-out element. The
    depth limit of each rule is calibrated on other simulated intact elements (seeds 101-103); with
    `BENCH_NARROW=1` the face rule (`max_share`) and the narrowness test (`max_share`, `min_area_elongation`)
    are calibrated on those and their cracked twins and join the candidates. The chosen default is then scored
    once on intact elements never used (seeds 110-114). The in-sample choice (all three) must be the shipped
    default. Features and detector scores are computed once per element and weights."""
    import hashlib

    import aftershock.pipeline.damage.report as report
    from aftershock.sources.simulator.cracks import cracked_element

    cache: dict[tuple, np.ndarray] = {}
    compute, run_detector = report.compute_features, report.detect

    def digest(a: np.ndarray) -> str:
        return hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()

    def cached_features(cloud: LabelledCloud, features: FeatureSet | str, cfg: CrackConfig) -> np.ndarray:
        key = ("f", str(features), cfg.shade_cell_m, cfg.weights, digest(cloud.points))
        if key not in cache:
            cache[key] = compute(cloud, features, cfg)
        return cache[key]

    def cached_detect(x: np.ndarray, detector: Detector | str, **kw: object):  # type: ignore[no-untyped-def]
        key = ("d", str(detector), digest(x))
        if key not in cache:
            cache[key] = run_detector(x, detector, **kw)  # type: ignore[arg-type]
        return cache[key]

    monkeypatch.setattr(report, "compute_features", cached_features)
    monkeypatch.setattr(report, "detect", cached_detect)

    def sim(kind: str, seed: int, intact: bool) -> tuple[LabelledCloud, np.ndarray]:
        cloud, mask, _ = cracked_element(kind, seed, sim_spacing(kind), intact=intact)
        return cloud, mask

    objects = dict(elements)
    for kind in SIM_KINDS:
        objects[f"{kind}-cracked"] = sim(kind, 100, False)
        for seed in MERIT_INTACT_SEEDS:
            objects[f"{kind}-intact-{seed}"] = sim(kind, seed, True)
    calibration = [sim(kind, seed, True) for kind in SIM_KINDS for seed in CALIBRATION_SEEDS]
    calibration_cracked = [sim(kind, seed, False) for kind in SIM_KINDS for seed in CALIBRATION_SEEDS] if NARROW else []
    reals = list(OBJECTS)
    sims = [f"{k}-cracked" for k in SIM_KINDS]
    intact = [f"{k}-intact-{seed}" for k in SIM_KINDS for seed in MERIT_INTACT_SEEDS]
    settings: dict[str, dict[str, object]] = {}
    off = {"max_share": 1.0, "min_area_elongation": 0.0, "min_chroma_contrast": 0.0}
    for rule, over in RULES.items():
        for wname, weights in WEIGHTS.items():
            base = {**over, "edge_spacings": 0.0, "cracks_only": True, "weights": weights}
            intact_runs = [find_cracks(c, CrackConfig(**base), m) for c, m in calibration]
            limit = _calibrate_limit(intact_runs, DEPTH_GRID, _depth)
            tag = "" if len(WEIGHTS) == 1 else f", {wname} CrackEmbed"
            settings[f"{rule}, no depth test{tag}"] = {**base, "depth_sigmas": 0.0, **off}
            settings[f"{rule}, depth >= {limit:g} sigma{tag}"] = {**base, "depth_sigmas": limit, **off}
            if TINT:
                hue = _calibrate_limit(intact_runs, TINT_GRID, _hue)
                settings[f"{rule}, no depth test, hue >= {hue:g} %{tag}"] = {
                    **base,
                    **off,
                    "depth_sigmas": 0.0,
                    "min_chroma_contrast": hue,
                }
            if not NARROW:
                continue
            cracked_runs = [find_cracks(c, CrackConfig(**base), m) for c, m in calibration_cracked]
            face, _ = _calibrate_narrow(cracked_runs, intact_runs, (0.0,))  # the face rule alone
            share, k = _calibrate_narrow(cracked_runs, intact_runs)
            for test, narrow in (
                (f"share <= {face:g}", {"max_share": face, "min_area_elongation": 0.0}),
                (f"share <= {share:g}, elongation >= {k:g}", {"max_share": share, "min_area_elongation": k}),
            ):
                print(f"  {rule}{tag}: {test} — " + _narrow_effect(intact_runs, cracked_runs, **narrow))
                settings[f"{rule}, no depth test, {test}{tag}"] = {**base, "depth_sigmas": 0.0, **narrow}
                settings[f"{rule}, depth >= {limit:g} sigma, {test}{tag}"] = {**base, "depth_sigmas": limit, **narrow}
    table: dict[str, dict[str, dict[str, float]]] = {}
    for label, override in settings.items():
        cfg = CrackConfig(**override)
        row: dict[str, dict[str, float]] = {}
        for name, (cloud, mask) in objects.items():
            r = find_cracks(cloud, cfg, mask)
            s = r.scores
            row[name] = {
                "flag": float(r.mask.mean()),
                "far": far_share(r.cloud.points, r.truth, r.mask),  # type: ignore[arg-type]
                "f1": s.f1 if s is not None and r.truth.any() else float("nan"),  # type: ignore[union-attr]
                "width": s.width_error_m if s is not None and r.truth.any() else float("nan"),  # type: ignore[union-attr]
            }
        table[label] = row
    print("\nEvery setting: real elements F1 / flagged far (>10 cm) from true cracks / main-crack width error mm;")
    print(
        "simulated cracked (seed 100 of each kind) F1; simulated intact (seeds "
        + ", ".join(map(str, MERIT_INTACT_SEEDS))
        + " of each kind) flagged (mean / worst)"
    )
    for label, row in table.items():
        print(
            f"  {label:82s} "
            + "  ".join(f"{row[n]['f1']:.2f}/{row[n]['far'] * 100:4.1f}%/{row[n]['width'] * 1000:4.1f}" for n in reals)
            + f" | sim {np.mean([row[n]['f1'] for n in sims]):.3f} | intact "
            + f"{np.mean([row[n]['flag'] for n in intact]) * 100:.2f}%/"
            + f"{np.max([row[n]['flag'] for n in intact]) * 100:.2f}%"
        )
    print("\nLeave one object out (setting chosen without the element; F1 in-sample = the shipped default's):")
    chosen_all = _choose(table, reals, sims, intact)
    left_out: dict[str, float] = {}
    for held in reals:
        label = _choose(table, [n for n in reals if n != held], sims, intact)
        r, a = table[label][held], table[chosen_all][held]
        left_out[held] = r["f1"]
        print(
            f"  {held:8s} left-out F1 {r['f1']:.3f} (width error {r['width'] * 1000:.1f} mm, far flagged "
            f"{r['far'] * 100:.1f} %) with [{label}]; in-sample {a['f1']:.3f}; published {PUBLISHED_OBJECT[held]:.2f}"
        )
    print(f"  in-sample choice: [{chosen_all}]")
    cfg = CrackConfig(**settings[chosen_all])
    held_out: dict[str, list[float]] = {kind: [] for kind in SIM_KINDS}
    for kind in SIM_KINDS:
        for seed in TEST_SEEDS:
            cloud, mask = sim(kind, seed, True)
            held_out[kind].append(float(find_cracks(cloud, cfg, mask).mask.mean()))
    print(
        f"  chosen setting on intact elements never used (seeds {TEST_SEEDS[0]}-{TEST_SEEDS[-1]}), flagged: "
        + ", ".join(f"{k} {np.mean(v) * 100:.2f} % (worst {np.max(v) * 100:.2f} %)" for k, v in held_out.items())
        + f"; all {np.mean(list(held_out.values())) * 100:.2f} %"
    )
    default = CrackConfig()
    worst = min(left_out, key=lambda n: left_out[n])
    if TINT and settings[chosen_all].get("min_chroma_contrast", 0.0) > 0 and left_out[worst] < LEFT_OUT_F1_TARGET:
        # round T's rule (README): the hue test ships only if no real element's left-out F1 falls under the target
        print(f"  the choice has the hue test and {worst} left out scores {left_out[worst]:.2f}: the default has none")
        return
    assert {k: getattr(default, k) for k in settings[chosen_all]} == settings[chosen_all], "default is not the choice"


def test_score_contrast_real_against_simulated(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    """How faint the cracks are to the detector: the median score of the true crack points above the median of
    all, in robust standard deviations (shipped features and detector, before any threshold), on the real elements
    and on unseen simulated ones (seeds 100-101). The simulator's cracks should be about as faint as the real ones."""
    from aftershock.pipeline.damage.detectors import detect, robust_sigma
    from aftershock.pipeline.damage.features import compute_features
    from aftershock.pipeline.damage.report import carry_mask, default_resolution
    from aftershock.pipeline.geometry import voxel_downsample
    from aftershock.sources.simulator.cracks import cracked_element

    cfg = CrackConfig()

    def contrast(cloud: LabelledCloud, mask: np.ndarray) -> float:
        keep, voxel_of = voxel_downsample(cloud.points, default_resolution(cloud.points))
        part, truth = cloud.select(keep), carry_mask(mask, voxel_of, len(keep))
        score = detect(compute_features(part, cfg.features, cfg), cfg.detector, seed=cfg.seed).score
        return float((np.median(score[truth]) - np.median(score)) / robust_sigma(score))

    print("\nCrack points' score above the bulk (robust sigmas, median over the true crack points):")
    print("  real: " + ", ".join(f"{n} {contrast(c, m):.1f}" for n, (c, m) in elements.items()))
    for kind in SIM_KINDS:
        z = [contrast(*cracked_element(kind, seed, sim_spacing(kind))[:2]) for seed in (100, 101)]
        print(f"  simulated {kind}: " + ", ".join(f"{v:.1f}" for v in z))


def test_depth_of_true_crack_points(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    """Do the scans resolve the cracks' depth? The true crack points' depth behind the surface of the other points
    around them (`recess.depth_z`, the evaluation grid, local noise units; median and 90th percentile) against the
    sound points', on the real elements and on simulated ones (seeds 100-101)."""
    from aftershock.pipeline.damage.recess import depth_z
    from aftershock.pipeline.damage.report import carry_mask, default_resolution
    from aftershock.pipeline.geometry import voxel_downsample
    from aftershock.sources.simulator.cracks import cracked_element

    cfg = CrackConfig()

    def depth(cloud: LabelledCloud, mask: np.ndarray) -> str:
        keep, voxel_of = voxel_downsample(cloud.points, default_resolution(cloud.points))
        truth = carry_mask(mask, voxel_of, len(keep))
        z = depth_z(cloud.points[keep], truth, cfg.depth_cell_m)
        crack, sound = np.percentile(z[truth], [50, 90]), np.percentile(z[~truth], [50, 90])
        return f"crack {crack[0]:.1f} / {crack[1]:.1f}, sound {sound[0]:.2f} / {sound[1]:.2f}"

    print("\nDepth behind the surface around (local noise units, median / 90th percentile):")
    for name, (cloud, mask) in elements.items():
        print(f"  {name:9s} {depth(cloud, mask)}")
    for kind in SIM_KINDS:
        for seed in (100, 101):
            cloud, mask, _ = cracked_element(kind, seed, sim_spacing(kind))
            print(f"  {kind}-{seed:<4d} {depth(cloud, mask)}")


def _crack_owner(points: np.ndarray, truth: list[CrackTruth]) -> np.ndarray:
    """Index into `truth` of the simulated crack whose centre line is nearest each of `points`."""
    from scipy.spatial import cKDTree

    t = np.linspace(0.0, 1.0, 400)
    lines = [
        np.stack([np.interp(t, np.linspace(0, 1, len(c.polyline)), c.polyline[:, i]) for i in range(3)], 1)
        for c in truth
    ]
    return np.repeat(np.arange(len(truth)), 400)[cKDTree(np.concatenate(lines)).query(points)[1]]


def _simulated_matches(
    result: CrackResult, mask: np.ndarray, truth: list[CrackTruth]
) -> list[tuple[float, float, float, float]]:
    """Each simulated crack (its marked points: those nearest its centre line) against the reported crack
    holding most of them (a third at least): (true length, true width, measured length, measured width),
    NaN when not found. The true width is the simulator's mean opening, clamped to the spacing."""
    idx = np.flatnonzero(mask)
    owner = _crack_owner(result.cloud.points[idx], truth)
    out = []
    for k, c in enumerate(truth):
        ids = result.crack_ids[idx[owner == k]]
        if len(ids) < 20:
            continue
        count = np.bincount(ids, minlength=len(result.cracks) + 1)
        count[0] = 0
        best = int(np.argmax(count))
        found = best > 0 and 3 * count[best] >= len(ids)
        r = result.cracks[best - 1] if found else None
        nan = float("nan")
        out.append((c.length_m, max(c.width_m, result.spacing_m), r.length_m if r else nan, r.width_m if r else nan))
    return out


def test_width_estimator_on_simulated_truth(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    """The opening-width estimator alone, without detection: each simulated crack's own marked points (seeds
    100-104, 4 mm spacing, slabs 8 mm) measured as a reported crack is (`crack_shape` on the surface around it)
    against the simulator's mean opening (clamped to the spacing); and each real element's main true crack
    measured on its truth mask against the reported crack holding it. Separates what the estimator gets wrong
    from what detection gets wrong (the main-crack width errors of the tables are both together)."""
    from scipy.spatial import cKDTree

    from aftershock.pipeline.damage.measure import crack_shape, surface_around
    from aftershock.sources.simulator.cracks import cracked_element

    cfg = CrackConfig()
    print("\nWidth estimator on the true crack points (no detection): measured - true opening, mm")
    for kind in SIM_KINDS:
        err, true_w = [], []
        for seed in range(100, 105):
            cloud, mask, truth = cracked_element(kind, seed, 0.004 if kind != "slab" else 0.008)
            result = find_cracks(cloud, cfg, mask)  # the evaluated cloud, its spacing and carried mask
            pts, h = result.cloud.points, result.spacing_m
            idx = np.flatnonzero(result.truth)
            owner = _crack_owner(pts[idx], truth)
            tree = cKDTree(pts)
            link = max(cfg.link_m, cfg.link_spacings * h)
            for k, c in enumerate(truth):
                own = idx[owner == k]
                if len(own) < cfg.min_crack_points:
                    continue
                shape = crack_shape(pts[own], h, link, surface_around(tree, pts, own, max(0.02, 2 * link)))
                err.append(max(shape.width, h) - max(c.width_m, h))
                true_w.append(max(c.width_m, h))
        e = np.array(err) * 1000
        print(
            f"  simulated {kind:6s} {len(e)} cracks, true opening median {np.median(true_w) * 1000:.1f} mm: "
            f"error median {np.median(np.abs(e)):.1f} mm, bias {np.median(e):+.1f} mm, "
            f"within 3 mm {np.mean(np.abs(e) <= 3) * 100:.0f} %"
        )
    for name in ("column1", "column2"):
        cloud, mask = elements[name]
        s = find_cracks(cloud, cfg, mask).scores
        assert s is not None
        print(
            f"  real {name}: main true crack {s.true_width_m * 1000:.1f} mm on its truth mask, the reported crack "
            f"holding it {s.found_width_m * 1000:.1f} mm (recall {s.recall:.2f}, precision {s.precision:.2f})"
        )


def test_per_crack_sizes(elements: dict[str, tuple[LabelledCloud, np.ndarray]]) -> None:
    """What a field team reads: every reported crack's length and width against the truth, on the real
    elements and on unseen simulated ones (seeds 100-104). Real truth: each connected group of the truth
    mask, linked and measured as the reported cracks are. Simulated truth: the simulator's own crack
    lengths and mean openings (crossing cracks merge into one reported crack: their length error is large)."""
    from aftershock.sources.simulator.cracks import cracked_element

    cfg = CrackConfig()
    print("\nPer crack (widths are openings; errors |measured - true|, median over true cracks found):")
    print(f"  {'element':10s} {'F1':>5s} {'found':>7s} {'main len/wid err mm':>20s} {'median len/wid err mm':>22s}")
    for name, (cloud, mask) in elements.items():
        s = find_cracks(cloud, cfg, mask).scores
        assert s is not None
        print(
            f"  {name:10s} {s.f1:5.3f} {s.found_cracks:3d}/{s.true_cracks:<3d} "
            f"{s.length_error_m * 1000:9.0f} {s.width_error_m * 1000:9.1f} "
            f"{s.median_length_error_m * 1000:10.0f} {s.median_width_error_m * 1000:10.1f}"
            f"   (study's protocol {s.study_length_error_m * 1000:.0f} / {s.study_width_error_m * 1000:.1f}; "
            f"{s.true_blobs} true blobs left out)"
        )
        for m in s.matches[:8]:
            print(
                f"      true {m.true_length_m:6.3f} m x {m.true_width_m * 1000:5.1f} mm -> "
                f"crack {m.crack_id:2d}: {m.length_m:6.3f} m x {m.width_m * 1000:5.1f} mm"
            )
    for kind in ("column", "wall", "slab"):
        rows, f1 = [], []
        for seed in range(100, 105):
            cloud, mask, truth = cracked_element(kind, seed, 0.004 if kind != "slab" else 0.008)
            result = find_cracks(cloud, cfg, mask)
            f1.append(result.scores.f1)  # type: ignore[union-attr]
            rows += _simulated_matches(result, result.truth, truth)  # type: ignore[arg-type]
        a = np.array(rows)
        ok = np.isfinite(a[:, 2])
        dl, dw = np.abs(a[ok, 2] - a[ok, 0]), np.abs(a[ok, 3] - a[ok, 1])
        print(
            f"  {kind:6s} seeds 100-104: F1 {np.mean(f1):.3f}; {ok.sum()} of {len(a)} simulated cracks found; "
            f"length error median {np.median(dl) * 1000:.0f} mm, width error median {np.median(dw) * 1000:.1f} mm "
            f"(within 4 mm: {np.mean(dw <= 0.004) * 100:.0f} %), true width {np.median(a[:, 1]) * 1000:.1f} mm median"
        )


def test_drift_on_simulated_buildings() -> None:
    """Drift and tilt of every level of damaged simulated buildings against the truth, at static-scan
    spacings; target ≤ 2 mm and ≤ 0.05°."""
    from aftershock.pipeline.damage.drift import measure_drift
    from aftershock.sources.simulator.building import build_scene

    worst_tilt, worst_drift = 0.0, 0.0
    for spacing, seeds in ((0.05, (1, 2, 3, 4, 5)), (0.03, (1, 2, 3))):
        print(f"\nStory drift and tilt on simulated damaged buildings (static scan, {spacing * 100:.0f} cm spacing):")
        for seed in seeds:
            scene = build_scene("disaster", seed)
            cloud = scene.sample_static_cloud(spacing, seed=0)
            t0 = time.perf_counter()
            result = measure_drift(cloud.points, DriftConfig())
            took = time.perf_counter() - t0
            levels = scene.truth.levels
            print(
                f"  building {seed}: {len(cloud.points)} points, {len(result.stories)} slabs found, "
                f"{len(levels)} levels, {took:.1f} s"
            )
            assert len(result.stories) == len(levels)
            for story, level in zip(result.stories, levels, strict=True):
                dt = max(abs(story.tilt_x_deg - level.tilt_x_deg), abs(story.tilt_y_deg - level.tilt_y_deg))
                dd = float(np.hypot(story.drift_x_mm - level.drift_x_mm, story.drift_y_mm - level.drift_y_mm))
                worst_tilt, worst_drift = max(worst_tilt, dt), max(worst_drift, dd)
                print(
                    f"    level {level.index}: drift {story.drift_x_mm:+7.1f} {story.drift_y_mm:+7.1f} mm "
                    f"(truth {level.drift_x_mm:+7.1f} {level.drift_y_mm:+7.1f}, error {dd:.2f}), tilt "
                    f"{story.tilt_x_deg:+.3f} {story.tilt_y_deg:+.3f}° (truth {level.tilt_x_deg:+.3f} "
                    f"{level.tilt_y_deg:+.3f})"
                )
    print(f"  worst tilt error {worst_tilt:.4f}°, worst drift error {worst_drift:.2f} mm")
    assert worst_tilt <= 0.05 and worst_drift <= 2.0


# Drift settings are chosen on these layouts only; the others are reported, never used for a choice.
DRIFT_CHOICE: Final = {"column-grid": (1, 2, 3, 4), "walls-openings": (1, 2, 3, 4)}
DRIFT_REPORT: Final = {"partial-collapse": (1, 2, 3, 4), "missing-slab": (1, 2, 3, 4)}


def test_drift_on_frames_of_other_layouts() -> None:
    """Story drift and tilt on frames built another way than the simulator's buildings (`simulator.frames`:
    column grids without walls, walls with openings, partial collapse, missing slab parts; 2-5 mm range noise
    along the line of sight, occluders), 7 cm spacing. Settings were chosen on the first two layouts only;
    the last two were never used for a choice. Targets: drift ≤ 2 mm, tilt ≤ 0.02°."""
    from aftershock.pipeline.damage.drift import measure_drift
    from aftershock.sources.simulator.frames import drift_frame

    for role, layouts in (("chosen on", DRIFT_CHOICE), ("never used to choose", DRIFT_REPORT)):
        print(f"\nDrift and tilt on frames, layouts {role}:")
        for layout, seeds in layouts.items():
            drift_err, tilt_err, missed = [], [], 0
            for seed in seeds:
                frame = drift_frame(layout, seed, 0.07)
                result = measure_drift(frame.points, DriftConfig())
                if len(result.stories) != len(frame.levels):
                    missed += 1
                    continue
                for story, level in zip(result.stories, frame.levels, strict=True):
                    drift_err.append(np.hypot(story.drift_x_mm - level.drift_x_mm, story.drift_y_mm - level.drift_y_mm))
                    tilt_err.append(
                        max(abs(story.tilt_x_deg - level.tilt_x_deg), abs(story.tilt_y_deg - level.tilt_y_deg))
                    )
            print(
                f"  {layout:16s} {len(seeds)} frames, {len(drift_err)} levels: drift error median "
                f"{np.median(drift_err):.2f} mm, worst {np.max(drift_err):.2f} mm; tilt error worst "
                f"{np.max(tilt_err):.4f}°; frames whose levels were not all found: {missed}"
            )
