"""`aftershock eval SOURCE`: run the stream on a log with ground truth and score it.

Scores are computed on the points of the voxel map (one stored point per voxel, with the true class and
instance of that point): overall and mean accuracy, per-class and mean IoU, NMI, AMI, ARI, and instance
precision/recall/mIoU at IoU 0.5 with one-to-one matching (see `pipeline.metrics`); plus the trajectory
error against the true poses and the time per stage.
"""

from __future__ import annotations

import itertools
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Final

import numpy as np
import typer

from aftershock.pipeline.commands import CONFIG, END, EVERY, LABELLER, MAX_SCANS, OVERRIDES, START, TOPIC
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.labellers.oracle import ORACLES
from aftershock.pipeline.mission import build_config, open_scans
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.types import Scan
from aftershock.pipeline.voxel_map import VoxelMap

POSES: Final = ("estimated", "truth")


def evaluate_map(vmap: VoxelMap) -> dict[str, Any]:
    """Scores of the map's predictions against the true labels of its stored points."""
    # Imported here: scikit-learn costs every command ~2 s of start-up otherwise (the CLI imports them all).
    from aftershock.pipeline.metrics import cluster_scores, instance_scores, semantic_scores

    if not vmap.has_truth:
        raise InputError("the log carries no ground truth (class_id / instance_id point fields)")
    known = vmap.true_class_ids != np.iinfo(np.uint16).max
    pred_cls, true_cls = vmap.class_ids[known], vmap.true_class_ids[known]
    pred_inst, true_inst = vmap.instance_ids[known], vmap.true_instance_ids[known]
    sem = semantic_scores(true_cls, pred_cls)
    clu = cluster_scores(true_inst, pred_inst)
    ins = instance_scores(true_inst, pred_inst)
    return {
        "overall_accuracy": sem.overall_accuracy,
        "mean_accuracy": sem.mean_accuracy,
        "mean_iou": sem.mean_iou,
        "per_class_iou": sem.per_class_iou,
        "per_class_accuracy": sem.per_class_accuracy,
        "confusion": sem.confusion,
        "nmi": clu.nmi,
        "ami": clu.ami,
        "ari": clu.ari,
        "precision": ins.precision,
        "recall": ins.recall,
        "instance_mean_iou": ins.mean_iou,
        "true_instances": ins.true_instances,
        "predicted_instances": ins.predicted_instances,
        "evaluated_points": int(known.sum()),
    }


def require_truth(scans: Iterator[Scan], source: str, poses: bool = False) -> Iterator[Scan]:
    """The scans, after checking that the first one carries true labels (and, with `poses`, a true pose), so a
    log without them fails at once."""
    first = next(scans, None)
    if first is None:
        raise InputError("no scans", source)
    if not first.has_ground_truth:
        raise InputError("the log carries no ground truth (class_id / instance_id point fields)", source)
    if poses and first.gt_pose is None:
        raise InputError("the log carries no true poses for --poses truth; use --poses estimated", source)
    return itertools.chain([first], scans)


def report(result: StreamResult, poses: str = "estimated", oracle: str = "none") -> dict[str, Any]:
    """The scores as JSON data; `poses` says which poses placed the scans ("estimated" by KISS-ICP or the
    log's "truth", in which case there is no trajectory error to report), `oracle` what truth stood in for
    part of the labeller's output ("none", "classes" or "objects")."""
    s = result.summary
    scores = evaluate_map(result.vmap)
    traj = result.trajectory if poses == "estimated" else None
    return {
        **scores,
        "ate_m": traj.ate_rmse_m if traj else None,
        "rpe_m_per_scan": traj.rpe_trans_m if traj else None,
        "rpe_deg_per_scan": traj.rpe_rot_deg if traj else None,
        "drift_percent": traj.drift_percent if traj else None,
        "path_length_m": traj.path_length_m if traj else None,
        "scans": s.scans,
        "scans_per_second": s.scans_per_second,
        "mean_timings_ms": s.mean_timings_ms,
        "registration_failures": len(s.registration_failures),
        "map_voxels": s.map_voxels,
        "labeller": result.labeller,
        "environment": result.environment.value,
        "interrupted": s.interrupted,
        "poses": poses,
        "oracle": oracle,
        # predicted_instances are the objects shown (at least cluster.min_object_voxels voxels); fragments are
        # all instances before the small ones were hidden, final_merges those the end-of-run consolidation joined
        "fragments": s.fragments,
        "final_merges": s.final_merges,
        "level_tilt_deg": s.level_tilt_deg,
    }


