"""Our types as Rerun archetypes: colours for scans, classes, instances and embeddings, point layers, the
trajectory, cracks and story planes. Pure functions (and the frozen embedding colouring): nothing is logged here.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import rerun as rr

from aftershock.pipeline.classes import (
    CLASS_COLORS,
    CLASS_NAMES,
    UNCERTAIN_COLOR,
    UNLABELLED,
    UNLABELLED_COLOR,
    instance_colors,
)
from aftershock.pipeline.geometry import voxel_downsample
from aftershock.pipeline.types import Crack, LabelledCloud, RunInfo, RunSummary, Scan, Story

DRIFT_ARROW_M_PER_MM: Final = 0.05  # drift arrows are drawn 50 times larger than life (1 mm -> 5 cm)
FIT_SAMPLE: Final = 20_000  # embeddings the colour projection is fitted on

SCAN_RADIUS: Final = rr.Radius.ui_points(1.5)
MAP_RADIUS_OF_VOXEL: Final = 0.2  # map points drawn with a world-space radius of this fraction of the voxel
UNCERTAIN_RADIUS_OF_VOXEL: Final = 0.35  # uncertain voxels drawn larger than the map's, over them
CRACK_RADIUS: Final = rr.Radius.ui_points(3.0)
TRAJECTORY_COLOR: Final = (255, 210, 0)
GROWTH_INLIER_COLOR: Final = (60, 220, 90)
GROWTH_NEIGHBOUR_COLOR: Final = (255, 200, 40)
CRACK_COLOR: Final = (255, 30, 60)
LABEL_CLEARANCE_M: Final = 0.3  # a crack this close to a fully labelled one gets its number only
MILD_CRACK_COLOR: Final = (255, 150, 0)

# A perceptually ordered ramp (viridis stops) for intensity colouring, interpolated per channel.
_RAMP: Final = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64)


def annotation_context() -> rr.AnnotationContext:
    """The class table (and the unlabelled id) as a Rerun annotation context."""
    infos = [(i, name, tuple(int(c) for c in CLASS_COLORS[i])) for i, name in enumerate(CLASS_NAMES)]
    infos.append((UNLABELLED, "unlabelled", tuple(int(c) for c in UNLABELLED_COLOR)))
    return rr.AnnotationContext(infos)


def ramp_colors(values: np.ndarray) -> np.ndarray:
    """Colours (N, 3) uint8 for scalar values, stretched between their 2nd and 98th percentiles."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(v) == 0:
        return np.zeros((0, 3), np.uint8)
    finite = v[np.isfinite(v)]
    lo, hi = np.percentile(finite, [2, 98]) if len(finite) else (0.0, 1.0)
    t = np.clip((np.nan_to_num(v, nan=lo) - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(_RAMP) - 1)
    stops = np.arange(len(_RAMP))
    return np.stack([np.interp(t, stops, _RAMP[:, c]) for c in range(3)], axis=1).astype(np.uint8)


class EmbeddingColors:
    """Embeddings (N, D) to RGB with a PCA fitted on the first batch and then frozen, so colours stay
    comparable from scan to scan."""

    def __init__(self) -> None:
        self.mean: np.ndarray | None = None
        self.axes: np.ndarray | None = None  # (D, 3)
        self.scale: np.ndarray | None = None  # (3,)

    def __call__(self, embeddings: np.ndarray) -> np.ndarray:
        e = np.asarray(embeddings, dtype=np.float32)
        if self.axes is None or self.axes.shape[0] != e.shape[1]:
            self._fit(e[:: max(1, len(e) // FIT_SAMPLE)].astype(np.float64))
        assert self.mean is not None and self.axes is not None and self.scale is not None
        # 0.5 + 0.5 * (e - mean) @ axes / scale, folded into one affine map
        gain = (0.5 * self.axes / self.scale).astype(np.float32)
        offset = (0.5 - self.mean @ (0.5 * self.axes / self.scale)).astype(np.float32)
        return (np.clip(e @ gain + offset, 0.0, 1.0) * 255).astype(np.uint8)

    def _fit(self, e: np.ndarray) -> None:
        d = e.shape[1]
        self.mean = e.mean(axis=0) if len(e) else np.zeros(d)
        axes = np.zeros((d, 3))
        if len(e) >= 2:
            _, _, vt = np.linalg.svd(e - self.mean, full_matrices=False)
            k = min(3, vt.shape[0])
            axes[:, :k] = vt[:k].T
        else:
            axes[: min(d, 3), : min(d, 3)] = np.eye(min(d, 3))
        self.axes = axes
        spread = ((e - self.mean) @ axes).std(axis=0) if len(e) >= 2 else np.ones(3)
        self.scale = np.maximum(2.0 * spread, 1e-6)


def datetime(ns: int) -> np.datetime64:
    return np.datetime64(int(ns), "ns")


def scan_colors(scan: Scan) -> np.ndarray | None:
    """The scan's own colours, else its intensity on the ramp, else none."""
    if scan.colors is not None:
        return scan.colors
    if scan.intensity is not None:
        return ramp_colors(scan.intensity)
    return None


def instance_colors_of(ids: np.ndarray) -> np.ndarray:
    """`instance_colors` computed once per distinct id (a scan has many points but few instances)."""
    unique, inverse = np.unique(ids, return_inverse=True)
    return instance_colors(unique)[inverse.reshape(-1)]


def raw_points(scan: Scan, voxel_m: float) -> rr.Points3D:
    """The raw scan in the sensor frame, one point per `voxel_m` voxel (all of them for 0)."""
    colors = scan_colors(scan)
    pts = scan.points
    if voxel_m > 0 and len(pts):
        keep, _ = voxel_downsample(pts, voxel_m)
        pts, colors = pts[keep], colors[keep] if colors is not None else None
    return rr.Points3D(pts, colors=colors, radii=SCAN_RADIUS)


def pose_transform(pose: np.ndarray) -> rr.Transform3D:
    """A 4 x 4 pose (parent <- child) as a transform."""
    return rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3])


def trajectory_strip(positions: list[np.ndarray]) -> rr.LineStrips3D:
    return rr.LineStrips3D([np.asarray(positions)], colors=TRAJECTORY_COLOR, radii=rr.Radius.ui_points(2.5))


def _values(instance_ids: np.ndarray, confidence: np.ndarray | None) -> rr.AnyValues:
    """`instance_id` and, where known, `confidence` (the labeller's probability for the class) per point."""
    if confidence is None:
        return rr.AnyValues(instance_id=instance_ids)
    return rr.AnyValues(instance_id=instance_ids, confidence=confidence)


def labelled_points(
    points: np.ndarray,
    class_ids: np.ndarray,
    instance_ids: np.ndarray,
    radius: float,
    confidence: np.ndarray | None = None,
) -> tuple[rr.Points3D, rr.AnyValues]:
    """Points with their class (coloured by the annotation context), `instance_id` and `confidence` beside them."""
    return (
        rr.Points3D(points.astype(np.float32), class_ids=class_ids, radii=radius),
        _values(instance_ids, confidence),
    )


def instance_points(points: np.ndarray, class_ids: np.ndarray, instance_ids: np.ndarray) -> list:
    """Points coloured by instance, with their class and `instance_id`."""
    return [
        rr.Points3D(points, colors=instance_colors_of(instance_ids), class_ids=class_ids, radii=SCAN_RADIUS),
        rr.AnyValues(instance_id=instance_ids),
    ]


def map_tile(
    points: np.ndarray,
    class_ids: np.ndarray | None,
    colors: np.ndarray | None,
    instance_ids: np.ndarray,
    radius: float,
    confidence: np.ndarray | None = None,
) -> tuple[rr.Points3D, rr.AnyValues]:
    """One map tile: by class, or by colour for a map without classes."""
    return (
        rr.Points3D(points.astype(np.float32), class_ids=class_ids, colors=colors, radii=radius),
        _values(instance_ids, confidence),
    )


def tile_labels(
    class_ids: np.ndarray, instance_ids: np.ndarray, confidence: np.ndarray | None = None
) -> tuple[rr.Points3D, rr.AnyValues]:
    """Only the labels of a map tile whose points stayed."""
    return rr.Points3D.from_fields(class_ids=class_ids), _values(instance_ids, confidence)


def uncertain_points(points: np.ndarray, confidence: np.ndarray, radius: float) -> tuple[rr.Points3D, rr.AnyValues]:
    """Map voxels the labeller is unsure of, in one colour no class has, drawn over the map."""
    return (
        rr.Points3D(points.astype(np.float32), colors=UNCERTAIN_COLOR, radii=radius),
        rr.AnyValues(confidence=confidence),
    )


def refined_points(cloud: LabelledCloud) -> list:
    """LRGNet's segmentation: by instance colour (else the cloud's colour), with classes and instance ids."""
    colors = instance_colors_of(cloud.instance_ids) if cloud.instance_ids is not None else cloud.colors
    extra = [rr.AnyValues(instance_id=cloud.instance_ids)] if cloud.instance_ids is not None else []
    return [rr.Points3D(cloud.points, colors=colors, class_ids=cloud.class_ids, radii=SCAN_RADIUS), *extra]


def growth_points(cloud: LabelledCloud, inliers: np.ndarray, neighbours: np.ndarray) -> tuple[rr.Points3D, rr.Points3D]:
    """One step of LRGNet's growth: the region's inliers and the neighbours it may take next."""
    radius = rr.Radius.ui_points(2.5)
    return (
        rr.Points3D(cloud.points[inliers], colors=GROWTH_INLIER_COLOR, radii=radius),
        rr.Points3D(cloud.points[neighbours], colors=GROWTH_NEIGHBOUR_COLOR, radii=radius),
    )


def run_text(info: RunInfo) -> str:
    """What the run reads, in one line of the text log."""
    what = f"source {info.source} ({info.source_kind}"
    what += f", topic {info.topic})" if info.topic else ")"
    return what + f", {info.environment}, labeller {info.labeller or 'none'}"


def summary_text(summary: RunSummary) -> str:
    """The run summary in one line of the text log."""
    text = (
        f"{summary.scans} scans, {summary.points} points, {summary.map_voxels} map voxels, "
        f"{summary.instances} instances, {summary.scans_per_second:.2f} scans/s"
    )
    if summary.registration_failures:
        text += f", registration flagged at scans {summary.registration_failures}"
    if summary.interrupted:
        text += " (interrupted)"
    return text


def crack_points(cloud: LabelledCloud) -> list:
    extra = [rr.AnyValues(instance_id=cloud.instance_ids)] if cloud.instance_ids is not None else []
    return [rr.Points3D(cloud.points, colors=CRACK_COLOR, radii=CRACK_RADIUS), *extra]


def rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat()


def quaternion_to_z(normal: np.ndarray) -> np.ndarray:
    """(x, y, z, w) rotation taking +z onto `normal`."""
    n = normal / max(np.linalg.norm(normal), 1e-12)
    if n[2] < 0:
        n = -n
    axis = np.cross([0.0, 0.0, 1.0], n)
    s = np.linalg.norm(axis)
    if s < 1e-9:
        return np.array([0.0, 0.0, 0.0, 1.0])
    angle = np.arctan2(s, n[2])
    return np.append(axis / s * np.sin(angle / 2), np.cos(angle / 2))


def crack_boxes(cracks: list[Crack]) -> rr.Boxes3D:
    """One box per crack: long side along its axis, short side across it in the surface, thin along the normal."""
    centers, half_sizes, quats, labels, colors = [], [], [], [], []
    # Labels would pile up where cracks cluster: the longest of a cluster carries the full label, the others
    # within LABEL_CLEARANCE_M of a labelled one just their number (all in the damage report).
    order = sorted(range(len(cracks)), key=lambda k: (-cracks[k].severe, -cracks[k].length_m))
    full: set[int] = set()
    placed: list[np.ndarray] = []
    for k in order:
        if all(np.linalg.norm(cracks[k].center - p) >= LABEL_CLEARANCE_M for p in placed):
            full.add(k)
            placed.append(cracks[k].center)
    for k, c in enumerate(cracks):
        axis = c.axis / max(np.linalg.norm(c.axis), 1e-12)
        normal = c.normal - axis * float(np.dot(c.normal, axis))
        normal /= max(np.linalg.norm(normal), 1e-12)
        across = np.cross(normal, axis)
        quats.append(rr.Quaternion(xyzw=rotation_to_quaternion(np.stack([axis, across, normal], axis=1))))
        centers.append(c.center)
        half_sizes.append([c.length_m / 2, max(c.width_m / 2, 0.002), 0.003])
        severity = "severe" if c.severe else "hairline"
        # a width below what the scan resolves there is not a measurement: say so, never a number
        wide = f"{c.width_m * 1000:.1f} mm wide" if c.width_resolved else "width not measurable"
        text = f"crack {c.instance_id}: {c.length_m * 100:.1f} cm long, {wide} ({severity})"
        labels.append(text if k in full else f"crack {c.instance_id}")
        colors.append(CRACK_COLOR if c.severe else MILD_CRACK_COLOR)
    return rr.Boxes3D(centers=centers, half_sizes=half_sizes, quaternions=quats, labels=labels, colors=colors)


def story_layers(
    stories: list[Story], bounds: tuple[np.ndarray, np.ndarray] | None
) -> tuple[list[tuple[int, rr.Boxes3D, rr.Points3D]], rr.Arrows3D | None]:
    """Each story's plane as a thin box over the map's extent (`bounds`, else 10 m around the origin) with its
    label on an opaque point at the plane's corner (the box's own label would take its faint color, and at the
    centre it would sit on the map's labels), and the drift arrows (exaggerated, labelled in mm) at their
    centres: none for a story whose drift was not measured, nor for the reference slab (no "0.0 mm")."""
    lo, hi = bounds if bounds is not None else (np.full(3, -5.0), np.full(3, 5.0))
    cx, cy = (lo[:2] + hi[:2]) / 2
    half = np.maximum((hi[:2] - lo[:2]) / 2, 0.5)
    planes: list[tuple[int, rr.Boxes3D, rr.Points3D]] = []
    origins, vectors, labels = [], [], []
    for s in stories:
        a, b, c, d = (float(v) for v in s.plane)
        z = -(a * cx + b * cy + d) / c if abs(c) > 1e-6 else s.height_m
        center = np.array([cx, cy, z])
        measured = s.drift_x_mm is not None and s.drift_y_mm is not None and s.drift_mm is not None
        if not measured:
            label = f"story {s.index}: drift and tilt not measured"
        elif s.reason is not None:
            label = f"story {s.index}: reference level"
        else:
            label = f"story {s.index}: drift {s.drift_mm:.1f} mm, tilt {s.tilt_deg:.2f}°"
        box = rr.Boxes3D(
            centers=[center],
            half_sizes=[[half[0], half[1], 0.005]],
            quaternions=[rr.Quaternion(xyzw=quaternion_to_z(np.array([a, b, c])))],
            colors=[(120, 180, 255, 60)],
            fill_mode="solid",
        )
        corner = np.array([cx - half[0], cy - half[1], z])
        tag = rr.Points3D([corner], colors=[(150, 200, 255)], radii=0.02, labels=[label], show_labels=True)
        planes.append((s.index, box, tag))
        if not measured or s.reason is not None:
            continue
        assert s.drift_x_mm is not None and s.drift_y_mm is not None and s.drift_mm is not None
        origins.append(center)
        vectors.append([s.drift_x_mm * DRIFT_ARROW_M_PER_MM, s.drift_y_mm * DRIFT_ARROW_M_PER_MM, 0.0])
        labels.append(f"{s.drift_mm:.1f} mm")
    arrows = rr.Arrows3D(origins=origins, vectors=vectors, labels=labels, colors=(255, 90, 90)) if origins else None
    return planes, arrows
