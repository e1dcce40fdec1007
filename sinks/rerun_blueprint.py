"""The Rerun layout (entity paths, timelines) and the default blueprint: a "site" tab with the map in 3D, a
plan (the map from above) and the class legend, and an "engineering" tab with the per-stage time series,
counts and the text log.

Layers that repeat the current scan (raw, the log's own clouds, and the full-resolution debug layers) start
hidden so the labelled scan reads clearly over the map; each can be switched on in the viewer's blueprint
panel.
See `sinks.rerun_sink` for what each entity holds.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from aftershock.pipeline.classes import CLASS_COLORS, CLASS_NAMES, UNCERTAIN_COLOR, UNLABELLED_COLOR

# Timelines. `message_log_time` and `ros2_timestamp` are the names Rerun's own MCAP import gives the MCAP log
# time and the ROS 2 header stamp (absolute ns), so a recording lines up with the imported log in one viewer.
SCAN_TIMELINE: Final = "scan"
SENSOR_TIMELINE: Final = "sensor_time"
MCAP_LOG_TIMELINE: Final = "message_log_time"
MCAP_STAMP_TIMELINE: Final = "ros2_timestamp"
LRGNET_STEP_TIMELINE: Final = "lrgnet_step"

WORLD: Final = "world"
MAP: Final = "world/map"
UNCERTAIN: Final = "world/uncertain"  # map voxels the labeller is unsure of, tiled as the map
TRAJECTORY: Final = "world/trajectory"
ROBOT: Final = "world/robot"
RAW: Final = "world/robot/raw"
LOG_FRAME: Final = "world/robot/log_frame"
REGISTERED: Final = "world/scan/registered"
LABELS: Final = "world/scan/labels"
LABELLED: Final = "world/scan/labelled"
INSTANCES: Final = "world/scan/instances"
EMBEDDING: Final = "world/scan/embedding"
REFINED: Final = "world/refined"
REFINED_GROWTH: Final = "world/refined/growth"
CRACK_POINTS: Final = "world/damage/crack_points"
CRACKS: Final = "world/damage/cracks"
STORIES: Final = "world/damage/stories"
DRIFT: Final = "world/damage/drift"
STATS_TIME: Final = "stats/time_ms"
STATS_COUNTS: Final = "stats/counts"
LOG: Final = "log"
LEGEND: Final = "legend"  # one coloured disc and name per class, always in view
LEGEND_SWATCHES: Final = "legend/swatches"
LEGEND_NAMES: Final = "legend/names"
LEGEND_ROWS: Final = 8  # the legend's discs in columns of this many
LEGEND_COLUMN_STEP: Final = 5.0  # legend units between its columns (a disc is 0.8 across; names need room)
PLAN_EYE_HEIGHT_M: Final = 20.0  # the plan's eye above the start of the run, looking straight down

HIDDEN_BY_DEFAULT: Final[tuple[str, ...]] = (
    RAW,
    REGISTERED,
    LABELLED,
    INSTANCES,
    EMBEDDING,
)


def legend() -> tuple[rr.Points2D, rr.Points2D]:
    """The legend: a coloured disc per class (then unlabelled, and the colour of voxels drawn as uncertain), in
    class order down columns, and beside each its name in white (a label takes its point's colour, which on some
    discs would not read)."""
    names = [*CLASS_NAMES, "unlabelled", "uncertain label"]
    colors = np.vstack([CLASS_COLORS, UNLABELLED_COLOR[None], UNCERTAIN_COLOR[None]])
    k = np.arange(len(names))
    at = np.c_[(k // LEGEND_ROWS) * LEGEND_COLUMN_STEP, k % LEGEND_ROWS].astype(np.float64)
    discs = rr.Points2D(at, colors=colors, radii=0.4)
    text = rr.Points2D(at + np.array([2.0, -0.45]), colors=[235, 235, 235], radii=0.01, labels=names, show_labels=True)
    return discs, text


def default_blueprint(timeline: str = SCAN_TIMELINE, log_topic: str | None = None) -> rrb.Blueprint:
    """Tab "site": the 3D view of `world/` (three fifths of the width) beside the plan (the map, trajectory and
    damage seen from above) and the class legend. Tab "engineering": time per stage, counts and the log.
    With `log_topic`, the 3D view also holds the log's own clouds of that topic (as Rerun's MCAP import names
    the entity), hidden at first."""
    hidden = list(HIDDEN_BY_DEFAULT)
    contents = ["$origin/**"]
    if log_topic:
        topic = "/" + log_topic.lstrip("/")
        contents.append(f"{topic}/**")
        hidden.append(topic)
    site = rrb.Spatial3DView(
        origin=WORLD,
        name="site",
        contents=contents,
        background=[18, 18, 22],
        line_grid=rrb.LineGrid3D(visible=True, spacing=1.0, color=[80, 80, 80, 90]),
        overrides={path: rrb.EntityBehavior(visible=False) for path in hidden},
    )
    plan = rrb.Spatial3DView(
        origin=WORLD,
        name="plan (from above)",
        contents=[f"{MAP}/**", f"{TRAJECTORY}/**", f"{ROBOT}", "world/damage/**", f"{REFINED}/**"],
        background=[18, 18, 22],
        line_grid=rrb.LineGrid3D(visible=True, spacing=1.0, color=[80, 80, 80, 90]),
        eye_controls=rrb.EyeControls3D(
            kind=rrb.Eye3DKind.Orbital, position=[0.0, -0.01, PLAN_EYE_HEIGHT_M], look_target=[0.0, 0.0, 0.0],
            eye_up=[0.0, 0.0, 1.0],
        ),
        overrides={REFINED: rrb.EntityBehavior(visible=False)},
    )  # fmt: skip
    bounds = rrb.VisualBounds2D(x_range=[-1.0, 2 * LEGEND_COLUMN_STEP], y_range=[-1.0, float(LEGEND_ROWS)])
    key = rrb.Spatial2DView(origin=LEGEND, name="classes", background=[30, 30, 36], visual_bounds=bounds)
    engineering = rrb.Vertical(
        rrb.TimeSeriesView(origin=STATS_TIME, name="time per stage (ms)", plot_legend=rrb.Corner2D.LeftTop),
        rrb.TimeSeriesView(origin=STATS_COUNTS, name="counts", plot_legend=rrb.Corner2D.LeftTop),
        rrb.TextLogView(origin=LOG, name="log"),
        row_shares=[2, 2, 1],
        name="engineering",
    )
    tab_site = rrb.Horizontal(site, rrb.Vertical(plan, key, row_shares=[3, 2]), column_shares=[3, 2], name="site")
    return rrb.Blueprint(
        rrb.Tabs(tab_site, engineering, active_tab=0),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=timeline),
        collapse_panels=False,
    )
