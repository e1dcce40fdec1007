"""The shared vocabulary: small dataclasses over numpy arrays that every stage, source and sink passes.

Conventions (fixed, relied on everywhere):
- positions in metres, float64 (N, 3); poses are 4 x 4 homogeneous float64 matrices, sensor -> world;
- `Scan.stamp_ns` is the scan's time in nanoseconds (the message header stamp, else the log time);
- `Scan.times` are per-point times in seconds *relative to the stamp* (may be negative);
- class ids follow `pipeline.classes` (65535 = unlabelled); instance id 0 = "no object".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aftershock.pipeline.classes import UNLABELLED


def _check_len(name: str, arr: np.ndarray | None, n: int) -> None:
    if arr is not None and len(arr) != n:
        raise ValueError(f"{name} has {len(arr)} entries for {n} points")


@dataclass(slots=True)
class Scan:
    """One sweep of a LiDAR as it comes out of a source."""

    stamp_ns: int
    points: np.ndarray  # (N, 3) float64, sensor frame
    seq: int = 0
    frame_id: str = ""
    intensity: np.ndarray | None = None  # (N,) float32
    colors: np.ndarray | None = None  # (N, 3) uint8
    times: np.ndarray | None = None  # (N,) float64 seconds relative to stamp_ns
    ring: np.ndarray | None = None  # (N,) uint16
    class_ids: np.ndarray | None = None  # (N,) uint16 ground truth
    instance_ids: np.ndarray | None = None  # (N,) uint32 ground truth
    gt_pose: np.ndarray | None = None  # (4, 4) true sensor pose in the world, when the log has it
    log_time_ns: int | None = None  # when the message was logged (MCAP log time), for viewer alignment
    topic: str = ""

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        n = len(self.points)
        for name in ("intensity", "colors", "times", "ring", "class_ids", "instance_ids"):
            _check_len(name, getattr(self, name), n)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

    @property
    def has_ground_truth(self) -> bool:
        return self.class_ids is not None and self.instance_ids is not None

    def select(self, mask: np.ndarray) -> Scan:
        """The same scan restricted to the points of a boolean mask or index array; every per-point array follows."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]

        return Scan(
            stamp_ns=self.stamp_ns,
            points=self.points[mask],
            seq=self.seq,
            frame_id=self.frame_id,
            intensity=pick(self.intensity),
            colors=pick(self.colors),
            times=pick(self.times),
            ring=pick(self.ring),
            class_ids=pick(self.class_ids),
            instance_ids=pick(self.instance_ids),
            gt_pose=self.gt_pose,
            log_time_ns=self.log_time_ns,
            topic=self.topic,
        )


@dataclass(slots=True)
class Labels:
    """Per-point results of the labelling and clustering stages, aligned with the points they describe."""

    class_ids: np.ndarray  # (N,) uint16, UNLABELLED where not predicted
    instance_ids: np.ndarray  # (N,) uint32, 0 = no object
    embeddings: np.ndarray | None = None  # (N, D) float32 unit vectors (MCPNet)
    scores: np.ndarray | None = None  # (N,) float32 confidence of the class

    @staticmethod
    def empty(n: int) -> Labels:
        return Labels(np.full(n, UNLABELLED, np.uint16), np.zeros(n, np.uint32))


@dataclass(slots=True)
class InstanceMerge:
    """Instances joined by the clustering stage: every id in `merged` now reads as `into`."""

    into: int
    merged: tuple[int, ...]
    seq: int


@dataclass(frozen=True, slots=True)
class MapRows:
    """What the labelling stage did to the map with one scan, for the stages and sinks after it: the points it
    kept (the range filter), the map row of each, the rows the scan opened, and the first kept point of every
    map voxel the scan fell in (one point per voxel, in row order)."""

    points: np.ndarray  # (K,) int64 indices into the scan of the kept points, ascending
    rows: np.ndarray  # (K,) the map row of each kept point
    new_rows: np.ndarray  # rows the scan opened, in first-point order
    first_points: np.ndarray  # indices into the scan of the first kept point of each voxel the scan fell in
    # new rows labelled before the labeller (on a confirmed structural element: class, score and embedding
    # written); the labeller was given the rest
    given: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        _check_len("rows", self.rows, len(self.points))

    @staticmethod
    def empty() -> MapRows:
        none = np.zeros(0, np.int64)
        return MapRows(none, none, none, none)


@dataclass(slots=True)
class Frame:
    """A scan on its way through the stages; each stage fills in its part and records how long it took."""

    scan: Scan
    pose: np.ndarray | None = None  # (4, 4) estimated sensor pose, world <- sensor (end of sweep)
    world_points: np.ndarray | None = None  # (N, 3) the deskewed scan in the world frame
    # (4, 4) estimated sensor pose at `scan.stamp_ns` (equals `pose` unless the sweep was deskewed);
    # compare this one with `scan.gt_pose` and write it with the stamp in pose files.
    stamp_pose: np.ndarray | None = None
    registration_ok: bool = True
    registration_note: str = ""
    map_rows: MapRows | None = None  # what the labelling stage did to the map (None before it)
    # older map rows whose class or score the labeller rewrote with this scan (instance votes); None: it could
    # not say (any may have changed)
    rewritten: np.ndarray | None = None
    labels: Labels | None = None  # for the points of `scan` (unlabelled where not kept)
    merges: list[InstanceMerge] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def seq(self) -> int:
        return self.scan.seq


