"""The Rerun layout (entity paths, timelines) and the default blueprint: the site in 3D, with the per-stage
time series and the text log beside it.

Layers that repeat the current scan (raw, the log's own clouds, and the full-resolution debug layers) start
hidden so the labelled scan reads clearly over the map; each can be switched on in the viewer's blueprint
panel.
See `sinks.rerun_sink` for what each entity holds.
"""

from __future__ import annotations

from typing import Final

import rerun.blueprint as rrb

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

HIDDEN_BY_DEFAULT: Final[tuple[str, ...]] = (
    RAW,
    REGISTERED,
    LABELLED,
    INSTANCES,
    EMBEDDING,
)


def default_blueprint(timeline: str = SCAN_TIMELINE, log_topic: str | None = None) -> rrb.Blueprint:
    """The 3D view of `world/` (three quarters of the width) beside time per stage, counts and the log.
    With `log_topic`, the view also holds the log's own clouds of that topic (as Rerun's MCAP import names
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
    side = rrb.Vertical(
        rrb.TimeSeriesView(origin=STATS_TIME, name="time per stage (ms)", plot_legend=rrb.Corner2D.LeftTop),
        rrb.TimeSeriesView(origin=STATS_COUNTS, name="counts", plot_legend=rrb.Corner2D.LeftTop),
        rrb.TextLogView(origin=LOG, name="log"),
        row_shares=[2, 2, 1],
    )
    return rrb.Blueprint(
        rrb.Horizontal(site, side, column_shares=[3, 1]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=timeline),
        collapse_panels=False,
    )
