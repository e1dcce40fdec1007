"""The structure stage of the stream: after the network labelled a scan's new voxels, the structure model takes
them, refits what changed (within its budget) and writes the fused classes into the map and the scan's labels."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from time import perf_counter

import numpy as np

from aftershock.pipeline.structure.model import StructureModel
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import VoxelMap


def structure_frame(frame: Frame, vmap: VoxelMap, model: StructureModel) -> Frame:
    if frame.pose is not None and np.isfinite(frame.pose).all():
        model.observe(vmap, frame.pose[:3, 3])
        model.update(vmap, float(frame.pose[2, 3]))
    model.apply(vmap, frame.rewritten)
    kept = frame.map_rows
    if frame.labels is not None and kept is not None and len(kept.rows):
        frame.labels.class_ids[kept.points] = vmap.class_ids[kept.rows]
        if frame.labels.scores is not None:
            frame.labels.scores[kept.points] = vmap.scores[kept.rows]
    return frame


def structure_stage(frames: Iterable[Frame], vmap: VoxelMap, model: StructureModel | None) -> Iterator[Frame]:
    """Each frame through the structure model (`None`: the stage is off and costs nothing)."""
    for frame in frames:
        if model is not None:
            t0 = perf_counter()
            structure_frame(frame, vmap, model)
            # added to the time `explain` took in the label stage (the new voxels onto the elements found)
            frame.timings_ms["structure"] = frame.timings_ms.get("structure", 0.0) + (perf_counter() - t0) * 1e3
        yield frame
