"""`aftershock cracks INPUT`: find the cracks of an element (PLY/PCD, or an exported map with --box), measure
each one's length (its minimum-area rectangle) and width (its opening: median extent across the crack over
slices along it), and score against a truth mask when one is given."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from aftershock.pipeline.config import load_config
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.progress import note
from aftershock.pipeline.types import DamageFound


def parse_box(text: str) -> np.ndarray:
    """'x0,y0,z0,x1,y1,z1' -> (2, 3)."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6:
        raise InputError(f"--box {text!r} is not six comma-separated numbers x0,y0,z0,x1,y1,z1")
    return np.sort(np.asarray(values).reshape(2, 3), axis=0)


def load_mask(path: Path, n: int) -> np.ndarray:
    """A boolean (or 0/1) per-point mask from .npy; its length must match the cloud."""
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        mask = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"not a readable .npy mask ({exc})", path) from None
    if mask.ndim != 1 or len(mask) != n:
        raise InputError(f"mask has shape {mask.shape} but the cloud has {n} points", path)
    if mask.dtype != bool and not np.isin(np.unique(mask), [0, 1]).all():
        raise InputError("mask is neither boolean nor 0/1", path)
    return mask.astype(bool)


def cracks(
    input: Path = typer.Argument(..., help="Element or map as PLY/PCD (e.g. a column cut out of a scan)."),
    truth: Path | None = typer.Option(None, help="Per-point boolean crack mask (.npy) to score against."),
    features: str | None = typer.Option(
        None, help="rgb | intensity | normal | curvature | fpfh | crackembed | shade | shade+crackembed."
    ),
    detector: str | None = typer.Option(
        None,
        help="isolation-forest (default) | ridge (orthoimage ridges) | region (damaged regions) | "
        "robust-covariance | one-class-svm | lof | kmeans | gmm | mean-shift.",
    ),
    resolution: float | None = typer.Option(
        None, help="Evaluation grid in metres (default: 1 mm for columns/walls, 1 cm for slabs)."
    ),
    box: str | None = typer.Option(None, help="Only the points in x0,y0,z0,x1,y1,z1 (metres)."),
    report: Path | None = typer.Option(None, help="Also write the JSON result to this file."),
    save: Path | None = typer.Option(None, "--save", help="Also write a Rerun recording (.rrd) of the element."),
    force: bool = typer.Option(False, help="Overwrite the report file and --save's recording."),
    config: Path | None = typer.Option(None, help="Config file (TOML/JSON)."),
    set_: list[str] | None = typer.Option(None, "--set", help="Override a setting: cracks.smooth_cell_m=0.02"),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON (nothing else on stdout)."),
) -> None:
    """Detect cracks (unsupervised), measure each one on its own plane, and score against a mask."""
    from aftershock.pipeline.cloud_io import check_output, finite_points, read_cloud, write_atomically
    from aftershock.pipeline.damage.components import in_box
    from aftershock.pipeline.damage.report import find_cracks

    cfg = load_config(config, set_)
    if resolution is not None and not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"--resolution must be a positive number of metres, not {resolution}")
    for out_path in (report, save):
        if out_path is not None:
            check_output(out_path, force, inputs=[p for p in (input, truth) if p is not None])
    cloud = read_cloud(input)
    mask = load_mask(truth, len(cloud)) if truth is not None else None
    # Non-finite vertices are dropped here, at the input, so no analysis below ever meets one.
    cloud, kept = finite_points(cloud, input, note)
    mask = mask[kept] if mask is not None else None
    if box is not None:
        keep = in_box(cloud.points, parse_box(box))
        if len(keep) == 0:
            raise InputError("no point of the input lies in --box", input)
        cloud = cloud.select(keep)
        mask = mask[keep] if mask is not None else None
    try:
        result = find_cracks(cloud, cfg.cracks, mask, features=features, detector=detector, resolution_m=resolution)
    except InputError as exc:
        raise InputError(str(exc), input) from None
    out = {"input": str(input)} | result.to_json()
    if save is not None:
        from aftershock.pipeline.mission import save_recording

        points = result.cloud.select(result.mask) if result.mask.any() else None
        if points is not None:
            points.instance_ids = result.crack_ids[result.mask].astype("uint32")
        view = cfg.rerun.model_copy(update={"map_voxel_m": result.resolution_m})  # the element as evaluated
        save_recording(save, result.cloud, view, True, DamageFound(result.cracks, points, report=out))  # checked above
        out["recording"] = str(save)
    if report is not None:
        text = json.dumps(out, indent=2)
        write_atomically(report, lambda tmp: tmp.write_text(text))
    if as_json:
        print(json.dumps(out, indent=2))
        return
    print(
        f"{len(result.cracks)} crack(s) on {len(result.cloud)} points "
        f"(grid {result.resolution_m * 1000:g} mm, spacing {result.spacing_m * 1000:.1f} mm, "
        f"{result.features} + {result.detector})"
    )
    for remark in result.notes:
        print(f"note: {remark}")
    for c in result.cracks:
        x, y, z = c.center
        flag = " SEVERE" if c.severe else ""
        if c.width_resolved:
            width = f"{c.width_m * 1000:.1f} mm (widest {c.max_width_m * 1000:.1f} mm)"
        else:
            width = f"not measurable (present; the scan resolves {c.resolvable_m * 1000:.1f} mm here)"
        print(
            f"  crack {c.instance_id:3d} at ({x:.3f}, {y:.3f}, {z:.3f}) length {c.length_m:.3f} m "
            f"width {width} points {c.num_points}{flag}"
        )
    if result.scores is not None:
        s = result.scores
        print(f"precision {s.precision:.3f} recall {s.recall:.3f} F1 {s.f1:.3f}")
        if np.isfinite(s.found_length_m):
            print(
                f"main true crack against its reported crack: length {s.found_length_m:.3f} / "
                f"{s.true_length_m:.3f} m (error {s.length_error_m:.3f}), width {s.found_width_m * 1000:.1f} / "
                f"{s.true_width_m * 1000:.1f} mm (error {s.width_error_m * 1000:.1f})"
            )
        elif np.isfinite(s.true_length_m):
            print(f"main true crack ({s.true_length_m:.3f} m long): not found")
        found = f"{s.found_cracks} of {s.true_cracks} true cracks found"
        if s.found_cracks:
            found += f"; median error length {s.median_length_error_m:.3f} m, "
            found += f"width {s.median_width_error_m * 1000:.1f} mm"
        print(found)
    if save is not None:  # the hint last
        from aftershock.pipeline.commands.run import rerun_program

        print(f"open the recording with: {rerun_program()} {save}")
