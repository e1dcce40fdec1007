"""Labelling stage: range-filter each registered scan, open new voxels in the map, let a labeller label them.

A labeller is pluggable (`Labeller` protocol); `make_labeller(name, cfg, environment)` builds one by name. Each
lives in its own module `pipeline.labellers.<module>` exposing `create(cfg, name, environment) -> Labeller`
(a module may serve several names), imported only when asked for, so a labeller that needs weights costs
nothing until it is chosen.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator
from time import perf_counter
from typing import TYPE_CHECKING, Final, Protocol, runtime_checkable

import numpy as np

from aftershock.pipeline.config import Config, Environment
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Frame, Labels, MapRows
from aftershock.pipeline.voxel_map import VoxelMap

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel

# name -> module under pipeline.labellers
LABELLERS: Final[dict[str, str]] = {
    "mcpnet": "mcpnet",
    "region-growing": "region_growing",
    "mcpnet-nocontext": "mcpnet",
    "pointnet": "pointnet_online",
    "pointnet-temporal": "pointnet_online",
    "pointnet-spatial": "pointnet_online",
}
FALLBACK_LABELLER: Final = "region-growing"
# (map, the scan's new rows, the frame) -> the rows of them already labelled (class, score, embedding written) by
# another part of the stream: the structure model's confirmed elements. The labeller gets the rest.
Explain = Callable[[VoxelMap, np.ndarray, Frame], np.ndarray]


@runtime_checkable
class Labeller(Protocol):
    """Labels the voxels a scan opened, and says which neighbouring voxels may belong to the same object."""

    name: str
    embedding_dim: int  # width of the per-voxel embeddings it writes (0 = none)

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> np.ndarray | None:
        """Fill `class_ids`, `scores` (and where it has them `normals`, `embeddings`) of the new rows.
        `frame` is registered (pose, world points) and `frame.map_rows` says which points went into the map, and
        which new rows were labelled already (`given`: not among `new_rows`). Returns the older rows whose class
        or score it rewrote too (instance votes), or None when it cannot say (any may have changed)."""
        ...

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        """Per pair of (neighbouring) voxel rows: True where they should join the same instance."""
        ...

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        """After instances merged (the end of a run): their voxels may take the class the instance votes for
        (a labeller without instance votes does nothing)."""
        ...


@runtime_checkable
class StructureReader(Protocol):
    """A labeller whose network may read the structure model's evidence (#28): the stream hands it the live
    model (`pipeline.structure.StructureModel`) once, and updates it after every scan's labelling."""

    def use_structure(self, model: StructureModel) -> None: ...


def hand_structure(labeller: Labeller, model: StructureModel) -> None:
    """Give `labeller` the stream's structure model where it can read it (labellers that cannot ignore it)."""
    if isinstance(labeller, StructureReader):
        labeller.use_structure(model)


def make_labeller(name: str, cfg: Config, environment: Environment) -> Labeller:
    """The labeller called `name` for this environment (indoor or outdoor, decided by the caller); InputError
    if unknown, not built, or its weights are missing."""
    module_name = LABELLERS.get(name)
    if module_name is None:
        raise InputError(f"unknown labeller {name!r}; choose one of: {', '.join(LABELLERS)}")
    full = f"aftershock.pipeline.labellers.{module_name}"
    try:
        module = importlib.import_module(full)
    except ModuleNotFoundError as exc:
        if exc.name == full:
            raise InputError(f"labeller {name!r} is not available in this build") from None
        raise
    try:
        labeller = module.create(cfg, name, environment)
    except FileNotFoundError as exc:
        raise InputError(
            f"labeller {name!r}: weights not found ({exc.filename or exc}); see `aftershock train --help`"
        ) from None
    return labeller


def labelling_range(cfg: Config, environment: Environment) -> float:
    """Horizontal distance from the robot within which points are labelled (2 m indoors, 10 m outdoors)."""
    return cfg.label.outdoor_range_m if environment is Environment.OUTDOOR else cfg.label.indoor_range_m


def label_frame(
    frame: Frame, vmap: VoxelMap, labeller: Labeller, range_m: float, explain: Explain | None = None
) -> Frame:
    scan = frame.scan
    n = len(scan)
    if not frame.registration_ok or frame.world_points is None:
        frame.map_rows = MapRows.empty()
        frame.rewritten = frame.map_rows.new_rows
        frame.labels = Labels.empty(n)
        frame.counts.update(kept=0, new_voxels=0, map_voxels=len(vmap))
        return frame
    idx = np.flatnonzero(np.hypot(scan.points[:, 0], scan.points[:, 1]) <= range_m)

    def pick(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[idx]

    new_rows, rows = vmap.insert(
        frame.world_points[idx], pick(scan.colors), scan.seq, pick(scan.class_ids), pick(scan.instance_ids)
    )
    _, first = np.unique(rows, return_index=True)  # rows are numbered in first-point order
    given = new_rows[:0]
    if explain is not None and frame.pose is not None:
        t0 = perf_counter()
        given = explain(vmap, new_rows, frame)
        # the structure model's work, timed as its own
        frame.timings_ms["structure"] = frame.timings_ms.get("structure", 0.0) + (perf_counter() - t0) * 1e3
    frame.map_rows = MapRows(points=idx, rows=rows, new_rows=new_rows, first_points=idx[first], given=given)
    if len(new_rows):
        rest = new_rows[~np.isin(new_rows, given)] if len(given) else new_rows
        frame.rewritten = labeller.label(vmap, rest, frame)
    else:
        frame.rewritten = new_rows
    labels = Labels.empty(n)
    labels.class_ids[idx] = vmap.class_ids[rows]
    labels.instance_ids[idx] = vmap.instance_ids[rows]
    labels.scores = np.zeros(n, np.float32)
    labels.scores[idx] = vmap.scores[rows]
    if vmap.embedding_dim:
        labels.embeddings = np.zeros((n, vmap.embedding_dim), np.float32)
        labels.embeddings[idx] = vmap.embeddings[rows]
    frame.labels = labels
    frame.counts.update(kept=len(idx), new_voxels=len(new_rows), map_voxels=len(vmap))
    return frame


def label_stage(
    frames: Iterable[Frame], vmap: VoxelMap, labeller: Labeller, range_m: float, explain: Explain | None = None
) -> Iterator[Frame]:
    """Each frame labelled; with `explain`, the new voxels it explains skip the labeller (and its time is the
    `structure` stage's, not the label stage's)."""
    for frame in frames:
        t0 = perf_counter()
        label_frame(frame, vmap, labeller, range_m, explain)
        own = frame.timings_ms.get("structure", 0.0)
        frame.timings_ms["label"] = (perf_counter() - t0) * 1e3 - own
        yield frame
