"""The layers of the on-demand analyses of the final map: LRGNet's segmentation (`world/refined`) with one
object's growth on the `lrgnet_step` timeline, and the damage (`world/damage/...`: crack points, crack boxes,
story planes, drift arrows). `static` when no scan's time is set (a command without a run)."""

from __future__ import annotations

import numpy as np
import rerun as rr

from aftershock.pipeline.types import DamageFound, LabelledCloud
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks import rerun_convert as C


def log_refined(
    rec: rr.RecordingStream, cloud: LabelledCloud, steps: list[tuple[np.ndarray, np.ndarray]], static: bool
) -> None:
    """The segmentation, then each step of the growth (inliers, neighbours); growth steps leave the recording
    with no time set (the caller sets the scan's again)."""
    rec.log(L.REFINED, *C.refined_points(cloud), static=static)
    if not steps:
        return
    rec.reset_time()
    for i, (inliers, neighbours) in enumerate(steps):
        rec.set_time(L.LRGNET_STEP_TIMELINE, sequence=i)
        inlier_points, neighbour_points = C.growth_points(cloud, inliers, neighbours)
        rec.log(f"{L.REFINED_GROWTH}/inliers", inlier_points)
        rec.log(f"{L.REFINED_GROWTH}/neighbours", neighbour_points)
        text = f"step {i}: {len(inliers)} inliers, {len(neighbours)} neighbours"
        rec.log(f"{L.LOG}/lrgnet", rr.TextLog(text, level="DEBUG"))
    rec.reset_time()


def log_damage(
    rec: rr.RecordingStream, found: DamageFound, bounds: tuple[np.ndarray, np.ndarray] | None, static: bool
) -> None:
    """Crack points and boxes, and each story's plane over the map's extent (`bounds`) with its drift arrow."""
    if found.crack_points is not None and len(found.crack_points):
        rec.log(L.CRACK_POINTS, *C.crack_points(found.crack_points), static=static)
    if found.cracks:
        rec.log(L.CRACKS, C.crack_boxes(found.cracks), static=static)
    if not found.stories:
        return
    planes, arrows = C.story_layers(found.stories, bounds)
    for index, box, tag in planes:
        rec.log(f"{L.STORIES}/s{index}", box, static=static)
        rec.log(f"{L.STORIES}/s{index}/label", tag, static=static)
    if arrows is not None:
        rec.log(L.DRIFT, arrows, static=static)
