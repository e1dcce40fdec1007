"""`aftershock run [SOURCE]`: the streaming pipeline (register, label, cluster) over a log, to Rerun/MCAP/files.

With no SOURCE it runs on the sample recording in recordings/. Output paths are checked before any work
starts; Ctrl-C stops the run and leaves valid outputs of everything processed (exit code 130).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any, Final

import typer

from pipeline.config import Config, load_config
from pipeline.errors import InputError
from pipeline.label import FALLBACK_LABELLER, LABELLERS
from pipeline.progress import enabled
from pipeline.stream import StreamResult, run_stream
from pipeline.types import RunInfo, Scan
from sinks.base import Sink

LABELLER_HELP: Final = (
    f"One of: {', '.join(LABELLERS)}. Default mcpnet; the {FALLBACK_LABELLER} baseline if its weights are missing."
)
SAMPLE: Final = Path(__file__).resolve().parents[2] / "recordings" / "sample.mcap"


def build_config(
    config: Path | None,
    overrides: list[str] | None,
    labeller: str | None = None,
    topic: str | None = None,
    start: float | None = None,
    end: float | None = None,
    every: int | None = None,
    max_scans: int | None = None,
) -> Config:
    """The config file, then `--set` overrides, then the dedicated options (which win)."""
    sets = list(overrides or [])
    for key, value in (
        ("label.labeller", labeller),
        ("source.topic", topic),
        ("source.start_s", start),
        ("source.end_s", end),
        ("source.every", every),
        ("source.max_scans", max_scans),
    ):
        if value is not None:
            sets.append(f"{key}={json.dumps(value)}")
    return load_config(config, sets)


def resolve_source(source: str | None) -> str:
    if source is not None:
        return source
    if not SAMPLE.is_file():
        raise InputError("the sample recording is missing; pass a SOURCE", SAMPLE)
    return str(SAMPLE)


def open_scans(source: str, cfg: Config, quiet: bool) -> tuple[Iterator[Scan], RunInfo]:
    """The scans of a source (errors in the input raise here) and what the sinks need to know about it."""
    import sources

    desc = sources.describe(source, cfg.source.topic)
    scans = sources.open(
        source,
        topic=cfg.source.topic,
        pose_topic=cfg.source.pose_topic,
        start_s=cfg.source.start_s,
        end_s=cfg.source.end_s,
        max_scans=cfg.source.max_scans,
        every=cfg.source.every,
        progress=enabled(quiet),
    )
    info = RunInfo(source=source, source_kind=desc.kind.value, topic=desc.topic, log_start_ns=desc.log_start_ns)
    return scans, info


def make_sinks(
    cfg: Config,
    save: Path | None,
    spawn: bool,
    connect: str | None,
    mcap_out: Path | None,
    export: Path | None,
    force: bool,
) -> list[Sink]:
    """The sinks asked for; each checks its output path (exists without --force, not writable) right away."""
    sinks: list[Sink] = []
    try:
        if save is not None or spawn or connect is not None:
            from sinks.rerun_sink import RerunSink

            sinks.append(RerunSink(save, spawn, connect, cfg.rerun, force))
        if mcap_out is not None:
            from sinks.mcap_sink import McapSink

            sinks.append(McapSink(mcap_out, force))
        if export is not None:
            from sinks.files import FileExportSink

            sinks.append(FileExportSink(export, force))
    except BaseException:
        for sink in sinks:
            sink.close()
        raise
    return sinks


def result_dict(result: StreamResult, outputs: dict[str, str]) -> dict[str, Any]:
    s = result.summary
    out: dict[str, Any] = {
        "scans": s.scans,
        "points": s.points,
        "scans_per_second": s.scans_per_second,
        "wall_time_s": s.wall_time_s,
        "map_voxels": s.map_voxels,
        "instances": s.instances,
        "instances_per_class": s.instances_per_class,
        "mean_timings_ms": s.mean_timings_ms,
        "registration_failures": s.registration_failures,
        "interrupted": s.interrupted,
        "environment": result.environment.value,
        "labeller": result.labeller,
        "ate_m": result.trajectory.ate_rmse_m if result.trajectory else None,
        "trajectory": result.trajectory.as_dict() if result.trajectory else None,
        "outputs": outputs,
    }
    return out


def print_human(result: StreamResult, outputs: dict[str, str]) -> None:
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
    if "rerun" in outputs:
        print(f"open the recording with: rerun {outputs['rerun']}")
    for key in ("mcap", "export"):
        if key in outputs:
            print(f"{key}: {outputs[key]}")


def register(app: typer.Typer) -> None:
    @app.command()
    def run(
        source: str | None = typer.Argument(
            None, help="MCAP, ROS bag, point-cloud file/folder/glob or sim://… (default: the sample recording)."
        ),
        save: Path | None = typer.Option(None, "--save", help="Write a Rerun recording (.rrd)."),
        spawn: bool = typer.Option(False, "--spawn", help="Stream to a Rerun viewer started for this run."),
        connect: str | None = typer.Option(None, "--connect", help="Stream to a running viewer (rerun+http://…)."),
        mcap_out: Path | None = typer.Option(None, "--mcap-out", help="Write labelled clouds and poses as MCAP."),
        export: Path | None = typer.Option(None, "--export", help="Folder for map.ply, poses and summary.json."),
        labeller: str | None = typer.Option(None, "--labeller", help=LABELLER_HELP),
        config: Path | None = typer.Option(None, "--config", help="TOML or JSON config file."),
        overrides: list[str] | None = typer.Option(None, "--set", help="Config override section.key=value."),
        topic: str | None = typer.Option(None, "--topic", help="Point-cloud topic (default: the only one)."),
        start: float | None = typer.Option(None, "--start", help="Seconds from the log start to begin at."),
        end: float | None = typer.Option(None, "--end", help="Seconds from the log start to stop at."),
        every: int | None = typer.Option(None, "--every", help="Use every N-th scan."),
        max_scans: int | None = typer.Option(None, "--max-scans", help="Stop after this many scans."),
        force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or notices."),
        as_json: bool = typer.Option(False, "--json", help="Print the run summary as JSON."),
    ) -> None:
        """Register, label and cluster a LiDAR log scan by scan, streaming every stage to the outputs."""
        cfg = build_config(config, overrides, labeller, topic, start, end, every, max_scans)
        src = resolve_source(source)
        scans, info = open_scans(src, cfg, quiet)
        sinks = make_sinks(cfg, save, spawn, connect, mcap_out, export, force)
        outputs = {k: str(v) for k, v in (("rerun", save), ("mcap", mcap_out), ("export", export)) if v is not None}
        notice = (lambda _t: None) if quiet else (lambda t: print(f"aftershock: {t}", file=sys.stderr))
        result = run_stream(scans, cfg, sinks, info, notice)
        if as_json:
            print(json.dumps(result_dict(result, outputs), indent=2, default=_jsonable))
        else:
            print_human(result, outputs)
        if result.summary.interrupted:
            raise typer.Exit(130)


def _jsonable(obj: object) -> object:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "__dataclass_fields__"):
        return asdict(obj)  # type: ignore[arg-type]
    return str(obj)
