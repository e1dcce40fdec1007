"""`aftershock simulate`: a simulated mission as a labelled ROS 2 MCAP, and the building's static scan as PLY."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from aftershock.pipeline import progress
from aftershock.pipeline.classes import CLASS_NAMES
from aftershock.pipeline.errors import InputError


def _class_name(i: int) -> str:
    return CLASS_NAMES[i] if i < len(CLASS_NAMES) else str(i)


def simulate(
    out: Path | None = typer.Option(None, "--out", "-o", help="MCAP file to write the mission to."),
    seed: int = typer.Option(0, "--seed", help="Building and mission seed: the same seed, the same bytes."),
    scene: str = typer.Option(
        "disaster", "--scene", help="Scene generator: office, disaster (the families), hall, wing or flats."
    ),
    sensor: str = typer.Option(
        "vlp16",
        "--sensor",
        help="Sensor: vlp16, vlp16-20hz, dense, vlp32c, os0-32/64/128, os1-32/64/128 (published beam tables).",
    ),
    robot: str = typer.Option("legged", "--robot", help="Robot: legged, wheeled or tracked."),
    height: float | None = typer.Option(None, "--height", help="LiDAR mount height above the floor, 0.3-1.8 m."),
    tilt: float | None = typer.Option(None, "--tilt", help="LiDAR pitched down by this many degrees."),
    turn_rate: float | None = typer.Option(None, "--turn-rate", help="Fastest turn of the robot, deg/s."),
    sway: float | None = typer.Option(None, "--sway", help="Body roll amplitude of the gait, degrees."),
    palette: str | None = typer.Option(None, "--palette", help="Colours: natural, random, grey or swap."),
    no_color: bool = typer.Option(False, "--no-color", help="A LiDAR without a camera: no rgb field."),
    conditions: str | None = typer.Option(
        None, "--conditions", help="plain, or random: noise, dropouts, mixed edges, glass, mirrors."
    ),
    randomize: bool = typer.Option(
        False, "--randomize", help="Draw robot settings, palette and conditions from the seed."
    ),
    scans: int | None = typer.Option(None, "--scans", help="Number of scans (default 100)."),
    duration: float | None = typer.Option(None, "--duration", help="Mission length in seconds."),
    story: int = typer.Option(0, "--story", help="Story the robot walks (0 = ground floor)."),
    speed: float | None = typer.Option(None, "--speed", help="Walking speed in m/s (default 1.0)."),
    spacing: float | None = typer.Option(
        None, "--spacing", help="Scan every this many metres of travel instead of at the sensor rate."
    ),
    static_out: Path | None = typer.Option(None, "--static-out", help="PLY for the labelled static scan."),
    static_spacing: float = typer.Option(0.05, "--static-spacing", help="Point spacing of the static scan (m)."),
    truth_out: Path | None = typer.Option(None, "--truth-out", help="JSON file for the scene's ground truth."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate a robot mission through a procedural building: labelled scans and true poses."""
    from aftershock.pipeline.cloud_io import check_output, write_atomically, write_cloud
    from aftershock.sources.simulated import SimSpec, check_spec, make_mission, resolve
    from aftershock.sources.simulator.recording import truth_to_dict, write_mission

    if out is None and static_out is None and truth_out is None:
        raise InputError("nothing to write: give --out, --static-out and/or --truth-out")
    if scans is not None and duration is not None:
        raise InputError("give --scans or --duration, not both")
    spec = SimSpec(
        scene,
        seed,
        sensor,
        scans,
        duration,
        story,
        speed,
        spacing,
        robot=robot,
        height_m=height,
        tilt_deg=tilt,
        turn_deg_s=turn_rate,
        sway_deg=sway,
        palette=palette,
        color=not no_color,
        conditions=conditions,
        randomize=randomize,
    )
    check_spec(spec, spec.uri())
    for p in (out, static_out, truth_out):
        if p is not None:
            check_output(p, force)
    t0 = time.perf_counter()
    mission = make_mission(spec)
    setup_s = time.perf_counter() - t0
    summary: dict = {
        "uri": spec.uri(),
        "family": scene,
        "seed": seed,
        "sensor": sensor,
        "story": story,
        "building_and_plan_s": round(setup_s, 3),
        "generator": scene,
        "color": not no_color,
        **resolve(spec).to_dict(),
    }
    if out is not None:
        from aftershock.pipeline.progress import track

        t1 = time.perf_counter()
        stream = track(mission, total=len(mission), desc="simulating", show=progress.enabled(quiet))
        meta = {"family": scene, "seed": seed, "sensor": sensor, "story": story, "scans": len(mission)}
        meta["uri"] = spec.uri()  # everything that chose this mission, randomisation included
        stats = write_mission(out, stream, truth=mission.scene.truth, metadata=meta, force=force)
        dt = time.perf_counter() - t1
        summary.update(
            out=str(out),
            scans=stats.scans,
            points=stats.points,
            points_per_scan=round(stats.points / max(stats.scans, 1), 1),
            seconds=round(dt, 3),
            scans_per_second=round(stats.scans / dt, 2) if dt > 0 else None,
            bytes=out.stat().st_size,
            trajectory_loop_m=round(mission.trajectory.length, 2),
            class_histogram={_class_name(k): v for k, v in sorted(stats.class_histogram.items())},
        )
    if static_out is not None:
        t2 = time.perf_counter()
        cloud = mission.scene.sample_static_cloud(static_spacing, seed)
        write_cloud(static_out, cloud, force=force)
        summary.update(
            static_out=str(static_out), static_points=len(cloud), static_seconds=round(time.perf_counter() - t2, 3)
        )
    if truth_out is not None:
        text = json.dumps(truth_to_dict(mission.scene.truth), indent=1)
        write_atomically(check_output(truth_out, force), lambda tmp: tmp.write_text(text))
        summary["truth_out"] = str(truth_out)
    if as_json:
        print(json.dumps(summary, indent=2))
        return
    if out is not None:
        print(
            f"{out}: {summary['scans']} scans, {summary['points_per_scan']:,.0f} points per scan, "
            f"{summary['scans_per_second']} scans/s, {summary['bytes'] / 1e6:.1f} MB"
        )
        hist = ", ".join(f"{k} {v:,d}" for k, v in summary["class_histogram"].items())
        print(f"  classes: {hist}")
    if static_out is not None:
        print(f"{static_out}: static scan, {summary['static_points']:,d} points")
    if truth_out is not None:
        print(f"{truth_out}: ground truth")
