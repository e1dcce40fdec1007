"""Sinks: the only code that writes. Each implements `sinks.base.Sink` and is told about every frame after
every stage, the growing map, the on-demand layers and the end of the run.

- `sinks.rerun_sink.RerunSink`: an .rrd recording and/or a live viewer (layout in `sinks.rerun_blueprint`);
- `sinks.mcap_sink.McapSink`: labelled PointCloud2 scans and PoseStamped poses in an MCAP file;
- `sinks.files.FileExportSink`: the labelled PLY map, TUM and KITTI poses, a JSON summary.

They are imported from their modules (rerun and mcap load only when asked for).
"""

from aftershock.sinks.base import Sink, Stage

__all__ = ["Sink", "Stage"]
