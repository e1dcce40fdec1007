"""The clustering stage: each labelled frame's new map rows get instance ids, its kept points the ids shown."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from time import perf_counter

from aftershock.pipeline.cluster.clusterer import InstanceClusterer
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import VoxelMap


def cluster_frame(frame: Frame, vmap: VoxelMap, clusterer: InstanceClusterer) -> Frame:
    """Cluster the rows the labelling stage opened (`frame.map_rows`) and label the frame's kept points."""
    rows = frame.map_rows
    if rows is not None and len(rows.new_rows):
        merges = clusterer.add(vmap, rows.new_rows, frame.seq)
        frame.merges.extend(merges)
        frame.counts["merges"] = len(merges)
    if frame.labels is not None and rows is not None and len(rows.points):
        frame.labels.instance_ids[rows.points] = clusterer.shown_ids(vmap.instance_ids[rows.rows], rows.rows)
    frame.counts["instances_opened"] = clusterer.next_id - 1
    return frame


def cluster_stage(frames: Iterable[Frame], vmap: VoxelMap, clusterer: InstanceClusterer) -> Iterator[Frame]:
    for frame in frames:
        t0 = perf_counter()
        cluster_frame(frame, vmap, clusterer)
        frame.timings_ms["cluster"] = (perf_counter() - t0) * 1e3
        yield frame
