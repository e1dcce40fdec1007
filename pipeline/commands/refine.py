"""`aftershock refine INPUT`: re-segment a labelled cloud into objects with LRGNet, class-agnostic; with
`--truth`, score it (and the classical baselines) against the file's `instance_id`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.progress import note


def refine(
    input: Path = typer.Argument(..., help="A point-cloud file (PLY of the DESIGN.md format, PCD, ...)."),
    truth: bool = typer.Option(False, "--truth", help="Score against the file's instance_id."),
    search: str = typer.Option(None, help="greedy (default) | restart | beam."),
    score: str = typer.Option(None, help="Local-search score: ml (log-likelihood) | np (number of points)."),
    baselines: bool = typer.Option(
        None, "--baselines/--no-baselines", help="Also run the classical baselines (default: with --truth)."
    ),
    out: Path | None = typer.Option(None, help="Write the cloud with the refined instance_id as PLY."),
    weights: Path | None = typer.Option(None, help="LRGNet weights (default: the shipped ones)."),
    seed: int | None = typer.Option(None, help="Seed of the samples and local search."),
    config: Path | None = typer.Option(None, help="Config file (TOML or JSON)."),
    set_: list[str] = typer.Option([], "--set", help="Override a setting, e.g. lrgnet.max_steps=40."),
    force: bool = typer.Option(False, help="Overwrite --out if it exists."),
    as_json: bool = typer.Option(False, "--json", help="Print the results as JSON (nothing else on stdout)."),
) -> None:
    """Re-segment a cloud into objects by learnt region growing."""
    if seed is not None and not 0 <= seed <= 2**32 - 1:
        raise InputError(f"--seed {seed}: a seed is between 0 and {2**32 - 1} (numpy and torch take 32-bit seeds)")
    from aftershock.pipeline.cloud_io import check_output, finite_points, read_cloud, write_cloud
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.refine import baseline_cloud, refine_cloud, scores
    from aftershock.pipeline.refine.baselines import available
    from aftershock.pipeline.refine.features import voxelise

    cfg = load_config(config, set_).lrgnet
    updates = {"search": search, "score": score, "seed": seed, "weights": str(weights) if weights else None}
    cfg = cfg.model_copy(update={k: v for k, v in updates.items() if v is not None})
    if cfg.search not in ("greedy", "restart", "beam"):
        raise InputError(f"unknown search {cfg.search!r} (greedy, restart or beam)")
    if cfg.score not in ("ml", "np"):
        raise InputError(f"unknown score {cfg.score!r} (ml or np)")
    if out is not None:
        check_output(out, force, inputs=[input])
    cloud, _ = finite_points(read_cloud(input), input, note)
    if truth and cloud.instance_ids is None:
        raise InputError("--truth needs an instance_id vertex property, and this file has none", input)
    result = refine_cloud(cloud, cfg)
    steps = np.asarray(result.steps_per_object, float)
    report: dict = {
        "input": str(input),
        "points": len(cloud),
        "voxels": result.voxels,
        "search": cfg.search,
        "segments": result.segments,
        "seconds": round(result.seconds, 3),
        "grown_regions": len(steps),
        "steps_per_object": round(float(steps.mean()), 2) if len(steps) else 0.0,
        "colour": result.color,  # whether the cloud had colour: which mode's settings it was grown with
        "settings": result.settings,
    }
    methods: dict[str, dict] = {}
    if truth:
        assert cloud.instance_ids is not None
        report.update(scores(cloud.instance_ids, result.instance_ids))
        methods["lrgnet"] = {k: report[k] for k in ("nmi", "ami", "ari", "precision", "recall", "mean_iou")}
        methods["lrgnet"]["seconds"] = report["seconds"]
        if baselines is None or baselines:
            vc = voxelise(cloud, cfg.voxel_size_m, cfg.delta_m)
            for baseline in available():
                b = baseline_cloud(cloud, baseline, cfg, vc)
                methods[baseline.value] = {**scores(cloud.instance_ids, b.instance_ids), "seconds": b.seconds}
        report["methods"] = methods
    if out is not None:
        refined = cloud.select(np.arange(len(cloud)))
        refined.instance_ids = result.instance_ids
        write_cloud(out, refined, force=force)
        report["out"] = str(out)
    if as_json:
        print(json.dumps(report, indent=2))
        return
    typer.echo(
        f"{input}: {report['points']} points, {report['voxels']} voxels -> {report['segments']} objects "
        f"in {report['seconds']:.1f} s ({cfg.search}, {report['steps_per_object']:.1f} network steps per region)"
    )
    if methods:
        keys = ("nmi", "ami", "ari", "precision", "recall", "mean_iou")
        typer.echo(f"{'method':<12}" + "".join(f"{k:>10}" for k in (*keys, "seconds")))
        for name, m in methods.items():
            typer.echo(f"{name:<12}" + "".join(f"{m[k]:>10.3f}" for k in (*keys, "seconds")))
    if out is not None:
        typer.echo(f"wrote {out}")
