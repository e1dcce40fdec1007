"""Damage assessment end to end: cracks on an element (features → detector → smoothing → clean-up and
growth → instances → sizes → scores) and the JSON damage report of a map (cracks per element, story drift and tilt)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from aftershock.pipeline.config import Config, CrackConfig
from aftershock.pipeline.damage.components import extract_elements
from aftershock.pipeline.damage.detectors import (
    ANOMALY_DETECTORS,
    CLUSTERS_PER_FEATURE,
    Detection,
    Detector,
    detect,
    edge_points,
    grow,
    mixture_threshold,
    null_threshold,
    parse_detector,
    robust_sigma,
    smooth,
    valley_threshold,
)
from aftershock.pipeline.damage.drift import DriftResult, measure_drift
from aftershock.pipeline.damage.features import FeatureSet, compute_features, parse_features
from aftershock.pipeline.damage.measure import Scores, fit_plane, keep_narrow, measure_cracks, score, supported
from aftershock.pipeline.damage.recess import depth_z, keep_recessed
from aftershock.pipeline.damage.region import region_mask
from aftershock.pipeline.damage.region import settings_of as region_settings
from aftershock.pipeline.damage.ridge import ridge_mask, settings_of
from aftershock.pipeline.damage.tint import keep_tinted, measure_tint
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.geometry import point_spacing, voxel_downsample
from aftershock.pipeline.types import Crack, LabelledCloud, Story

COLUMN_RESOLUTION_M: Final = 0.001  # the study's evaluation grids
SLAB_RESOLUTION_M: Final = 0.01
ERROR_DEFINITION: Final = (
    "length_error_m/width_error_m: the main (largest) true crack (a connected group of the truth mask, linked, "
    "measured and filtered like a reported crack) against the whole reported crack holding most of its points; "
    "median_*: the same over every true crack found; study_*: the detected part of the largest true group "
    "against all of it, by minimum-area rectangle (the study's protocol); widths are openings"
)
_SLAB_COS: Final = np.cos(np.deg2rad(30.0))
MIN_POINTS: Final = 100  # fewer points cannot hold a crack of `min_crack_points` and the surface around it


class TooSparseError(InputError):
    """The cloud's point spacing is coarser than the cracks it could find."""