def print_report(rep: dict[str, Any]) -> None:
    pct = 100.0
    print(
        f"{rep['scans']} scans, labeller {rep['labeller']} ({rep['environment']}), {rep['evaluated_points']} map points"
    )
    print(
        f"semantic: overall accuracy {rep['overall_accuracy'] * pct:.1f} %, mean accuracy "
        f"{rep['mean_accuracy'] * pct:.1f} %, mean IoU {rep['mean_iou'] * pct:.1f} %"
    )
    print("  IoU per class: " + ", ".join(f"{k} {v * pct:.1f}" for k, v in rep["per_class_iou"].items()))
    print(f"instances: NMI {rep['nmi'] * pct:.1f}, AMI {rep['ami'] * pct:.1f}, ARI {rep['ari'] * pct:.1f}")
    print(
        f"  at IoU 0.5: precision {rep['precision']:.3f}, recall {rep['recall']:.3f}, mIoU "
        f"{rep['instance_mean_iou']:.3f} ({rep['predicted_instances']} objects shown of {rep['fragments']} "
        f"fragments, {rep['true_instances']} true)"
    )
    if rep["ate_m"] is not None:
        print(
            f"trajectory: ATE {rep['ate_m']:.3f} m over {rep['path_length_m']:.1f} m, RPE "
            f"{rep['rpe_m_per_scan']:.3f} m / {rep['rpe_deg_per_scan']:.2f}° per scan, "
            f"drift {rep['drift_percent']:.2f} %"
        )
    elif rep.get("poses") == "truth":
        print("trajectory: the log's true poses were used (labelling scored without registration errors)")
    else:
        print("trajectory: the log has no true poses")
    timing = ", ".join(f"{k} {v:.1f}" for k, v in rep["mean_timings_ms"].items())
    print(f"speed: {rep['scans_per_second']:.1f} scans/s; ms per scan: {timing}")


def evaluate(
    source: str = typer.Argument(..., help="A log with ground truth (class_id/instance_id fields), or sim://…"),
    labeller: str | None = LABELLER,
    config: Path | None = CONFIG,
    overrides: list[str] | None = OVERRIDES,
    topic: str | None = TOPIC,
    start: float | None = START,
    end: float | None = END,
    every: int | None = EVERY,
    max_scans: int | None = MAX_SCANS,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or notices."),
    as_json: bool = typer.Option(False, "--json", help="Print the scores as JSON."),
    poses: str = typer.Option(
        "estimated",
        "--poses",
        help="estimated: register with KISS-ICP; truth: place scans with the log's true poses, so labelling "
        "errors can be told apart from registration errors.",
    ),
    oracle: str = typer.Option(
        "none",
        "--oracle",
        help="classes: the true class stands in for the labeller's; objects: a vector per true object stands "
        "in for its embeddings — to tell class, embedding and clustering errors apart.",
    ),
) -> None:
    """Score the online labelling and registration against the ground truth in a log."""
    if poses not in POSES:
        raise InputError(f"unknown --poses {poses!r}; choose one of: {', '.join(POSES)}")
    if oracle not in ORACLES:
        raise InputError(f"unknown --oracle {oracle!r}; choose one of: {', '.join(ORACLES)}")
    cfg = build_config(config, overrides, labeller, topic, start, end, every, max_scans)
    cfg.registration.poses = poses  # type: ignore[assignment]  # checked above
    cfg.label.oracle = oracle  # type: ignore[assignment]  # checked above
    scans, info = open_scans(source, cfg, quiet)
    scans = require_truth(scans, source, poses=poses == "truth")
    notice = (lambda _t: None) if quiet else (lambda t: print(f"aftershock: {t}", file=sys.stderr))
    result = run_stream(scans, cfg, [], info, notice)
    rep = report(result, poses, oracle)
    if as_json:
        print(json.dumps(rep, indent=2))
    else:
        print_report(rep)
    if result.summary.interrupted:
        raise typer.Exit(130)
