"""What the crack detectors' benchmarks share (bench_cracks_ridge, bench_cracks_region): the published figures
beside ours, the cloud find_cracks evaluates, F1, the share of crack-free points flagged, one table row."""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.damage.report import CrackResult, carry_mask, default_resolution
from aftershock.pipeline.geometry import point_spacing, voxel_downsample
from aftershock.pipeline.types import LabelledCloud

FAR_M: Final = 0.10  # a point this far from every true crack point is crack-free


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
