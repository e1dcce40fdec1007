"""The stream: scans -> register -> label -> cluster, one frame at a time, with every sink told after each stage.

    result = run_stream(sources.open(path), cfg, sinks, RunInfo(source=path, source_kind="mcap"))

Stages are generator functions chained lazily (`stage_chain`, first below). With `stream.overlap` (opt-in)
reading and registering run on a second thread, at most `stream.ahead` scans ahead, while the main thread
labels, clusters and tells the sinks (the slow parts of both release the GIL: KISS-ICP, PyTorch, numpy); every
sink call still happens on the main thread in the same order as without it, so the outputs are the same. The
accumulated map goes to the sinks every `cfg.rerun.map_every` scans (decided here only) and once at the end.
Sinks always get `close()`, and after a Ctrl-C also `end()` with what was processed, so their files stay valid;
the result then says `interrupted` and counts the scans that went through every stage (the one in flight may
have reached the sinks for its first stages).
"""

from __future__ import annotations

import logging
import queue
import signal
import sys
import threading
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from time import perf_counter
from typing import Final

import numpy as np
from threadpoolctl import threadpool_limits

from aftershock.pipeline.classes import CLASS_NAMES, NUM_CLASSES
from aftershock.pipeline.cluster import InstanceClusterer, cluster_stage
from aftershock.pipeline.config import Config, Environment
from aftershock.pipeline.errors import InputError, OutputError
from aftershock.pipeline.label import (
    FALLBACK_LABELLER,
    Explain,
    Labeller,
    hand_structure,
    label_stage,
    labelling_range,
    make_labeller,
)
from aftershock.pipeline.labellers.oracle import TruthStandIn
from aftershock.pipeline.register import (
    MIN_POINTS,
    Registrar,
    TruthPoses,
    guess_environment,
    make_registrar,
    register_stage,
)
from aftershock.pipeline.scan_stats import DistributionCheck, Reference
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.structure import StructureModel
from aftershock.pipeline.structure.stage import structure_stage
from aftershock.pipeline.trajectory import TrajectoryError, trajectory_error
from aftershock.pipeline.types import Frame, InstanceMerge, LabelledCloud, RunInfo, RunSummary, Scan
from aftershock.pipeline.voxel_map import VoxelMap

log = logging.getLogger(__name__)

STAGES: tuple[str, ...] = ("source", "register", "label", "structure", "cluster", "sinks")


def stage_chain(
    scans: Iterable[Scan], run: _Run, sinks: Sequence[Sink]
) -> tuple[Generator[Frame, None, None], Iterator[Frame]]:
    """The stages, chained lazily, every sink told after each: source -> register -> label (the network, then the
    structure model's fusion) -> cluster. Returns
    the registered frames (closed to stop the reading) and the clustered ones (iterated by `_loop`)."""
    reach = labelling_range(run.cfg, run.environment)
    registered = register_stage(_timed_source(scans), run.registrar)
    if run.cfg.stream.overlap:
        registered = _ahead(registered, run.cfg.stream.ahead)
    # The raw scan goes to the sinks after its registration (which leaves it as it is): all on this thread.
    frames = _tap(_tap(registered, sinks, Stage.RAW), sinks, Stage.REGISTERED)
    labelled = label_stage(frames, run.vmap, run.labeller, reach, explainer(run.structure, run.labeller))
    labelled = structure_stage(labelled, run.vmap, run.structure)
    frames = _tap(labelled, sinks, Stage.LABELLED)
    frames = _tap(cluster_stage(frames, run.vmap, run.clusterer), sinks, Stage.CLUSTERED)
    return registered, frames


def explainer(model: StructureModel | None, labeller: Labeller) -> Explain | None:
    """The structure model's `explain` for the label stage (new voxels on a confirmed element skip the network),
    for a labeller with embeddings (the element gives its own; one without links voxels by normals, which the
    structure does not give)."""
    if model is None or not model.cfg.skip_explained or not labeller.embedding_dim:
        return None
    return model.explain


@dataclass(slots=True)
class StreamResult:
    summary: RunSummary
    vmap: VoxelMap
    environment: Environment
    labeller: str
    seqs: np.ndarray  # (F,) scan sequence numbers of the frames
    stamps_ns: np.ndarray  # (F,)
    poses: np.ndarray  # (F, 4, 4) estimated poses at the scan stamps
    true_poses: np.ndarray | None  # (F, 4, 4), NaN for frames without one; None when (almost) none had one
    trajectory: TrajectoryError | None
    notes: list[str] = field(default_factory=list)
    structure: StructureModel | None = None  # the building's elements (None: `structure.enabled` off)


