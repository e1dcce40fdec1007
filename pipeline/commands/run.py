"""`aftershock run [SOURCE]`: the streaming pipeline (register, label, cluster) over a log, to Rerun/MCAP/files.

With no SOURCE it runs on the sample recording in recordings/. Output paths are checked before any work
starts; Ctrl-C stops the run and leaves valid outputs of everything processed (exit code 130).
"""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
import typer

from aftershock.pipeline.commands import CONFIG, END, EVERY, LABELLER, MAX_SCANS, OVERRIDES, START, TOPIC
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.mission import (
    Outputs,
    build_config,
    mission_json,
    resolve_source,
    run_source,
    to_json,
)
from aftershock.pipeline.stream import StreamResult
from aftershock.pipeline.types import RunInfo


def parse_region(region: str | None) -> np.ndarray | None:
    """`x0,y0,z0,x1,y1,z1` in metres -> (2, 3) min and max corners."""
    if region is None:
        return None
    try:
        values = [float(v) for v in region.split(",")]
    except ValueError:
        values = []
    if len(values) != 6:
        raise InputError(f"--region {region!r} is not six numbers x0,y0,z0,x1,y1,z1")
    box = np.array(values).reshape(2, 3)
    return np.stack([box.min(axis=0), box.max(axis=0)])


def print_human(result: StreamResult, outputs: dict[str, str], info: RunInfo | None = None) -> None:
    s = result.summary
    state = "interrupted after" if s.interrupted else "processed"
    print(
        f"{state} {s.scans} scans ({s.scans_per_second:.1f} scans/s, {result.environment.value}, "
        f"labeller {result.labeller}): {s.map_voxels} map voxels, {s.instances} instances"
    )
    if s.mean_timings_ms:
        print("per scan: " + ", ".join(f"{k} {v:.1f} ms" for k, v in s.mean_timings_ms.items()))
    if s.registration_failures:
        shown = ", ".join(str(q) for q in s.registration_failures[:10])
        more = " …" if len(s.registration_failures) > 10 else ""
        print(f"registration could not align {len(s.registration_failures)} scans: {shown}{more}")
    if result.trajectory is not None:
        t = result.trajectory
        print(
            f"trajectory error: ATE {t.ate_rmse_m:.3f} m RMSE over {t.path_length_m:.1f} m, "
            f"RPE {t.rpe_trans_m:.3f} m / {t.rpe_rot_deg:.2f}° per scan, drift {t.drift_percent:.2f} %"
        )
    if s.skipped_messages:
        print(f"skipped {s.skipped_messages} messages that could not be decoded (see the warnings)")
    if s.damage:
        print(f"the log ended early: {s.damage}")
    for text in s.warnings:
        print(f"warning: {text}")


def program() -> str:
    """`aftershock` as the user can run it from here: the bare name when that is what is on PATH, else the path
    it was started by (`.venv/bin/aftershock` outside the venv), else `python -m aftershock.pipeline`."""
    started = Path(sys.argv[0]) if sys.argv and sys.argv[0] else None
    if started is not None and started.name == "aftershock":
        on_path = shutil.which("aftershock")
        if on_path is not None and Path(on_path).resolve() == started.resolve():
            return "aftershock"
        return shlex.quote(str(started))
    return f"{shlex.quote(sys.executable)} -m aftershock.pipeline"


def rerun_program() -> str:
    """The `rerun` viewer command: on PATH, or the one installed beside this Python (a venv's bin/)."""
    if shutil.which("rerun") is not None:
        return "rerun"
    beside = Path(sys.executable).parent / "rerun"
    return shlex.quote(str(beside)) if beside.is_file() else "rerun"


def print_hints(outputs: dict[str, str], info: RunInfo | None = None) -> None:
    """What was written and how to open it, as commands that work as printed; printed last."""
    for key in ("mcap", "export"):
        if key in outputs:
            print(f"{key}: {outputs[key]}")
    if "rerun" in outputs:
        rrd = shlex.quote(outputs["rerun"])
        if info is not None and info.raw_in_log:
            print(f"open it with its log: {program()} view {shlex.quote(info.source)} {rrd}")
        else:
            print(f"open the recording with: {rerun_program()} {rrd}")
    if "export" in outputs:
        print(f"site report: {program()} report {shlex.quote(outputs['export'])}")


def print_on_demand(results: dict[str, Any]) -> None:
    if "refine" in results:
        r = results["refine"]
        print(f"refined: {r['objects']} objects from {r['points']} map points in {r['seconds']:.1f} s")
    if "damage" in results:
        d = results["damage"]
        severe = d.get("severe_cracks", 0)
        print(f"damage: {len(d['cracks'])} cracks ({severe} severe), {len(d['stories'])} story planes")
        from aftershock.pipeline.damage.report import story_text

        for story in d["stories"]:
            print(f"  story {story['index']} at {story['height_m']:.2f} m: {story_text(story)}")
        for note in d.get("notes", []):
            print(f"  note: {note}")


def run(
    source: str | None = typer.Argument(
        None, help="MCAP, ROS bag, point-cloud file/folder/glob or sim://… (default: the sample recording)."
    ),
    save: Path | None = typer.Option(None, "--save", help="Write a Rerun recording (.rrd)."),
    spawn: bool = typer.Option(False, "--spawn", help="Stream to a Rerun viewer started for this run."),
    connect: str | None = typer.Option(None, "--connect", help="Stream to a running viewer (rerun+http://…)."),
    mcap_out: Path | None = typer.Option(None, "--mcap-out", help="Write labelled clouds and poses as MCAP."),
    export: Path | None = typer.Option(None, "--export", help="Folder for map.ply, poses and summary.json."),
    labeller: str | None = LABELLER,
    config: Path | None = CONFIG,
    overrides: list[str] | None = OVERRIDES,
    topic: str | None = TOPIC,
    start: float | None = START,
    end: float | None = END,
    every: int | None = EVERY,
    max_scans: int | None = MAX_SCANS,
    refine: bool = typer.Option(False, "--refine", help="Re-segment the final map into objects with LRGNet."),
    damage: bool = typer.Option(False, "--damage", help="Cracks and story drift/tilt on the final map."),
    region: str | None = typer.Option(
        None, "--region", help="Limit --refine/--damage to the box x0,y0,z0,x1,y1,z1 (metres, map frame)."
    ),
    debug_layers: bool = typer.Option(
        False, "--debug-layers", help="Also record every stage of every scan at full resolution (large)."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or notices."),
    as_json: bool = typer.Option(False, "--json", help="Print the run summary as JSON."),
) -> None:
    """Register, label and cluster a LiDAR log scan by scan, streaming every stage to the outputs."""
    sets = [*(overrides or []), "rerun.debug_layers=true"] if debug_layers else overrides
    cfg = build_config(config, sets, labeller, topic, start, end, every, max_scans)
    box = parse_region(region)
    src = resolve_source(source)
    notice = (lambda _t: None) if quiet else (lambda t: print(f"aftershock: {t}", file=sys.stderr))
    asked = Outputs(save, spawn, connect, mcap_out, export, force)
    if not (asked.paths() or spawn or connect):
        notice("nothing will be saved: add --export DIR (map, poses, summary), --save FILE.rrd or --spawn")
    result, extra, info = run_source(src, cfg, asked, refine, damage, box, quiet, notice)
    outputs = asked.paths()
    if as_json:
        print(to_json(mission_json(result, outputs, info, extra)))
    else:
        print_human(result, outputs, info)
        print_on_demand(extra)
        print_hints(outputs, info)
    if result.summary.interrupted:
        raise typer.Exit(130)
