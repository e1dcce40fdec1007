"""A Rerun recording of an on-demand analysis (`cracks --save`, `drift --save`): the analysed cloud as the
map, with the damage layers over it, in the default layout (legend and plan included)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.types import Crack, LabelledCloud, RunSummary, Story


def save_recording(
    path: Path,
    cloud: LabelledCloud,
    cfg: RerunConfig,
    force: bool,
    cracks: list[Crack] | None = None,
    crack_points: LabelledCloud | None = None,
    stories: list[Story] | None = None,
    report: dict[str, Any] | None = None,
) -> Path:
    """Write `path` (checked like every output): the cloud, then the cracks and stories found on it."""
    from aftershock.sinks.rerun_sink import RerunSink

    sink = RerunSink(path, False, None, cfg, force)
    try:
        sink.end(RunSummary(points=len(cloud), map_voxels=len(cloud)), cloud)  # the map first: stories span it
        sink.damage(cracks or [], crack_points, stories or [], report)
    finally:
        sink.close()
    return path