def default_resolution(points: np.ndarray) -> float:
    """1 cm for a horizontal element (a slab: its best-fit plane faces up), 1 mm for columns and walls."""
    if len(points) < 3:
        return COLUMN_RESOLUTION_M
    _, basis = fit_plane(points[:: max(1, len(points) // 20000)])
    return SLAB_RESOLUTION_M if abs(basis[2, 2]) >= _SLAB_COS else COLUMN_RESOLUTION_M


def carry_mask(mask: np.ndarray, voxel_of_point: np.ndarray, voxels: int) -> np.ndarray:
    """A voxel is crack when at least half of its input points are (majority, ties to crack)."""
    crack = np.bincount(voxel_of_point, weights=np.asarray(mask, np.float64), minlength=voxels)
    total = np.bincount(voxel_of_point, minlength=voxels)
    return crack >= 0.5 * total


@dataclass(slots=True)
class CrackResult:
    """Cracks found on one element, on the cloud they were evaluated on (after downsampling)."""

    cloud: LabelledCloud  # the evaluated cloud
    mask: np.ndarray  # (M,) bool predicted crack points
    crack_ids: np.ndarray  # (M,) crack instance of each point, 0 = none
    cracks: list[Crack]
    resolution_m: float
    spacing_m: float
    features: str
    detector: str
    truth: np.ndarray | None = None  # (M,) carried truth mask
    scores: Scores | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    input_points: int = 0
    notes: list[str] = field(default_factory=list)  # what was left out of the input, and why

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.scores is not None:
            s = self.scores
            out |= {
                "precision": s.precision,
                "recall": s.recall,
                "f1": s.f1,
                "length_error_m": _num(s.length_error_m),
                "width_error_m": _num(s.width_error_m),
                "error_definition": ERROR_DEFINITION,
                "true_length_m": _num(s.true_length_m),
                "true_width_m": _num(s.true_width_m),
                "found_length_m": _num(s.found_length_m),
                "found_width_m": _num(s.found_width_m),
                "median_length_error_m": _num(s.median_length_error_m),
                "median_width_error_m": _num(s.median_width_error_m),
                "true_cracks": s.true_cracks,
                "found_true_cracks": s.found_cracks,
                "true_blobs": s.true_blobs,
                "study_length_error_m": _num(s.study_length_error_m),
                "study_width_error_m": _num(s.study_width_error_m),
                "true_crack_matches": [
                    {
                        "true_length_m": round(m.true_length_m, 4),
                        "true_width_m": round(m.true_width_m, 4),
                        "true_points": m.true_points,
                        "crack_id": m.crack_id,
                        "length_m": _round(m.length_m),
                        "width_m": _round(m.width_m),
                    }
                    for m in s.matches
                ],
            }
        out |= {
            "cracks": [crack_json(c) for c in self.cracks],
            "crack_points": int(self.mask.sum()),
            "points": len(self.cloud),
            "input_points": self.input_points,
            "resolution_m": self.resolution_m,
            "spacing_m": self.spacing_m,
            "features": self.features,
            "detector": self.detector,
            "timings_s": self.timings_s,
            "notes": self.notes,
        }
        return out


def _num(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def _round(x: float) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 4)


WIDTH_NOT_MEASURABLE: Final = "present, width not measurable: narrower than the scan resolves here"


def crack_json(c: Crack) -> dict[str, Any]:
    """One crack; a width below what the scan resolves there is null, with the reason and the limit."""
    return {
        "id": c.instance_id,
        "position": [round(float(v), 4) for v in c.center],
        "length_m": round(c.length_m, 4),
        "width_m": round(c.width_m, 4) if c.width_resolved else None,
        "width_reason": None if c.width_resolved else WIDTH_NOT_MEASURABLE,
        "resolvable_mm": _round(c.resolvable_m * 1000),
        "max_width_m": _round(c.max_width_m),
        "rectangle_width_m": _round(c.rect_width_m),
        "area_width_m": _round(c.area_width_m),
        "depth_contrast": _round(c.depth_contrast),
        "chroma_contrast": _round(c.chroma_contrast),
        "points": c.num_points,
        "axis": [round(float(v), 4) for v in c.axis],
        "normal": [round(float(v), 4) for v in c.normal],
        "severe": c.severe,
        "width_resolved": c.width_resolved,
    }


def edge_suppressed(points: np.ndarray, score: np.ndarray, cell_m: float) -> np.ndarray:
    """Scores with those of the scan's edge points (`edge_points`) lowered to the median: a one-sided
    neighbourhood is no evidence of a crack."""
    if cell_m <= 0:
        return score
    edge = edge_points(points, cell_m)
    out = np.asarray(score, np.float64).copy()
    out[edge] = np.minimum(out[edge], np.median(out))
    return out


def decision_threshold(detection: Detection, cfg: CrackConfig) -> float:
    """The crack threshold of an anomaly detector's scores under the configured rule (`CrackConfig.threshold`)."""
    s = detection.score
    null = null_threshold(s, cfg.null_sigmas)
    if cfg.threshold == "null":
        return null
    if cfg.threshold == "mixture":
        return mixture_threshold(s, null, cfg.mixture_min_weight, cfg.mixture_separation, cfg.seed)
    if cfg.threshold == "valley":
        valley = valley_threshold(s, detection.threshold, cfg.valley_rise)
        return max(valley, null) if cfg.null_sigmas > 0 else valley
    return detection.threshold


def _point_detection(
    part: LabelledCloud, feats: FeatureSet, det: Detector, spacing: float, cfg: CrackConfig, timings: dict[str, float]
) -> np.ndarray:
    """Crack candidates of a point-feature detector: features → detector → scan-edge points lowered to the median
    → threshold by the configured rule → smoothing → support clean-up → growth (see `find_cracks`)."""
    t0 = time.perf_counter()
    x = compute_features(part, feats, cfg)
    timings["features"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    detection = detect(
        x, det, seed=cfg.seed, fit_points=cfg.fit_points, clusters=CLUSTERS_PER_FEATURE.get(feats.value, 2)
    )
    if det in ANOMALY_DETECTORS:
        edge_cell = cfg.edge_spacings * spacing
        detection = Detection(edge_suppressed(part.points, detection.score, edge_cell), detection.threshold)
        detection = Detection(detection.score, decision_threshold(detection, cfg))
    sigma = robust_sigma(detection.score)
    detection = smooth(part.points, detection, cfg.smooth_cell_m, cfg.smooth_keep_raw)
    support_m = cfg.support_spacings * spacing
    mask = supported(part.points, detection.mask, support_m, cfg.min_support)
    mask = grow(part.points, mask, detection.score, detection.threshold - cfg.grow_sigmas * sigma, cfg.grow_m)
    timings["detect"] = time.perf_counter() - t0
    return mask


def find_cracks(
    cloud: LabelledCloud,
    cfg: CrackConfig,
    truth: np.ndarray | None = None,
    *,
    features: FeatureSet | str | None = None,
    detector: Detector | str | None = None,
    resolution_m: float | None = None,
    check_spacing: bool = True,
) -> CrackResult:
    """Detect and measure the cracks of one element (a column, wall or slab cut out of a scan).

    The cloud is first reduced to one point per `resolution_m` voxel (default: 1 mm for columns and walls,
    1 cm for slabs, as the study evaluated); a truth mask is carried along by majority. Precision and recall
    are then counted over the points of that evaluated cloud. Detection: features → detector → scan-edge points
    lowered to the median score (`cfg.edge_spacings`) → threshold by the configured rule (`cfg.threshold`:
    a calibrated null rule that knows an element without cracks, a two-component mixture, or the valley before
    a separate mode of high scores) → scores smoothed over space → support clean-up (drops the smoothing's rim,
    and the thin ends of cracks with it) → growth: points within `cfg.grow_m` of a crack whose smoothed score is
    nearly above the threshold join it → cracks (connected, elongated groups) → each crack's depth contrast
    (`recess`) and hue contrast (`tint`), and with `cfg.depth_sigmas` > 0 only cracks at least that recessed
    stay, with `cfg.min_chroma_contrast` > 0 only those whose hue differs that much; with `cfg.cracks_only`
    the crack points are those of reported cracks. Each crack's opening is measured on all of its points, as each true
    crack's is. Points with non-finite coordinates are left out (`notes` says how many). Fewer than
    `MIN_POINTS` points, or a cloud whose spacing is coarser than `cfg.max_spacing_m`, raise `TooSparseError`
    (the latter unless `check_spacing` is off, for the spacing study)."""
    n_in = len(cloud)
    if truth is not None:
        truth = np.asarray(truth)
        if truth.ndim != 1 or len(truth) != n_in:
            raise InputError(f"the truth mask has {truth.shape} entries for a cloud of {n_in} points")
        truth = truth.astype(bool)
    notes: list[str] = []
    finite = np.isfinite(cloud.points).all(axis=1)
    if not finite.all():  # NaN coordinates (a scanner's no-return) would break every neighbourhood and fit
        notes.append(f"{int((~finite).sum())} point(s) with non-finite coordinates left out")
        cloud = cloud.select(np.flatnonzero(finite))
        truth = truth[finite] if truth is not None else None
    if len(cloud) < MIN_POINTS:
        raise TooSparseError(
            f"{len(cloud)} point(s) with finite coordinates are too few to look for cracks (at least {MIN_POINTS})"
        )
    feats = parse_features(features or cfg.features) if not isinstance(features, FeatureSet) else features
    det = parse_detector(detector or cfg.detector) if not isinstance(detector, Detector) else detector
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    res = resolution_m or cfg.resolution_m or default_resolution(cloud.points)
    keep, voxel_of = voxel_downsample(cloud.points, res)
    part = cloud.select(keep)
    carried = carry_mask(truth, voxel_of, len(keep)) if truth is not None else None
    spacing = point_spacing(part.points, seed=cfg.seed)
    timings["downsample"] = time.perf_counter() - t0
    if check_spacing and spacing > cfg.max_spacing_m:
        raise TooSparseError(
            f"too sparse for crack measurement: point spacing {spacing * 1000:.1f} mm is coarser than the "
            f"{cfg.max_spacing_m * 1000:.0f} mm limit (cracks narrower than the spacing cannot be seen)"
        )
    if det == Detector.RIDGE:
        t0 = time.perf_counter()
        mask = ridge_mask(part, spacing, settings_of(cfg), cfg.seed)
        timings["detect"] = time.perf_counter() - t0
        feature_name = "orthoimage"
    elif det == Detector.REGION:
        t0 = time.perf_counter()
        mask = region_mask(part, spacing, region_settings(cfg), cfg.seed)
        timings["detect"] = time.perf_counter() - t0
        feature_name = "orthoimage"
    else:
        mask = _point_detection(part, feats, det, spacing, cfg, timings)
        feature_name = feats.value
    t0 = time.perf_counter()
    link = max(cfg.link_m, cfg.link_spacings * spacing)
    cracks, ids = measure_cracks(
        part.points, mask, link, cfg.min_crack_points, cfg.severe_width_m, spacing, cfg.min_elongation
    )
    grouped = ids > 0
    measure_tint(cracks, part.points, part.colors, ids, ~mask)
    cracks, ids = keep_recessed(cracks, ids, depth_z(part.points, mask, cfg.depth_cell_m), cfg.depth_sigmas)
    cracks, ids = keep_tinted(cracks, ids, cfg.min_chroma_contrast)
    cracks, ids = keep_narrow(cracks, ids, len(part), cfg.max_share, cfg.min_area_elongation)
    mask &= (ids > 0) | ~grouped  # the points of flat or broad candidates (stains, streaks, shade) are no crack either
    if cfg.cracks_only:
        mask = ids > 0
    scores = None
    if carried is not None:
        scores = score(part.points, mask, carried, link, cfg.min_crack_points, spacing, ids, cracks, cfg.min_elongation)
    timings["measure"] = time.perf_counter() - t0
    return CrackResult(
        cloud=part,
        mask=mask,
        crack_ids=ids,
        cracks=cracks,
        resolution_m=float(res),
        spacing_m=spacing,
        features=feature_name,
        detector=det.value,
        truth=carried,
        scores=scores,
        timings_s={k: round(v, 3) for k, v in timings.items()},
        input_points=n_in,
        notes=notes,
    )


@dataclass(slots=True)
class DamageReport:
    """What `assess_damage` found on a map: cracks per element, stories, and what could not be measured."""

    cracks: list[Crack]
    crack_points: LabelledCloud | None  # the crack points of all elements (for the viewer)
    stories: list[Story]
    gravity: str
    elements_checked: int
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "cracks": [crack_json(c) for c in self.cracks],
            "severe_cracks": sum(c.severe for c in self.cracks),
            "stories": [story_json(s) for s in self.stories],
            "gravity": self.gravity,
            "elements_checked": self.elements_checked,
            "notes": self.notes,
        }


def story_json(s: Story) -> dict[str, Any]:
    """A story as JSON: drift and tilt null where not measured, with the `reason`."""

    def r(x: float | None, nd: int) -> float | None:
        return None if x is None else round(x, nd)

    return {
        "index": s.index,
        "height_m": round(s.height_m, 4),
        "plane": [round(float(v), 6) for v in s.plane],
        "drift_x_mm": r(s.drift_x_mm, 2),
        "drift_y_mm": r(s.drift_y_mm, 2),
        "drift_mm": r(s.drift_mm, 2),
        "tilt_x_deg": r(s.tilt_x_deg, 4),
        "tilt_y_deg": r(s.tilt_y_deg, 4),
        "tilt_deg": r(s.tilt_deg, 4),
        "points": s.num_points,
        "reason": s.reason,
    }


def story_text(s: Story | dict[str, Any]) -> str:
    """`drift 12.3 mm, tilt 0.120°`, or `drift and tilt not measured (why)`, or the reference slab's own words."""
    get = s.get if isinstance(s, dict) else lambda k: getattr(s, k)
    if get("drift_mm") is None or get("tilt_deg") is None:
        return f"drift and tilt not measured ({get('reason') or 'no reason given'})"
    if get("index") == 0 and get("reason"):
        return "reference level (drift and tilt are measured against it)"
    return f"drift {get('drift_mm'):.1f} mm, tilt {get('tilt_deg'):.3f}°"


def assess_damage(cloud: LabelledCloud, cfg: Config, box: np.ndarray | None = None) -> DamageReport:
    """Cracks and story drift/tilt of a map (the accumulated map at the end of a mission, or a region).

    `cloud` is any `LabelledCloud` in a gravity-aligned world frame (z up, as the map is); `cfg` is the run's
    whole `Config` (its `cracks` and `drift` sections are used); `box` (2, 3) = min and max corner limits the
    assessment to a region. Stories come from the whole cloud (or box); cracks are looked for on every
    structural element (columns, walls, slabs cut out by region growing) whose points are dense enough —
    a map downsampled to 10 cm voxels is not, and the report says so instead of guessing.
    Never raises for sparse or empty input: what could not be measured is listed in `notes`."""
    notes: list[str] = []
    if box is not None:
        lo, hi = np.asarray(box, np.float64).reshape(2, 3)
        cloud = cloud.select(np.all((cloud.points >= lo) & (cloud.points <= hi), axis=1))
    drift: DriftResult = measure_drift(cloud.points, cfg.drift)
    notes += drift.notes
    cracks: list[Crack] = []
    crack_clouds: list[LabelledCloud] = []
    elements = extract_elements(cloud, cfg.cracks) if len(cloud) else []
    checked = 0
    sparse = 0
    for element in elements:  # one iteration per structural element, not per point
        part = cloud.select(element)
        try:
            result = find_cracks(part, cfg.cracks)
        except TooSparseError:
            sparse += 1
            continue
        except InputError as exc:
            notes.append(f"element of {len(part)} points skipped: {exc}")
            continue
        checked += 1
        offset = len(cracks)
        for c in result.cracks:
            c.instance_id += offset
            cracks.append(c)
        if result.mask.any():
            crack_clouds.append(result.cloud.select(result.mask))
    if sparse:
        notes.append(
            f"{sparse} element(s) too sparse for crack measurement (spacing above "
            f"{cfg.cracks.max_spacing_m * 1000:.0f} mm): no cracks reported for them"
        )
    if not elements:
        notes.append("no structural element found to look for cracks on")
    crack_points = None
    if crack_clouds:
        crack_points = LabelledCloud(np.concatenate([c.points for c in crack_clouds]))
    return DamageReport(cracks, crack_points, drift.stories, drift.gravity, checked, notes)
