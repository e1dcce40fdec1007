"""Frames for the sink tests: real VLP-16 scans from ../shared/data, carried through the fields the stages fill in.

The stages are not run here (they have their own tests); poses follow a known path and labels come from a
simple geometric rule, so every value a sink writes can be checked against what went in.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from aftershock.pipeline.classes import UNLABELLED, SemanticClass
from aftershock.pipeline.geometry import voxel_downsample
from aftershock.pipeline.pointcloud2 import decode_pointcloud2, valid_mask
from aftershock.pipeline.types import Frame, InstanceMerge, LabelledCloud, Labels, MapRows, Scan

VELODYNE = "velodyne_vlp16_indoor.mcap"


def read_scans(path: Path) -> list[Scan]:
    """Every PointCloud2 of an MCAP as a Scan (invalid returns dropped), with its header stamp and log time."""
    scans = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for seq, (_, channel, message, msg) in enumerate(reader.iter_decoded_messages()):
            cloud = decode_pointcloud2(msg)
            c = cloud.columns
            xyz = np.stack([c["x"], c["y"], c["z"]], axis=1).astype(np.float64)
            ok = valid_mask(xyz)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            scans.append(
                Scan(
                    stamp_ns=stamp,
                    points=xyz[ok],
                    seq=seq,
                    frame_id=msg.header.frame_id,
                    intensity=c["intensity"][ok].astype(np.float32),
                    times=c["time"][ok].astype(np.float64),
                    log_time_ns=message.log_time,
                    topic=channel.topic,
                )
            )
    return scans


def pose_at(seq: int) -> np.ndarray:
    """A known path: 0.25 m forward and 3 degrees of yaw per scan, 0.4 m above the floor."""
    yaw = np.deg2rad(3.0 * seq)
    m = np.eye(4)
    m[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    m[:3, 3] = [0.25 * seq, 0.0, 0.4]
    return m


def label_rule(world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Classes from height (floor, wall, ceiling) and instances from 2 m cells of the walls."""
    z = world[:, 2]
    cls = np.full(len(world), SemanticClass.WALL, np.uint16)
    cls[z < 0.1] = SemanticClass.FLOOR
    cls[z > 2.2] = SemanticClass.CEILING
    cell = np.floor(world[:, :2] / 2.0).astype(np.int64)
    inst = ((cell[:, 0] + 50) * 100 + (cell[:, 1] + 50)).astype(np.uint32)
    inst[cls != SemanticClass.WALL] = 0
    return cls, inst


def make_frame(scan: Scan, *, labelled_range_m: float = 6.0) -> Frame:
    """The frame as it leaves the clustering stage."""
    pose = pose_at(scan.seq)
    world = scan.points @ pose[:3, :3].T + pose[:3, 3]
    keep = np.hypot(scan.points[:, 0], scan.points[:, 1]) < labelled_range_m
    cls, inst = label_rule(world)
    labels = Labels(np.where(keep, cls, UNLABELLED).astype(np.uint16), np.where(keep, inst, 0).astype(np.uint32))
    rng = np.random.default_rng(scan.seq)
    emb = rng.normal(size=(len(scan), 8)).astype(np.float32) + cls[:, None].astype(np.float32)
    labels.embeddings = emb / np.linalg.norm(emb, axis=1, keepdims=True)
    # What the labelling stage hands over, for a map of this scan alone (one row per 10 cm voxel of it).
    kept = np.flatnonzero(keep)
    first, rows = voxel_downsample(world[kept], 0.1)
    map_rows = MapRows(points=kept, rows=rows, new_rows=np.arange(len(first)), first_points=kept[first])
    frame = Frame(scan=scan, pose=pose, world_points=world, map_rows=map_rows, labels=labels)
    frame.timings_ms = {"register": 10.0 + scan.seq, "label": 20.0 + scan.seq, "cluster": 5.0}
    frame.counts = {"kept": int(keep.sum()), "new": int(keep.sum()) // 2}
    if scan.seq == 1:
        frame.merges = [InstanceMerge(into=int(inst[keep].max()), merged=(9999,), seq=1)]
    return frame


def frames(path: Path, repeat: int = 1) -> Iterator[Frame]:
    """The scans of a log as frames; `repeat` > 1 replays them with increasing seq and stamps (a longer run)."""
    scans = read_scans(path)
    period = scans[-1].stamp_ns - scans[0].stamp_ns + 100_000_000
    for r in range(repeat):
        for s in scans:
            seq = r * len(scans) + s.seq
            shifted = s.select(np.ones(len(s), bool))
            shifted.seq = seq
            shifted.stamp_ns = s.stamp_ns + r * period
            shifted.log_time_ns = (s.log_time_ns or s.stamp_ns) + r * period
            yield make_frame(shifted)


def map_of(frames_: list[Frame]) -> LabelledCloud:
    """The accumulated labelled map of the labelled points of some frames."""
    pts, cls, inst = [], [], []
    for f in frames_:
        assert f.labels is not None and f.world_points is not None and f.map_rows is not None
        pts.append(f.world_points[f.map_rows.points])
        cls.append(f.labels.class_ids[f.map_rows.points])
        inst.append(f.labels.instance_ids[f.map_rows.points])
    return LabelledCloud(np.concatenate(pts), class_ids=np.concatenate(cls), instance_ids=np.concatenate(inst))
