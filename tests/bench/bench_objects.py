"""Objects, not fragments: MCPNet's online clustering on held-out simulated missions, as the user sees it.

    make bench-objects      # pytest -m slow -s tests/bench/bench_objects.py

Per held-out mission (office and disaster, seeds 900/901, VLP-16, 150 scans; never used to choose a
setting): the true objects in the map, the objects shown (at least `cluster.min_object_voxels`), the
fragments before the small ones were hidden, instance precision / recall / mean IoU at IoU 0.5, NMI, ARI
and the class scores -- once with KISS-ICP's poses and once with the log's true poses (`eval --poses
truth`), so what registration costs can be told from what labelling and clustering cost.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Final

import numpy as np
import pytest
from common import stream_labeller

pytestmark = pytest.mark.timeout(7200)
# OBJECTS_BENCH_POSES=truth runs only one of the two pose sources.
POSES: Final = tuple(p for p in os.environ.get("OBJECTS_BENCH_POSES", "estimated,truth").split(",") if p)


def _row(name: str, r: dict[str, Any]) -> str:
    return (
        f"| {name} | {r['true_instances']} | {r['predicted_instances']} | {r['fragments']} | "
        f"{r['predicted_instances'] / max(r['true_instances'], 1):.2f} | {r['precision']:.3f} | {r['recall']:.3f} | "
        f"{r['instance_mean_iou']:.3f} | {r['nmi'] * 100:.1f} | {r['ari'] * 100:.1f} | "
        f"{r['overall_accuracy'] * 100:.1f} | {r['mean_iou'] * 100:.1f} | {r['timings']['cluster']:.1f} |"
    )


def test_objects_on_held_out_missions(heldout_missions: list[Path]) -> None:
    print(
        "\n| mission (poses) | true | shown | fragments | shown/true | precision | recall | inst. mIoU | NMI | ARI | "
        "OA | mIoU | cluster ms/scan |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    means: dict[str, dict[str, float]] = {}
    for poses in POSES:
        reps = [stream_labeller(m, "mcpnet", [f"registration.poses={poses}"]) for m in heldout_missions]
        for m, r in zip(heldout_missions, reps, strict=True):
            print(_row(f"{m.stem} ({poses})", r))
        mean = {k: float(np.mean([r[k] for r in reps])) for k in ("precision", "recall", "nmi", "ari")}
        mean["ratio"] = float(np.mean([r["predicted_instances"] / max(r["true_instances"], 1) for r in reps]))
        means[poses] = mean
        print(
            f"| **mean ({poses})** | | | | {mean['ratio']:.2f} | {mean['precision']:.3f} | {mean['recall']:.3f} | | "
            f"{mean['nmi'] * 100:.1f} | {mean['ari'] * 100:.1f} | | | |"
        )
    if "estimated" not in means:
        return
    m = means["estimated"]
    checks = {
        "objects shown <= 2x true": m["ratio"] <= 2.0,
        "precision >= 0.5": m["precision"] >= 0.5,
        "recall >= 0.6": m["recall"] >= 0.6,
    }
    print("\ntargets (KISS-ICP poses, mean over the held-out missions):")
    for name, ok in checks.items():
        print(f"  {'met ' if ok else 'MISSED'} {name}")
    # A report, not a gate; it fails only when objects are shown in fragments as before (≈ 20x the truth).
    assert m["ratio"] < 5.0
