"""`aftershock info PATH`: what is in a log before replaying it."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import typer

from aftershock.pipeline import progress
from aftershock.pipeline.text import safe


def _when(ns: int | None) -> str:
    if ns is None:
        return "?"
    if ns < 10**17:  # sensor clocks that count from boot, or files
        return f"{ns * 1e-9:.3f} s"
    return datetime.fromtimestamp(ns * 1e-9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def format_summary(summary) -> str:
    """The human-readable report."""
    span = f"{_when(summary.start_ns)} to {_when(summary.end_ns)}"
    lines = [f"{summary.path}: {summary.kind}, {summary.duration_s:.3f} s ({span})"]
    if summary.damage:
        lines.append(f"DAMAGED: {summary.damage}")
    width = max((len(t.name) for t in summary.topics), default=5)
    tw = max((len(t.type) for t in summary.topics), default=4)
    lines.append("topics:")
    for t in summary.topics:
        lines.append(f"  {t.name:<{width}}  {t.type:<{tw}}  {t.count:>7,d}")
    for pc in summary.point_clouds:
        shape = f", organized {pc.organized}" if pc.organized else ""
        lines.append(f"point cloud {pc.topic} ({pc.type}): {pc.scans} scans{shape}")
        if pc.scans:
            lines.append(
                f"  points per scan: min {pc.points_min:,d}, median {pc.points_median:,.0f}, max {pc.points_max:,d}"
                f" ({pc.invalid_points_total:,d} NaN/zero points dropped in all)"
            )
        fields = ", ".join(f"{f.name} {f.datatype}" + (f"[{f.count}]" if f.count > 1 else "") for f in pc.fields)
        lines.append(f"  fields: {fields or '?'}")
        if not pc.has_xyz:
            lines.append("  NO x/y/z fields: this topic cannot be replayed")
        timing = f"{pc.per_point_time} ({pc.time_convention})" if pc.per_point_time else "none (no deskewing)"
        lines.append(f"  per-point time: {timing}; intensity: {_yes(pc.intensity)}; colour: {_yes(pc.color)}")
        gt = [n for n, f in (("class_id", pc.ground_truth_classes), ("instance_id", pc.ground_truth_instances)) if f]
        lines.append(f"  ground truth: {', '.join(gt) if gt else 'none'}")
    poses = ", ".join(summary.pose_topics) if summary.pose_topics else "none"
    lines.append(f"ground-truth pose topics (PoseStamped): {poses}")
    return "\n".join(safe(line) for line in lines)  # topic and field names come from the file


def info(
    path: str = typer.Argument(..., help="MCAP file, ROS bag, or folder/glob of .pcd/.ply/.bin files."),
    as_json: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    topic: str | None = typer.Option(None, "--topic", help="Report only this point-cloud topic."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Topics, duration, fields and points per scan of a log: what to know before replaying it."""
    from aftershock.sources.inspect import inspect

    summary = inspect(path, progress=progress.enabled(quiet), topic=topic)
    if as_json:
        print(json.dumps(summary.to_json(), indent=2))
    else:
        print(format_summary(summary))