def _first_usable(scans: Iterator[Scan], source: str) -> tuple[list[Scan], Scan]:
    """Scans up to and including the first with enough points to register (InputError if there is none)."""
    skipped: list[Scan] = []
    for scan in scans:
        if len(scan) >= MIN_POINTS:
            return skipped, scan
        skipped.append(scan)
    what = f"{len(skipped)} scans, none with {MIN_POINTS} points or more" if skipped else "no scans"
    raise InputError(f"no usable scans ({what})", source)


def resolve_environment(cfg: Config, first: Scan) -> Environment:
    env = cfg.label.environment
    return guess_environment(first) if env is Environment.AUTO else env


def choose_labeller(cfg: Config, environment: Environment, notice: Callable[[str], None]) -> Labeller:
    """The configured labeller; the default MCPNet falls back to the baseline (with a notice) when it is
    not available, a labeller asked for by name, or with a weights file named, does not. With
    `label.oracle` the truth stands in for its classes or embeddings (`eval --oracle`)."""
    name = cfg.label.labeller
    try:
        labeller = make_labeller(name, cfg, environment)
    except InputError as exc:
        asked = {"labeller", "weights"} & cfg.label.model_fields_set
        if asked or cfg.label.weights is not None or name == FALLBACK_LABELLER:
            raise
        notice(f"{exc}; using the {FALLBACK_LABELLER} baseline instead")
        labeller = make_labeller(FALLBACK_LABELLER, cfg, environment)
    if cfg.label.oracle == "none":
        return labeller
    if cfg.label.oracle == "objects" and not labeller.embedding_dim:
        raise InputError(f"--oracle objects: labeller {labeller.name!r} has no embeddings to stand in for")
    return TruthStandIn(labeller, cfg.label.oracle)


@contextmanager
def _no_interrupts() -> Iterator[None]:
    """Hold off a second Ctrl-C or SIGTERM while the sinks finish their files (which never wait for ever:
    a sink that cannot write raises instead)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _timed_source(scans: Iterable[Scan]) -> Iterator[Frame]:
    it = iter(scans)
    while True:
        t0 = perf_counter()
        try:
            scan = next(it)
        except StopIteration:
            return
        frame = Frame(scan)
        frame.timings_ms["source"] = (perf_counter() - t0) * 1e3
        yield frame


_POLL_S: Final = 0.1  # how often a blocked reader thread looks whether the stream has stopped


@dataclass(frozen=True, slots=True)
class _End:
    """The last item of `_ahead`'s queue: the frames ended, or raised `error`."""

    error: BaseException | None = None


def _ahead(frames: Iterator[Frame], depth: int) -> Generator[Frame, None, None]:
    """`frames` computed on a second thread, at most `depth` ahead of the consumer, in order. An exception
    there is raised here, in its turn; when the consumer stops (end, error, Ctrl-C, `close()`) the thread
    stops after the frame it is working on and is joined, so nothing reads the source behind the caller's back."""
    out: queue.Queue[Frame | _End] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item: Frame | _End) -> bool:
        while not stop.is_set():
            try:
                out.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for frame in frames:
                if not put(frame):
                    return
        except BaseException as exc:  # handed to the consumer, which raises it in its turn
            put(_End(exc))
            return
        put(_End())

    thread = threading.Thread(target=work, name="aftershock-read-register", daemon=True)
    thread.start()
    try:
        while not isinstance(item := out.get(), _End):
            yield item
        if item.error is not None:
            raise item.error
    finally:
        stop.set()
        thread.join()


def _tap(frames: Iterable[Frame], sinks: Sequence[Sink], stage: Stage) -> Iterator[Frame]:
    for frame in frames:
        t0 = perf_counter()
        for sink in sinks:
            sink.stage(frame, stage)
        frame.timings_ms["sinks"] = frame.timings_ms.get("sinks", 0.0) + (perf_counter() - t0) * 1e3
        yield frame


def instances_per_class(cloud: LabelledCloud) -> dict[str, int]:
    """Number of instances whose majority class is each class."""
    if cloud.instance_ids is None or cloud.class_ids is None:
        return {}
    inst = cloud.instance_ids.astype(np.int64)
    cls = cloud.class_ids.astype(np.int64)
    ok = (inst > 0) & (cls < NUM_CLASSES)
    if not ok.any():
        return {}
    ids, inv = np.unique(inst[ok], return_inverse=True)
    votes = np.zeros((len(ids), NUM_CLASSES), np.int64)
    np.add.at(votes, (inv.ravel(), cls[ok]), 1)
    majority = np.bincount(votes.argmax(1), minlength=NUM_CLASSES)
    return {CLASS_NAMES[c]: int(majority[c]) for c in np.flatnonzero(majority)}


