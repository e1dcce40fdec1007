"""Sinks: the only code that writes. Each implements `aftershock.pipeline.sink.Sink` (the interface the stream
calls, owned by the stream) and is told about every frame after every stage, the growing map, the on-demand
layers and the end of the run.

- `rerun_sink.RerunSink`: an .rrd recording and/or a live viewer (layout in `rerun_blueprint`);
- `mcap_sink.McapSink`: labelled PointCloud2 scans and PoseStamped poses in an MCAP file;
- `files.FileExportSink`: the labelled PLY map, TUM and KITTI poses, a JSON summary.

They are imported from their modules (rerun and mcap load only when asked for).
"""
