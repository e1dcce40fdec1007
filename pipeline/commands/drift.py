"""`aftershock drift INPUT`: story slabs of a structure and how far each drifted and tilted against the lowest."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from aftershock.pipeline.config import load_config
from aftershock.pipeline.progress import note
from aftershock.pipeline.types import DamageFound


def drift(
    input: Path = typer.Argument(..., help="Point cloud of a structure (PLY/PCD, e.g. an exported map)."),
    gravity: str | None = typer.Option(
        None, help="Where 'up' comes from: frame-z (the input's z) or ground-plane (the lowest slab)."
    ),
    config: Path | None = typer.Option(None, help="Config file (TOML/JSON)."),
    set_: list[str] | None = typer.Option(None, "--set", help="Override a setting: drift.bin_m=0.05"),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON (nothing else on stdout)."),
    save: Path | None = typer.Option(None, "--save", help="Also write a Rerun recording (.rrd) of the slabs."),
    force: bool = typer.Option(False, "--force", help="Overwrite --save's file."),
) -> None:
    """Drift (mm) and tilt (degrees) of every story slab against the lowest one."""
    from aftershock.pipeline.cloud_io import check_output, finite_points, read_cloud
    from aftershock.pipeline.damage.drift import Gravity, measure_drift
    from aftershock.pipeline.damage.report import story_json, story_text
    from aftershock.pipeline.errors import InputError

    sets = list(set_ or [])
    if gravity is not None:
        if gravity not in {g.value for g in Gravity}:
            raise InputError(f"--gravity {gravity!r}: choose frame-z or ground-plane")
        sets.append(f"drift.gravity={gravity}")
    cfg = load_config(config, sets)
    if save is not None:
        check_output(save, force, inputs=[input])
    cloud, _ = finite_points(read_cloud(input), input, note)
    extent = np.ptp(cloud.points, axis=0) if len(cloud) else np.zeros(3)
    if float(extent.max()) <= 0:
        raise InputError(f"all {len(cloud)} points lie at one spot; there are no slabs to find", input)
    result = measure_drift(cloud.points, cfg.drift)
    out = {
        "input": str(input),
        "gravity": result.gravity,
        "stories": [story_json(s) for s in result.stories],
        "notes": result.notes,
    }
    if save is not None:
        from aftershock.pipeline.mission import save_recording

        save_recording(save, cloud, cfg.rerun, True, DamageFound(stories=result.stories, report=out))  # checked above
        out["recording"] = str(save)
    if as_json:
        print(json.dumps(out, indent=2))
        return
    print(f"{len(result.stories)} slab plane(s); up = {result.gravity}")
    for s in result.stories:
        if s.drift_mm is None or s.drift_x_mm is None or s.drift_y_mm is None or s.tilt_deg is None:
            print(f"  story {s.index} at z {s.height_m:.3f} m: {story_text(s)} ({s.num_points} points)")
            continue
        assert s.tilt_x_deg is not None and s.tilt_y_deg is not None
        print(
            f"  story {s.index} at z {s.height_m:.3f} m: drift x {s.drift_x_mm:+.1f} y {s.drift_y_mm:+.1f} "
            f"total {s.drift_mm:.1f} mm; tilt x {s.tilt_x_deg:+.3f} y {s.tilt_y_deg:+.3f} "
            f"total {s.tilt_deg:.3f} deg ({s.num_points} points)"
        )
    for text in result.notes:
        print(f"  note: {text}")
    if save is not None:
        from aftershock.pipeline.commands.run import rerun_program

        print(f"open the recording with: {rerun_program()} {save}")