@dataclass(slots=True)
class LabelledCloud:
    """A labelled point cloud: the accumulated map, a PLY file, a region of interest."""

    points: np.ndarray  # (N, 3) float64
    colors: np.ndarray | None = None  # (N, 3) uint8
    intensity: np.ndarray | None = None  # (N,) float32
    class_ids: np.ndarray | None = None  # (N,) uint16
    instance_ids: np.ndarray | None = None  # (N,) uint32
    normals: np.ndarray | None = None  # (N, 3) float32
    # (N,) float32 in [0, 1]: the labeller's probability for the class each point carries (0 where unlabelled)
    confidence: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        n = len(self.points)
        for name in ("colors", "intensity", "class_ids", "instance_ids", "normals", "confidence"):
            _check_len(name, getattr(self, name), n)

    def __len__(self) -> int:
        return len(self.points)

    def select(self, mask: np.ndarray) -> LabelledCloud:
        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]

        return LabelledCloud(
            self.points[mask],
            pick(self.colors),
            pick(self.intensity),
            pick(self.class_ids),
            pick(self.instance_ids),
            pick(self.normals),
            pick(self.confidence),
        )


@dataclass(slots=True)
class Crack:
    """One crack: a connected group of crack points measured on its own surface plane."""

    instance_id: int
    center: np.ndarray  # (3,) metres
    length_m: float
    width_m: float
    num_points: int
    axis: np.ndarray  # (3,) unit direction of the length
    normal: np.ndarray  # (3,) unit normal of the surface plane
    severe: bool
    width_resolved: bool = True  # False: narrower than the point spacing; width_m is then the spacing
    max_width_m: float = float("nan")  # widest part of the opening (90th percentile over the crack's slices)
    rect_width_m: float = float("nan")  # short side of the minimum-area rectangle (the whole group's extent)
    area_width_m: float = float("nan")  # mean width: its points' area (points x spacing^2) over its length
    depth_contrast: float = float("nan")  # how far its deepest points lie behind the surface around, in noise units
    chroma_contrast: float = float("nan")  # how far its hue lies from the surface around, % of chromaticity
    resolvable_m: float = float("nan")  # narrowest opening the scan can measure there (spacing, noise)


@dataclass(slots=True)
class Story:
    """One floor or ceiling plane and how far it moved against the lowest plane. Drift and tilt are None where
    they were not measured (one slab alone has nothing to be measured against), and `reason` says why; the
    lowest of several slabs is the reference (0 by definition, `reason` says so)."""

    index: int
    height_m: float
    plane: np.ndarray  # (4,) a, b, c, d with unit normal, ax + by + cz + d = 0
    drift_x_mm: float | None
    drift_y_mm: float | None
    drift_mm: float | None
    tilt_x_deg: float | None
    tilt_y_deg: float | None
    tilt_deg: float | None
    num_points: int
    reason: str | None = None


@dataclass(slots=True)
class DamageFound:
    """What a damage analysis hands the sinks: the cracks with their points (for the viewer), the story planes,
    and the whole report as JSON data (None where no report is written)."""

    cracks: list[Crack] = field(default_factory=list)
    crack_points: LabelledCloud | None = None
    stories: list[Story] = field(default_factory=list)
    report: dict[str, Any] | None = None


@dataclass(slots=True)
class SourceReport:
    """What a reader got past while reading, filled as it reads: the messages it skipped (log time in ns and
    why) and the damage that ended the log early (None: read to its end)."""

    skipped: list[tuple[int, str]] = field(default_factory=list)
    damage: str | None = None


@dataclass(slots=True)
class RunInfo:
    """What the sinks need to know before the first frame."""

    source: str  # what the user passed
    source_kind: str  # "mcap", "bag", "files", "sim"
    topic: str = ""
    environment: str = "indoor"
    labeller: str = ""
    log_start_ns: int | None = None
    # The viewer opens the log itself (MCAP with ROS 2 or Foxglove point clouds): the recording leaves raw
    # scans out and links the log's sensor frame to the estimated pose instead.
    raw_in_log: bool = False
    log_id: str = ""  # fingerprint of the log file, so a recording can be matched to its log
    report: SourceReport = field(default_factory=SourceReport)  # filled by the source while the run reads it


@dataclass(slots=True)
class RunSummary:
    """What a finished (or interrupted) run measured; the JSON summary is made from it."""

    scans: int = 0
    points: int = 0
    map_voxels: int = 0
    instances: int = 0
    instances_per_class: dict[str, int] = field(default_factory=dict)
    mean_timings_ms: dict[str, float] = field(default_factory=dict)
    wall_time_s: float = 0.0
    scans_per_second: float = 0.0
    registration_failures: list[int] = field(default_factory=list)
    interrupted: bool = False
    skipped_messages: int = 0  # undecodable scans or poses (or corrupt chunks) passed over with a warning
    damaged_log: bool = False  # the log ended early: cut off or damaged
    damage: str | None = None  # why it ended early
    fragments: int = 0  # instances before those under the minimum object size were hidden (`instances` = shown)
    final_merges: int = 0  # instances merged by the end-of-run consolidation
    level_tilt_deg: float | None = None  # how far the first scan's z was from up (None: world not levelled)
    structure_elements: dict[str, int] = field(default_factory=dict)  # structural elements found, per kind
    # what the run warned of once (scans outside the networks' training data, pipeline.scan_stats)
    warnings: list[str] = field(default_factory=list)
