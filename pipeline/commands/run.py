"""`aftershock run [SOURCE]`: the streaming pipeline (register, label, cluster) over a log, to Rerun/MCAP/files.

With no SOURCE it runs on the sample recording in recordings/. Output paths are checked before any work
starts; Ctrl-C stops the run and leaves valid outputs of everything processed (exit code 130).
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from time import perf_counter
from typing import Any, Final

import numpy as np
import typer

from aftershock.pipeline.config import Config, load_config
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.label import FALLBACK_LABELLER, LABELLERS
from aftershock.pipeline.progress import enabled
from aftershock.pipeline.sink import Sink
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.types import LabelledCloud, RunInfo, Scan, SourceReport

LABELLER_HELP: Final = (
    f"One of: {', '.join(LABELLERS)}. Default mcpnet; the {FALLBACK_LABELLER} baseline if its weights are missing."
)
SAMPLE: Final = Path(str(resources.files("aftershock.recordings") / "sample.mcap"))  # shipped in the wheel


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
    """The scans of a source (errors in the input raise here) and what the sinks need to know about it;
    `info.report` fills with the messages the reader skips and the damage that ends the log, if any."""
    from aftershock import sources

    desc = sources.describe(source, cfg.source.topic)
    report = SourceReport()
    scans = sources.open(
        source,
        topic=cfg.source.topic,
        pose_topic=cfg.source.pose_topic,
        start_s=cfg.source.start_s,
        end_s=cfg.source.end_s,
        max_scans=cfg.source.max_scans,
        every=cfg.source.every,
        progress=enabled(quiet),
        report=report,
    )
    info = RunInfo(
        source=source,
        source_kind=desc.kind.value,
        topic=desc.topic,
        log_start_ns=desc.log_start_ns,
        raw_in_log=desc.viewer_reads,
        log_id=desc.log_id,
        report=report,
    )
    return scans, info


def input_files(source: str) -> list[Path]:
    """The files a run reads (the log, a bag folder's files, a folder's or glob's point-cloud files), which no
    output may replace."""
    from aftershock import sources

    kind = sources.kind_of(source)
    if kind is sources.SourceKind.SIM:
        return []
    if kind is sources.SourceKind.FILES:
        from aftershock.sources.files import list_files

        return list_files(source)
    path = Path(source)
    return [q for q in path.iterdir() if q.is_file()] if path.is_dir() else [path]


def make_sinks(
    cfg: Config,
    save: Path | None,
    spawn: bool,
    connect: str | None,
    mcap_out: Path | None,
    export: Path | None,
    force: bool,
    refine: bool = False,
    damage: bool = False,
    inputs: Sequence[Path] = (),
) -> list[Sink]:
    """The sinks asked for; each checks its output path (exists without --force, not writable) right away,
    and no output may be one of the `inputs`, even with --force."""
    from aftershock.pipeline.cloud_io import check_output

    for out in (save, mcap_out):
        if out is not None:
            check_output(out, force, inputs)
    if export is not None:
        for name in ("map.ply", "poses_tum.txt", "poses_kitti.txt", "summary.json", "refined.ply", "damage.json"):
            if (export / name).exists():
                check_output(export / name, True, inputs)
    sinks: list[Sink] = []
    try:
        if save is not None or spawn or connect is not None:
            from aftershock.sinks.rerun_sink import RerunSink

            sinks.append(RerunSink(save, spawn, connect, cfg.rerun, force))
        if mcap_out is not None:
            from aftershock.sinks.mcap_sink import McapSink

            sinks.append(McapSink(mcap_out, force))
        if export is not None:
            from aftershock.sinks.files import FileExportSink

            sinks.append(FileExportSink(export, force, refine=refine, damage=damage))
    except BaseException:
        for sink in sinks:
            sink.close()
        raise
    return sinks


@dataclass(frozen=True)
class Outputs:
    """Where `run` sends its results (the `--save/--spawn/--connect/--mcap-out/--export` options)."""

    save: Path | None = None
    spawn: bool = False
    connect: str | None = None
    mcap_out: Path | None = None
    export: Path | None = None
    force: bool = False

    def paths(self) -> dict[str, str]:
        pairs = (("rerun", self.save), ("mcap", self.mcap_out), ("export", self.export))
        return {k: str(v) for k, v in pairs if v is not None}


def run_source(
    source: str,
    cfg: Config,
    outputs: Outputs,
    refine: bool = False,
    damage: bool = False,
    region: np.ndarray | None = None,
    quiet: bool = False,
    notice: Callable[[str], None] | None = None,
    extra_sinks: Sequence[Sink] = (),
) -> tuple[StreamResult, dict[str, Any], RunInfo]:
    """One mission, as `aftershock run` does it: open the source, make the sinks, run the stream and the
    on-demand analyses. Returns the stream's result, the analyses' results (`refine`, `damage`) and the
    run's `RunInfo` (whose `report` lists what the reader skipped).
    `batch` calls this once per mission inside a Ray task (with `extra_sinks` reporting progress)."""
    notice = notice or (lambda t: print(f"aftershock: {t}", file=sys.stderr))
    scans, info = open_scans(source, cfg, quiet)
    on_demand = OnDemand(cfg, refine, damage, region, notice) if refine or damage else None
    o = outputs
    sinks = make_sinks(
        cfg, o.save, o.spawn, o.connect, o.mcap_out, o.export, o.force, refine, damage, input_files(source)
    )
    result = run_stream(scans, cfg, [*sinks, *extra_sinks], info, notice, on_demand)
    return result, on_demand.results if on_demand is not None else {}, info


def result_dict(result: StreamResult, outputs: dict[str, str], report: SourceReport | None = None) -> dict[str, Any]:
    s = result.summary
    out: dict[str, Any] = {
        "scans": s.scans,
        "points": s.points,
        "scans_per_second": s.scans_per_second,
        "wall_time_s": s.wall_time_s,
        "map_voxels": s.map_voxels,
        "instances": s.instances,
        "fragments": s.fragments,  # instances before those under cluster.min_object_voxels were hidden
        "instances_per_class": s.instances_per_class,
        "mean_timings_ms": s.mean_timings_ms,
        "registration_failures": s.registration_failures,
        "interrupted": s.interrupted,
        "skipped_messages": s.skipped_messages,
        "skipped_log_times_ns": [t for t, _ in report.skipped] if report is not None else [],
        "damaged_log": s.damaged_log,
        "damage": s.damage,
        "environment": result.environment.value,
        "labeller": result.labeller,
        "level_tilt_deg": s.level_tilt_deg,  # the first scan's z from up (None: the world was not levelled)
        "ate_m": result.trajectory.ate_rmse_m if result.trajectory else None,
        "trajectory": result.trajectory.as_dict() if result.trajectory else None,
        "outputs": outputs,
    }
    return out


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


@dataclass
class OnDemand:
    """The analyses run over the final map (`--refine`, `--damage`), limited to a region when one is given;
    their results go to every sink and into the run's JSON."""

    cfg: Config
    refine: bool
    damage: bool
    region: np.ndarray | None
    notice: Callable[[str], None]
    results: dict[str, Any] = field(default_factory=dict)
    net: Any = None

    def __post_init__(self) -> None:
        if self.refine:  # a missing or mismatched weights file is an error before any work, not after the run
            from aftershock.pipeline.refine import load_network

            self.net = load_network(self.cfg.lrgnet)

    def __call__(self, cloud: LabelledCloud, sinks: Sequence[Sink]) -> None:
        if self.region is not None:
            lo, hi = self.region
            cloud = cloud.select(np.all((cloud.points >= lo) & (cloud.points <= hi), axis=1))
            if len(cloud) == 0:
                self.notice("the --region holds no map points; nothing to refine or assess")
                return
        if self.refine:
            self._refine(cloud, sinks)
        if self.damage:
            self._damage(cloud, sinks)

    def _refine(self, cloud: LabelledCloud, sinks: Sequence[Sink]) -> None:
        from aftershock.pipeline.refine import refine_cloud

        self.notice(f"refining {len(cloud)} map points with LRGNet ({self.cfg.lrgnet.search})")
        t0 = perf_counter()
        result = refine_cloud(cloud, self.cfg.lrgnet, record_object=1, net=self.net)
        refined = LabelledCloud(cloud.points, cloud.colors, cloud.intensity, cloud.class_ids, result.instance_ids)
        for sink in sinks:
            sink.refined(refined, result.steps)
        self.results["refine"] = {
            "objects": len(np.unique(result.instance_ids[result.instance_ids > 0])),
            "points": len(cloud),
            "seconds": round(perf_counter() - t0, 3),
            "mean_steps_per_object": float(np.mean(result.steps_per_object)) if result.steps_per_object else 0.0,
            "colour": result.colour,  # the map had colour (else it was refined with the colour-free settings)
            "settings": result.settings,
        }

    def _damage(self, cloud: LabelledCloud, sinks: Sequence[Sink]) -> None:
        from aftershock.pipeline.damage.report import assess_damage

        self.notice(f"assessing damage on {len(cloud)} map points")
        t0 = perf_counter()
        report = assess_damage(cloud, self.cfg)
        data = report.to_json()
        data["seconds"] = round(perf_counter() - t0, 3)
        for sink in sinks:
            sink.damage(report.cracks, report.crack_points, report.stories, data)
        self.results["damage"] = data


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
            print(json.dumps(result_dict(result, outputs, info.report) | extra, indent=2, default=_jsonable))
        else:
            print_human(result, outputs, info)
            print_on_demand(extra)
            print_hints(outputs, info)
        if result.summary.interrupted:
            raise typer.Exit(130)


def _jsonable(obj: object) -> object:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "__dataclass_fields__"):
        return asdict(obj)  # type: ignore[arg-type]
    return str(obj)