MapHook = Callable[[LabelledCloud, Sequence[Sink]], None]


def shown_map(vmap: VoxelMap, clusterer: InstanceClusterer) -> LabelledCloud:
    """The map as the user sees it: objects under the minimum size read as "no object"."""
    cloud = vmap.to_cloud()
    assert cloud.instance_ids is not None, "the map carries instance ids"
    cloud.instance_ids = clusterer.shown_ids(cloud.instance_ids, np.arange(len(cloud.instance_ids)))
    return cloud


def final_cloud(vmap: VoxelMap) -> LabelledCloud:
    """The map at the end of a run; without colour when no scan had any (not the grey the map stores for such
    points): LRGNet and the damage assessment then take their colour-free settings, and exports say so."""
    cloud = vmap.to_cloud()
    if not vmap.has_color:
        cloud.colors = None
    return cloud


def consolidate(
    vmap: VoxelMap,
    clusterer: InstanceClusterer,
    labeller: Labeller,
    seq: int,
    summary: RunSummary,
) -> tuple[list[InstanceMerge], bool]:
    """End of run: the map-level consolidation of the clusterer, the merged objects' class vote, and fragments
    under the minimum object size set to "no object" in the map itself. Returns the merges (for the sinks)
    and whether the map changed."""
    merges = clusterer.finish(vmap, seq)
    if merges:
        labeller.vote_instances(vmap, np.array([m.into for m in merges], np.int64))
    ids = vmap.instance_ids
    summary.fragments = len(np.unique(ids[ids > 0]))
    summary.final_merges = sum(len(m.merged) for m in merges)
    shown = clusterer.shown_ids(ids)
    changed = bool(merges) or not np.array_equal(shown, ids)
    ids[:] = shown
    return merges, changed


def run_stream(
    scans: Iterable[Scan],
    cfg: Config,
    sinks: Sequence[Sink],
    info: RunInfo,
    notice: Callable[[str], None] | None = None,
    on_final_map: MapHook | None = None,
) -> StreamResult:
    """Run the whole stream over `scans`; see the module docstring. `on_final_map` runs the on-demand
    analyses (LRGNet refinement, damage) over the final map and hands their results to the sinks; it is
    skipped after an interruption."""
    # The stages do many small (N x 3) products: BLAS threads only add wake-up costs (KISS-ICP has its own).
    with threadpool_limits(1, user_api="blas"):
        return _run(scans, cfg, sinks, info, notice, on_final_map)


@dataclass
class _Run:
    """One run's components and what it has gathered so far, from set-up to the result."""

    cfg: Config  # a copy, with the environment resolved
    environment: Environment
    labeller: Labeller
    vmap: VoxelMap
    registrar: Registrar | TruthPoses
    clusterer: InstanceClusterer
    t_start: float
    structure: StructureModel | None = None  # None: `structure.enabled` off
    notes: list[str] = field(default_factory=list)
    summary: RunSummary = field(default_factory=RunSummary)
    seqs: list[int] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    true_poses: list[np.ndarray | None] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    last_map_seq: int | None = None  # the scan the sinks last got the map after
    distribution: DistributionCheck | None = None  # scans unlike the networks' training scans (learned only)

    def add(self, frame: Frame) -> None:
        self.summary.scans += 1
        self.summary.points += len(frame.scan)
        if not frame.registration_ok:
            self.summary.registration_failures.append(frame.seq)
        self.seqs.append(frame.seq)
        self.stamps.append(frame.scan.stamp_ns)
        pose = frame.stamp_pose if frame.stamp_pose is not None else frame.pose
        assert pose is not None, "a frame has its pose once registered"
        self.poses.append(pose)
        self.true_poses.append(frame.scan.gt_pose)


