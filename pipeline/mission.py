"""One mission: a source through the stream to the sinks, and the analyses over its final map.

    result, analyses, info = run_source(path, load_config(None), Outputs(export=Path("out")))

`aftershock run` is this plus printing; `batch` runs it once per mission inside a Ray task and `eval` uses
its `open_scans`. Every sink is made and told here or in the stream, never in the command line; what
`run --json` prints is `mission_json` (its keys are listed in docs/json.md).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass
from importlib import resources
from pathlib import Path
from time import perf_counter
from typing import Any, Final

import numpy as np

from aftershock.pipeline.config import Config, RerunConfig, load_config
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.progress import enabled, working
from aftershock.pipeline.sink import Sink
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.types import DamageFound, LabelledCloud, RunInfo, RunSummary, Scan, SourceReport

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
        raw_in_log=desc.raw_in_log,
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
    from aftershock.pipeline.outputs import check_distinct, check_output

    export_files = ("map.ply", "poses_tum.txt", "poses_kitti.txt", "summary.json", "refined.ply", "damage.json")
    named: dict[str, Path | None] = {"--save": save, "--mcap-out": mcap_out}
    if export is not None:
        named |= {f"--export ({name})": export / name for name in export_files}
    check_distinct(named)  # `--save P --mcap-out P` would keep only one of them
    for out in (save, mcap_out):
        if out is not None:
            check_output(out, force, inputs)
    if export is not None:
        for name in export_files:
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
    on_demand = OnDemand(cfg, refine, damage, region, notice, quiet) if refine or damage else None
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
        "structure_elements": s.structure_elements,  # elements the structure model found, per kind
        "structure_notes": result.notes,  # what it could not do (no floor: the labels are the network's alone)
        "warnings": s.warnings,  # said once per run and reason: scans outside the networks' training data
    }
    return out


def mission_json(
    result: StreamResult, outputs: dict[str, str], info: RunInfo, analyses: dict[str, Any]
) -> dict[str, Any]:
    """What `run --json` prints: `result_dict`, then the on-demand analyses' results each under a key of its
    own (`refine`, `damage_report`). `damage` stays why the log ended early, as in `summary.json` and
    `info --json`: the damage report once overwrote it (docs/json.md)."""
    out = result_dict(result, outputs, info.report)
    if "refine" in analyses:
        out["refine"] = analyses["refine"]
    if "damage" in analyses:
        out["damage_report"] = analyses["damage"]
    return out


def to_json(data: dict[str, Any]) -> str:
    """`data` as indented JSON; numpy arrays and dataclasses become lists and objects."""
    return json.dumps(data, indent=2, default=_jsonable)


@dataclass
class OnDemand:
    """The analyses run over the final map (`--refine`, `--damage`), limited to a region when one is given;
    their results go to every sink and into the run's JSON."""

    cfg: Config
    refine: bool
    damage: bool
    region: np.ndarray | None
    notice: Callable[[str], None]
    quiet: bool = False  # no progress line on a terminal
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
        with working("refining with LRGNet", show=enabled(self.quiet)):
            result = refine_cloud(cloud, self.cfg.lrgnet, record_object=1, net=self.net)
        refined = LabelledCloud(cloud.points, cloud.colors, cloud.intensity, cloud.class_ids, result.instance_ids)
        for sink in sinks:
            sink.refined(refined, result.steps)
        self.results["refine"] = {
            "objects": len(np.unique(result.instance_ids[result.instance_ids > 0])),
            "points": len(cloud),
            "seconds": round(perf_counter() - t0, 3),
            "mean_steps_per_object": float(np.mean(result.steps_per_object)) if result.steps_per_object else 0.0,
            "colour": result.color,  # the map had colour (else it was refined with the colour-free settings)
            "settings": result.settings,
        }

    def _damage(self, cloud: LabelledCloud, sinks: Sequence[Sink]) -> None:
        from aftershock.pipeline.damage.report import assess_damage

        self.notice(f"assessing damage on {len(cloud)} map points")
        t0 = perf_counter()
        with working("assessing damage", show=enabled(self.quiet)):
            report = assess_damage(cloud, self.cfg)
        data = report.to_json()
        data["seconds"] = round(perf_counter() - t0, 3)
        for sink in sinks:
            sink.damage(DamageFound(report.cracks, report.crack_points, report.stories, data))
        self.results["damage"] = data


def _jsonable(obj: object) -> object:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if is_dataclass(obj) and not isinstance(obj, type):
        return asdict(obj)
    return str(obj)


def save_recording(path: Path, cloud: LabelledCloud, cfg: RerunConfig, force: bool, found: DamageFound) -> Path:
    """A Rerun recording of an on-demand analysis (`cracks --save`, `drift --save`) at `path` (checked like every
    output): the analysed cloud as the map, then the cracks and stories found on it, in the default layout."""
    from aftershock.sinks.rerun_sink import RerunSink

    sink = RerunSink(path, False, None, cfg, force)
    try:
        sink.end(RunSummary(points=len(cloud), map_voxels=len(cloud)), cloud)  # the map first: stories span it
        sink.damage(found)
    finally:
        sink.close()
    return path
