"""What the crack benchmarks share (bench_cracks, bench_cracks_ridge, bench_cracks_region): the published figures
beside ours, the cloud find_cracks evaluates, F1, the share of crack-free points flagged, one table row."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Final

import numpy as np

from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.damage.report import CrackResult, carry_mask, default_resolution, find_cracks
from aftershock.pipeline.geometry import point_spacing, voxel_downsample
from aftershock.pipeline.types import LabelledCloud

FAR_M: Final = 0.10  # a point this far from every true crack point is crack-free
Elements = dict[str, tuple[LabelledCloud, np.ndarray]]  # name -> (cloud, true crack mask)


PUBLISHED: Final = {
    "column1": "F1 .55 (raw RGB .32)",
    "column2": "F1 .67 (raw RGB .51)",
    "slab2": "F1 ~.75 (raw RGB ~.62)",
    "column4": "F1 .26 (raw RGB .22)",
}
PUBLISHED_WIDTH: Final = "width error 4 mm (study, mean of its elements)"


def sim_spacing(kind: str) -> float:
    return 0.008 if kind == "slab" else 0.003


def evaluated_cloud(cloud: LabelledCloud, truth: np.ndarray) -> tuple[LabelledCloud, np.ndarray, float]:
    """The cloud find_cracks evaluates (one point per grid voxel), its carried truth and its spacing."""
    keep, voxel_of = voxel_downsample(cloud.points, default_resolution(cloud.points))
    part = cloud.select(keep)
    return part, carry_mask(truth, voxel_of, len(keep)), point_spacing(part.points)


def f1_score(pred: np.ndarray, truth: np.ndarray) -> float:
    tp = float(np.sum(pred & truth))
    return 2 * tp / max(float(pred.sum() + truth.sum()), 1.0)


def far_share(points: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    far = np.ones(len(points), bool)
    if truth.any():
        dist, _ = cKDTree(points[truth]).query(points, k=1, distance_upper_bound=FAR_M, workers=-1)
        far = ~np.isfinite(dist)
    return float(mask[far].mean()) if far.any() else float("nan")


def crack_row(label: str, r: CrackResult, published: str) -> str:
    s = r.scores
    assert s is not None and r.truth is not None
    far = far_share(r.cloud.points, r.truth, r.mask)
    le = "n/a" if not np.isfinite(s.length_error_m) else f"{s.length_error_m * 1000:.0f}"
    we = "n/a" if not np.isfinite(s.width_error_m) else f"{s.width_error_m * 1000:.1f}"
    return (
        f"  {label:8s} F1 {s.f1:.3f} (P {s.precision:.2f} R {s.recall:.2f})  crack-free flagged {far * 100:5.2f} %  "
        f"main crack length error {le} mm, width error {we} mm  | published {published}"
    )


def old_default(cloud: LabelledCloud, mask: np.ndarray) -> CrackResult:
    """The detector the new ones must beat: shade+crackembed features with the isolation forest."""
    return find_cracks(cloud, CrackConfig(), mask, detector="isolation-forest", features="shade+crackembed")


def print_leave_one_out(
    names: tuple[str, ...],
    real: Elements,
    choose: Callable[[tuple[str, ...]], str],
    cfg_of: Callable[[str], CrackConfig],
    shown: Callable[[str], str] = str,
) -> dict[str, CrackResult]:
    """Each element scored with the candidate `choose` picks on the others (`cfg_of` gives its settings, `shown`
    how its row names it), a row each, then the published width error."""
    loo: dict[str, CrackResult] = {}
    for el in names:
        pick = choose(tuple(o for o in names if o != el))
        cloud, mask = real[el]
        loo[el] = find_cracks(cloud, cfg_of(pick), mask)
        print(crack_row(el, loo[el], PUBLISHED[el]) + f"  [{shown(pick)}]")
    print(f"  published width: {PUBLISHED_WIDTH}")
    return loo


def print_old_default(names: tuple[str, ...], real: Elements) -> dict[str, CrackResult]:
    """The old default on the same elements, a row each."""
    print("\nOld default (shade+crackembed, isolation forest), same elements, same run:")
    old: dict[str, CrackResult] = {}
    for el in names:
        cloud, mask = real[el]
        old[el] = old_default(cloud, mask)
        print(crack_row(el, old[el], PUBLISHED[el]))
    return old


def print_simulated_f1(cfg: CrackConfig, kinds: tuple[str, ...], seeds: tuple[int, ...] = (310, 311, 312)) -> None:
    """F1 on simulated cracked elements (with site marks) of seeds never used for a choice, one line per kind."""
    from aftershock.sources.simulator.cracks import cracked_element

    for kind in kinds:
        f = []
        for seed in seeds:
            cloud, mask, _ = cracked_element(kind, seed, sim_spacing(kind), marks=True)
            f.append(find_cracks(cloud, cfg, mask).scores.f1)  # type: ignore[union-attr]
        print(f"  {kind:6s} F1 " + " ".join(f"{v:.2f}" for v in f))


def print_speed_against_old_default(
    name: str, cloud: LabelledCloud, mask: np.ndarray, cfg: CrackConfig, t_start: float
) -> None:
    """Seconds of `cfg` (detector `name`) and of the old default on one element, and the whole benchmark's."""
    t0 = time.perf_counter()
    find_cracks(cloud, cfg, mask)
    new_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    old_default(cloud, mask)
    old_s = time.perf_counter() - t0
    print(
        f"\nSpeed on column2 ({len(cloud)} points): {name} {new_s:.2f} s, old default {old_s:.2f} s "
        f"(ratio {new_s / old_s:.2f}) on this shared machine; whole benchmark {time.perf_counter() - t_start:.0f} s"
    )


def usable_candidates(
    detector: str, setting: str, highs: dict[str, float | None], elements: int, most: float
) -> list[str]:
    """Print each candidate's seed score calibrated on `elements` simulated intact elements (at most `most` of
    their points flagged) and return the candidates that met it."""
    print(
        f"\n\n#30 {detector}. Seed score calibrated on simulated intact elements (with marks), "
        f"{elements} elements, at most {most * 100:.1f} % flagged:"
    )
    width = max((len(n) for n in highs), default=0)
    for name, h in highs.items():
        print(f"  {name:{width}s} {setting} {h if h is not None else 'none on the grid'}")
    usable = [n for n, h in highs.items() if h is not None]
    assert usable, "no candidate meets the intact calibration"
    return usable