def _run(
    scans: Iterable[Scan],
    cfg: Config,
    sinks: Sequence[Sink],
    info: RunInfo,
    notice: Callable[[str], None] | None,
    on_final_map: MapHook | None = None,
) -> StreamResult:
    notice = notice or (lambda text: print(f"aftershock: {text}", file=sys.stderr))
    run, all_scans = _set_up(scans, cfg, info, notice)
    registered, frames = stage_chain(all_scans, run, sinks)
    try:
        for sink in sinks:
            sink.begin(info)
        try:
            error: BaseException | None = _loop(run, frames, sinks, notice)
        finally:
            registered.close()  # no more reading and registering while the outputs are finished
        _finish(run, sinks, info, on_final_map, error, notice)
    finally:
        with _no_interrupts():
            _close_all(sinks)
    return _result(run)


def _set_up(
    scans: Iterable[Scan], cfg: Config, info: RunInfo, notice: Callable[[str], None]
) -> tuple[_Run, Iterator[Scan]]:
    """The components, chosen from the first usable scan (the environment, hence the labeller and the
    registration settings); and every scan again, that one and those before it included."""
    t_start = perf_counter()
    it = iter(scans)
    skipped, first = _first_usable(it, info.source)
    if cfg.label.oracle != "none" and not first.has_ground_truth:
        raise InputError(f"label.oracle={cfg.label.oracle} needs a log with ground truth", info.source)
    environment = resolve_environment(cfg, first)
    labeller = choose_labeller(cfg, environment, notice)
    info.environment = environment.value
    info.labeller = labeller.name
    run = _Run(
        cfg=cfg,
        environment=environment,
        labeller=labeller,
        vmap=VoxelMap.from_config(cfg.map, labeller.embedding_dim),
        registrar=make_registrar(cfg.registration, environment),
        clusterer=InstanceClusterer(cfg.cluster, labeller.affinity, labeller.embedding_dim),
        t_start=t_start,
    )
    if cfg.structure.enabled and cfg.label.oracle != "classes":  # the true classes leave nothing to fuse
        run.structure = StructureModel(cfg.structure, environment, run.vmap.voxel_size)
        hand_structure(labeller, run.structure)  # weights that read its evidence see it as of the previous scan
        # voxels on a slab, column or beam take its object (geometry decides); not where the truth stands in for
        # the objects (`--oracle objects` measures what perfect embeddings give the clustering)
        if cfg.cluster.structure_objects and cfg.label.oracle != "objects":
            run.clusterer.owner = run.structure.object_keys
    if labeller.name != FALLBACK_LABELLER and not isinstance(labeller, TruthStandIn):  # the baseline learnt nothing
        run.distribution = DistributionCheck(Reference.load(), notice)
    return run, (s for part in (skipped, [first], it) for s in part)


def _loop(
    run: _Run, frames: Iterator[Frame], sinks: Sequence[Sink], notice: Callable[[str], None]
) -> OutputError | None:
    """Every frame through the stages, the map to the sinks every `rerun.map_every` scans. Ctrl-C, or a sink
    that cannot write (a full disk, returned), ends it early and marks the run interrupted."""
    map_every = max(1, run.cfg.rerun.map_every)  # the one place that decides how often the map is re-sent
    try:
        for frame in frames:
            run.add(frame)
            if run.distribution is not None:
                run.distribution.check(frame)
            if run.summary.scans % map_every == 0:
                t0 = perf_counter()
                cloud = shown_map(run.vmap, run.clusterer)
                model = run.structure
                elements = model.elements(run.vmap, scans=False) if model is not None else []
                for sink in sinks:
                    sink.map_update(cloud, frame.seq)
                    if model is not None:
                        sink.structure(elements, frame.seq, [])
                frame.timings_ms["sinks"] = frame.timings_ms.get("sinks", 0.0) + (perf_counter() - t0) * 1e3
                run.last_map_seq = frame.seq
            for name in STAGES:
                run.timings[name] += frame.timings_ms.get(name, 0.0)
    except KeyboardInterrupt:
        run.summary.interrupted = True
        notice(f"interrupted after {run.summary.scans} scans; finishing the outputs")
    except OutputError as exc:  # a sink cannot write (a full disk): stop, and finish every other output
        run.summary.interrupted = True
        notice(f"stopped after {run.summary.scans} scans ({exc}); finishing the other outputs")
        return exc
    return None


def _finish(
    run: _Run,
    sinks: Sequence[Sink],
    info: RunInfo,
    on_final_map: MapHook | None,
    error: BaseException | None,
    notice: Callable[[str], None] = lambda _text: None,
) -> None:
    """End of run: consolidation and its merges to the sinks, the on-demand analyses (not after an
    interruption), the summary, the final map and `end()` to every sink; then the first error is raised."""
    summary, vmap = run.summary, run.vmap
    if run.seqs:
        merges, changed = consolidate(vmap, run.clusterer, run.labeller, run.seqs[-1], summary)
        if run.structure is not None:  # every changed region refitted, and the fused classes over the votes
            error = _finish_structure(run, sinks, notice) or error
            if run.clusterer.owner is not None:  # the elements as refitted at the end take their voxels
                run.clusterer.claim(vmap, run.seqs[-1])
                vmap.instance_ids[:] = run.clusterer.shown_ids(vmap.instance_ids)
            changed = True
        if changed:
            run.last_map_seq = None  # the map changed: the sinks get it again below
        for sink in sinks:
            try:
                sink.merges(merges, run.seqs[-1])
            except OutputError as exc:
                error = error or exc
    if on_final_map is not None and not summary.interrupted and len(vmap):
        try:
            on_final_map(final_cloud(vmap), sinks)
        except (Exception, KeyboardInterrupt) as exc:  # the run's own outputs are still finished below
            error = exc
    with _no_interrupts():
        final = final_cloud(vmap)
        _fill_summary(summary, vmap, final, run.timings, perf_counter() - run.t_start)
        summary.skipped_messages = len(info.report.skipped)
        summary.damaged_log = info.report.damage is not None
        summary.damage = info.report.damage
        summary.level_tilt_deg = run.registrar.tilt_deg
        summary.warnings = list(run.distribution.warnings) if run.distribution is not None else []
        summary.warnings += run.notes  # the structure model's (no floor found: the network's labels alone)
        for sink in sinks:  # one sink that cannot write does not keep the others from finishing
            try:
                if run.seqs and run.last_map_seq != run.seqs[-1]:
                    sink.map_update(final, run.seqs[-1])
                sink.end(summary, final)
            except OutputError as exc:
                error = error or exc
    if error is not None:
        raise error


def _finish_structure(run: _Run, sinks: Sequence[Sink], notice: Callable[[str], None]) -> OutputError | None:
    """The structure model over every region still waiting, its classes into the map, one warning where it
    found no floor (the labels are then the network's alone), and its elements to the sinks."""
    model, vmap, error = run.structure, run.vmap, None
    assert model is not None
    model.finish(vmap)
    model.apply(vmap)
    warning = model.warning()
    if warning:
        notice(warning)
        run.notes.append(warning)
    elements = model.elements(vmap)
    for e in elements:
        run.summary.structure_elements[e.kind.value] = run.summary.structure_elements.get(e.kind.value, 0) + 1
    for sink in sinks:
        try:
            sink.structure(elements, run.seqs[-1], run.notes)
        except OutputError as exc:
            error = error or exc
    return error


def _result(run: _Run) -> StreamResult:
    """The result of a finished run, with the trajectory error where the log gave true poses."""
    pose_arr = np.array(run.poses).reshape(-1, 4, 4)
    has_truth = np.array([p is not None for p in run.true_poses], bool)
    truth = None
    trajectory = None
    if has_truth.sum() >= 2:  # frames whose true pose the log could not give are left out
        truth = np.full((len(run.poses), 4, 4), np.nan)
        truth[has_truth] = np.array([p for p in run.true_poses if p is not None])
        trajectory = trajectory_error(pose_arr[has_truth], truth[has_truth])
    return StreamResult(
        summary=run.summary,
        vmap=run.vmap,
        environment=run.environment,
        labeller=run.labeller.name,
        seqs=np.array(run.seqs, np.int64),
        stamps_ns=np.array(run.stamps, np.int64),
        poses=pose_arr,
        true_poses=truth,
        trajectory=trajectory,
        notes=run.notes,
        structure=run.structure,
    )


def _close_all(sinks: Sequence[Sink]) -> None:
    """Close every sink, even when one fails; the first failure is raised after all were tried."""
    error: BaseException | None = None
    for sink in sinks:
        try:
            sink.close()
        except Exception as exc:
            error = error or exc
    if error is not None:
        raise error


def _fill_summary(
    summary: RunSummary, vmap: VoxelMap, final: LabelledCloud, timings: dict[str, float], wall: float
) -> None:
    summary.map_voxels = len(vmap)
    ids = vmap.instance_ids
    summary.instances = len(np.unique(ids[ids > 0]))
    summary.instances_per_class = instances_per_class(final)
    n = max(summary.scans, 1)
    summary.mean_timings_ms = {k: v / n for k, v in timings.items()}
    summary.wall_time_s = wall
    summary.scans_per_second = summary.scans / wall if wall > 0 else 0.0
