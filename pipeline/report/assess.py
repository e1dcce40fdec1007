"""A mission's results turned into the report's content: storeys (drift, ratio to storey height, tilt,
uncertainty, flag), structural inventory, cracks, debris, the ATC-20 detailed-evaluation checklist and a
suggested posting.

A value that was not measured is `None` with a `reason`, never a number. Drift and tilt limits, the drift
uncertainty and the debris thresholds come from `ReportConfig` (defaults and their sources there).
The checklist follows the overall and structural hazards of the ATC-20 Detailed Evaluation Safety Assessment
Form (ATC-20-2, 1995): collapse or partial collapse, building or storey leaning, columns, walls, floors and
slabs, and the nonstructural "stairs, exits" as debris blocking exits. The posting is only a suggestion
(`advisory: true`): ATC-20 postings are made by the inspecting engineer.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import PurePath
from typing import Any, Final

import numpy as np

from aftershock.pipeline.classes import CLASS_NAMES, SemanticClass
from aftershock.pipeline.config import Config, ReportConfig
from aftershock.pipeline.report.gather import MissionData

FOUND: Final = "found"
NONE: Final = "none"
NOT_ASSESSABLE: Final = "not_assessable"

INSPECTED: Final = "inspected"
RESTRICTED: Final = "restricted use"
UNSAFE: Final = "unsafe"
_SEVERITY: Final = {INSPECTED: 0, RESTRICTED: 1, UNSAFE: 2}

# Where findings live in a mission's recording (sinks/rerun_blueprint.py's entity paths)
ENTITY_MAP: Final = "world/map"
ENTITY_CRACKS: Final = "world/damage/cracks"
ENTITY_STORIES: Final = "world/damage/stories"
ENTITY_DRIFT: Final = "world/damage/drift"
SCAN_TIMELINE: Final = "scan"

UP_TEXT: Final = {
    "ground-plane": "the lowest slab taken as level (drift is the storeys' lean against it)",
    "frame-z": "the map's z axis (levelled by run from its first scan)",
}
CLOCK_SINCE_S: Final = 946_684_800.0  # 2000-01-01: earlier stamps are a file's own count, not the clock (PCD)
STOREY_PAD_M: Final = 0.3  # a storey's points start this far below its floor slab (the slab's own thickness)
POSTING_RULE: Final = (
    "unsafe: collapse or partial collapse found, or a storey's drift ratio or slab tilt above the unsafe limit "
    "by more than its measurement uncertainty; restricted use: a drift ratio or slab tilt above the restricted "
    "limit by more than its uncertainty, a severe crack on a column, wall or slab, or debris blocking an exit; "
    "a value whose uncertainty reaches across a limit (value - uncertainty <= limit < value + uncertainty) is "
    "within measurement uncertainty of the limit: shown, not escalated on alone; inspected: collapse and "
    "leaning assessed and nothing found; otherwise restricted use until an engineer has checked what this data "
    "could not assess"
)
CITATIONS: Final = {
    "checklist": "ATC-20 Detailed Evaluation Safety Assessment Form (ATC-20-2 addendum, Applied Technology "
    "Council, 1995): overall hazards (collapse or partial collapse, building or story leaning), structural "
    "hazards (columns, walls, roofs and floors), nonstructural hazards (stairs, exits); postings INSPECTED, "
    "RESTRICTED USE, UNSAFE",
    "drift_limits": "residual drift damage states of FEMA P-58-1 (2012), Appendix C: 0.5 % (1/200) "
    "realignment of the frame required; 1 % (1/100) major realignment, which may not be practical",
    "tilt_limits": "the drift limits' slopes (atan 1/200 = 0.29°, atan 1/100 = 0.57°): a choice of this tool",
    "tilt_uncertainty": "measured per storey from the data: the standard error of each slab plane's normal over "
    "the four quadrants of its inliers (pipeline/report/tilt.py), floor and ceiling combined, times 2 (about 95 %)",
    "uncertainty": "the worst drift error per storey through run on 2 simulated frames (simulator.frames "
    "missing-slab seed 5, partial-collapse seed 6, 6 storeys, 10 cm) with up from the lowest slab: 2.6 mm "
    "(measure_drift alone on the simulator's damaged buildings: 1.90 mm, README: Story drift and tilt); with up from "
    "the levelled map's z the same frames were 8-9 mm off per storey",
}


def _num(x: Any, nd: int = 4) -> float | None:
    return None if x is None or not np.isfinite(float(x)) else round(float(x), nd)


def ratio_text(ratio: float | None) -> str | None:
    """1/240 for 0.00417; None when not measured; 0 for no drift at all."""
    if ratio is None:
        return None
    if ratio <= 0:
        return "0"
    return f"1/{round(1 / ratio):d}"


def _where(m: MissionData, entity: str, instance: int | None = None) -> dict[str, Any]:
    """A finding's place in the mission's recording: entity path and timeline position (the damage layers and
    the map are logged at the last scan)."""
    out: dict[str, Any] = {
        "recording": str(m.recording) if m.recording is not None else None,
        "entity": entity,
        "timeline": SCAN_TIMELINE,
        "position": max(len(m.poses) - 1, 0),
    }
    if instance is not None:
        out["instance"] = instance
    return out


# ------------------------------------------------------------------------------------------------ storeys


@dataclass
class Levels:
    """The slab levels a mission's storeys are measured between: each as `story_json` writes it (height, plane,
    drift against the lowest slab, tilt), the measurement's notes, where up came from, and from what."""

    slabs: list[dict[str, Any]]
    notes: list[str]
    gravity: str | None
    measured_from: str
    points: np.ndarray | None = None  # the map the slabs were fitted on (their planes' inliers are among them)
    threshold_m: float = 0.02  # a point lies on a slab plane within this distance (the plane fit's own)


def measure_levels(m: MissionData, full: Config) -> Levels:
    """The slabs of the mission's map measured with `report.drift_gravity` (default: the lowest slab taken as
    level -- a map `run` levelled has its up from the first scan, which can be a few tenths of a degree off,
    and over a storey's height that is centimetres of drift); without a map, those of damage.json."""
    from aftershock.pipeline.damage.drift import measure_drift
    from aftershock.pipeline.damage.report import story_json

    if m.cloud is not None and len(m.cloud):
        result = measure_drift(m.cloud.points, full.drift.model_copy(update={"gravity": full.report.drift_gravity}))
        slabs = [story_json(st) for st in result.stories]
        return Levels(
            slabs, list(result.notes), result.gravity, "map.ply", m.cloud.points, full.drift.ransac_threshold_m
        )
    if m.damage is None:
        return Levels([], ["no map and no damage assessment"], None, "nothing")
    stories = sorted(m.damage.get("stories") or [], key=lambda st: float(st["height_m"]))
    return Levels(stories, list(m.damage.get("notes") or []), m.damage.get("gravity"), "damage.json")


def _plane_z(plane: list[float], xy: np.ndarray) -> np.ndarray:
    a, b, c, d = plane
    return -(a * xy[:, 0] + b * xy[:, 1] + d) / c


def _angle_deg(p: list[float], q: list[float]) -> float:
    n1, n2 = np.asarray(p[:3], float), np.asarray(q[:3], float)
    cos = abs(float(n1 @ n2)) / (np.linalg.norm(n1) * np.linalg.norm(n2))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


NEAR_LIMIT: Final = "within measurement uncertainty of the limit"


def exceeds(value: float | None, uncertainty: float | None, limit: float) -> bool:
    """Evidence that `value` exceeds `limit`: by more than its uncertainty (none stated: the value alone)."""
    return value is not None and value - (uncertainty or 0.0) > limit


def straddles(value: float | None, uncertainty: float | None, limit: float) -> bool:
    """`limit` lies within value ± uncertainty, and the value is no evidence of exceeding it."""
    return value is not None and not exceeds(value, uncertainty, limit) and value + (uncertainty or 0.0) > limit


def ratio_uncertainty(s: dict[str, Any]) -> float | None:
    """A storey's drift uncertainty as a share of its height."""
    if s.get("uncertainty_mm") is None or not s.get("height_m"):
        return None
    return float(s["uncertainty_mm"]) / 1000.0 / float(s["height_m"])


def _flag(
    ratio: float | None, ratio_u: float | None, tilt: float | None, tilt_u: float | None, cfg: ReportConfig
) -> str | None:
    if ratio is None and tilt is None:
        return None
    if exceeds(ratio, ratio_u, cfg.drift_unsafe_ratio) or exceeds(tilt, tilt_u, cfg.tilt_unsafe_deg):
        return UNSAFE
    if exceeds(ratio, ratio_u, cfg.drift_restricted_ratio) or exceeds(tilt, tilt_u, cfg.tilt_restricted_deg):
        return RESTRICTED
    if straddles(ratio, ratio_u, cfg.drift_restricted_ratio) or straddles(tilt, tilt_u, cfg.tilt_restricted_deg):
        return NEAR_LIMIT
    return "within limits"


def storeys(m: MissionData, measured: Levels, cfg: ReportConfig) -> list[dict[str, Any]]:
    """One entry per storey: between two slab levels the drift step, its ratio to the storey height and the
    ceiling slab's tilt against the floor slab; with one slab or none, one storey whose values are None and
    say why."""
    slabs = measured.slabs
    if not slabs:
        notes = "; ".join(measured.notes) or "no slab found"
        return [_unmeasured(0, None, f"no floor or ceiling slab found ({notes})")]
    kept = [slabs[0]]
    low_surfaces = []
    for s in slabs[1:]:  # a horizontal surface lower than a storey above the last level is furniture or a platform
        if float(s["height_m"]) - float(kept[-1]["height_m"]) >= cfg.min_storey_height_m:
            kept.append(s)
        else:
            low_surfaces.append(float(s["height_m"]) - float(kept[-1]["height_m"]))
    slabs = kept
    if len(slabs) == 1:
        z = float(slabs[0]["height_m"])
        if low_surfaces:
            heights = ", ".join(f"{h:.2f}" for h in low_surfaces)
            return [_unmeasured(0, z, (
                f"one slab found (at z {z:.2f} m); the horizontal surface(s) {heights} m above it are lower than "
                f"a storey ({cfg.min_storey_height_m:.1f} m): furniture or platforms, not a ceiling"
            ))]  # fmt: skip
        why = (
            f"one slab found (at z {z:.2f} m): drift and tilt need a storey's floor and ceiling, two slabs; "
            "the scan saw no second level"
        )
        return [_unmeasured(0, z, why)]
    notes = " ".join(measured.notes)
    out = []
    for i in range(len(slabs) - 1):
        lo, hi = slabs[i], slabs[i + 1]
        height = float(hi["height_m"]) - float(lo["height_m"])
        # slab drifts are against the lowest slab (its own drift is the reference, 0 or None)
        dx = (hi.get("drift_x_mm") or 0.0) - (lo.get("drift_x_mm") or 0.0)
        dy = (hi.get("drift_y_mm") or 0.0) - (lo.get("drift_y_mm") or 0.0)
        drift = float(np.hypot(dx, dy))
        ratio = drift / 1000.0 / height if height > 0 else None
        tilt = _angle_deg(lo["plane"], hi["plane"])
        tilt_u, tilt_u_reason = _tilt_uncertainty(measured, lo["plane"], hi["plane"])
        # the stories' numbering in the notes is that of the damage report's slabs (lowest first)
        k = int(lo.get("index", i))
        footprints = re.search(rf"story {k}: too few tall walls", notes) is not None
        reason = None
        uncertainty: float | None = _uncertainty(measured, height, cfg)
        method: str | None = "wall and column lean"
        if footprints:  # partly seen slabs' footprints move with what was seen of them, not with the storey
            reason = (
                f"drift: too few tall walls or columns seen; the offset of the slab footprints "
                f"({drift:.0f} mm) is no drift measurement"
            )
            drift, dx, dy, ratio, uncertainty, method = np.nan, np.nan, np.nan, None, None, None
        out.append(
            {
                "index": i,
                "floor_z_m": _num(lo["height_m"], 3),
                "ceiling_z_m": _num(hi["height_m"], 3),
                "height_m": _num(height, 3),
                "drift_mm": _num(drift, 2),
                "drift_x_mm": _num(dx, 2),
                "drift_y_mm": _num(dy, 2),
                "drift_ratio": _num(ratio, 6),
                "drift_ratio_text": ratio_text(ratio),
                "tilt_deg": _num(tilt, 4),
                "tilt_uncertainty_deg": _num(tilt_u, 4),
                "uncertainty_mm": uncertainty,
                "method": method,
                "flag": _flag(ratio, _ratio_u(uncertainty, height), tilt, tilt_u, cfg),
                "reason": "; ".join(r for r in (reason, tilt_u_reason) if r) or None,
                "plane": lo["plane"],
            }
        )
    top = slabs[-1]  # the top slab (a roof, or the ceiling of the last storey seen) starts no storey of its own
    out[-1]["roof_z_m"] = _num(top["height_m"], 3)
    return out


def _ratio_u(uncertainty_mm: float | None, height_m: float) -> float | None:
    return None if uncertainty_mm is None or height_m <= 0 else uncertainty_mm / 1000.0 / height_m


def _tilt_uncertainty(measured: Levels, floor: list[float], ceiling: list[float]) -> tuple[float | None, str | None]:
    """The tilt's expanded uncertainty from the slabs' own points (`tilt.py`), or None and why not."""
    from aftershock.pipeline.report.tilt import plane_spread, tilt_uncertainty

    if measured.points is None:
        return (
            None,
            f"tilt uncertainty not measured: the slabs come from {measured.measured_from}, without their points",
        )
    pts = np.asarray(measured.points, np.float64)
    return tilt_uncertainty(
        plane_spread(pts, floor, measured.threshold_m), plane_spread(pts, ceiling, measured.threshold_m)
    )


def _uncertainty(measured: Levels, height_m: float, cfg: ReportConfig) -> float:
    """The drift method's own error; with up from the map's frame (`frame-z`) of a map `run` levelled, what an
    up direction off by `level_uncertainty_deg` adds over the storey's height."""
    extra = 0.0
    if measured.gravity == "frame-z":
        extra = height_m * 1000.0 * np.tan(np.deg2rad(cfg.level_uncertainty_deg))
    return round(cfg.drift_uncertainty_mm + extra, 1)


def _unmeasured(index: int, floor_z: float | None, reason: str) -> dict[str, Any]:
    return {
        "index": index,
        "floor_z_m": _num(floor_z, 3),
        "ceiling_z_m": None,
        "height_m": None,
        "drift_mm": None,
        "drift_x_mm": None,
        "drift_y_mm": None,
        "drift_ratio": None,
        "drift_ratio_text": None,
        "tilt_deg": None,
        "tilt_uncertainty_deg": None,
        "uncertainty_mm": None,
        "method": None,
        "flag": None,
        "reason": reason,
        "plane": None,
    }


def storey_of(points: np.ndarray, levels: list[dict[str, Any]]) -> np.ndarray:
    """The storey index of each point: from a little below its floor slab to a little below the next one."""
    floors = [s["floor_z_m"] for s in levels]
    if len(levels) <= 1 or any(f is None for f in floors):
        return np.zeros(len(points), np.int64)
    edges = np.asarray(floors[1:], float) - STOREY_PAD_M
    return np.searchsorted(edges, points[:, 2], side="right").astype(np.int64)


# ------------------------------------------------------------------------------------------------ contents


def _instances_by_class(cls: np.ndarray, inst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(instance ids, majority class of each) over points with an instance."""
    ok = inst > 0
    if not ok.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids, inv = np.unique(inst[ok], return_inverse=True)
    votes = np.zeros((len(ids), len(CLASS_NAMES)), np.int64)
    known = cls[ok] < len(CLASS_NAMES)
    np.add.at(votes, (inv.reshape(-1)[known], cls[ok][known].astype(np.int64)), 1)
    return ids, votes.argmax(axis=1)


STRUCTURE_KINDS: Final = {"slab": ("floor", "ceiling"), "wall": ("wall",), "column": ("column",), "beam": ("beam",)}


def _element_z(element: dict[str, Any]) -> float | None:
    """The middle height of a structure-model element's extent ({min, max}, [[min], [max]] or 6 numbers)."""
    ext = element.get("extent")
    try:
        if isinstance(ext, dict):
            lo, hi = ext.get("min"), ext.get("max")
        else:
            flat = np.asarray(ext, float).reshape(-1)
            lo, hi = flat[:3], flat[3:6]
        return float((np.asarray(lo, float)[2] + np.asarray(hi, float)[2]) / 2)
    except (TypeError, ValueError, IndexError):
        return None


def inventory(m: MissionData, levels: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Slabs, walls, columns and beams per storey: from the structure model when the mission has one,
    otherwise the map's objects by majority class."""
    out = [{"storey": s["index"], "source": "", "slabs": 0, "walls": 0, "columns": 0, "beams": 0} for s in levels]
    elements = (m.structure or {}).get("elements")
    if isinstance(elements, list):
        for entry in out:
            entry["source"] = "structure model (structure.json)"
        for e in elements:
            kind = str(e.get("kind", "")).lower()
            z = _element_z(e)
            key = next((k for k, names in STRUCTURE_KINDS.items() if kind == k or kind in names), None)
            if key is None or z is None:
                continue
            i = int(storey_of(np.array([[0.0, 0.0, z]]), levels)[0])
            out[min(i, len(out) - 1)][key + "s"] += 1
        return out
    for entry in out:
        entry["source"] = "objects of the labelled map, by majority class"
    cloud = m.cloud
    if cloud is None or cloud.instance_ids is None or cloud.class_ids is None:
        return out
    ids, cls = _instances_by_class(cloud.class_ids.astype(np.int64), cloud.instance_ids.astype(np.int64))
    if len(ids) == 0:
        return out
    # each object's storey: that of its lowest points' median (a wall spans its storey's height)
    order = np.argsort(cloud.instance_ids)
    sorted_ids = cloud.instance_ids[order]
    starts = np.searchsorted(sorted_ids, ids)
    ends = np.searchsorted(sorted_ids, ids, side="right")
    z_med = np.array([np.median(cloud.points[order[a:b], 2]) for a, b in zip(starts, ends, strict=True)])
    storey = storey_of(np.c_[np.zeros((len(ids), 2)), z_med], levels)
    for key, names in STRUCTURE_KINDS.items():
        wanted = np.isin(cls, [CLASS_NAMES.index(n) for n in names])
        counts = np.bincount(storey[wanted], minlength=len(out))
        for i, n in enumerate(counts[: len(out)]):
            out[i][key + "s"] = int(n)
    return out


def debris(m: MissionData, levels: list[dict[str, Any]], cfg: ReportConfig) -> list[dict[str, Any]]:
    """Per storey: the debris volume (each grid cell's debris height above the floor times its area) and the
    share of the floor area it covers (cells with debris among the cells with floor or debris)."""
    out = []
    cloud = m.cloud
    for s in levels:
        entry: dict[str, Any] = {"storey": s["index"], "volume_m3": None, "floor_area_m2": None, "floor_share": None}
        if cloud is None or cloud.class_ids is None or len(cloud) == 0:
            entry["reason"] = "no map"
            out.append(entry)
            continue
        sel = storey_of(cloud.points, levels) == s["index"]
        pts, cls = cloud.points[sel], cloud.class_ids[sel]
        is_debris = cls == SemanticClass.DEBRIS
        is_floor = cls == SemanticClass.FLOOR
        cell = cfg.plan_cell_m
        floor_cells = np.unique(np.floor(pts[is_floor | is_debris, :2] / cell).astype(np.int64), axis=0)
        if not is_floor.any():
            entry["reason"] = "no floor seen in this storey: no floor area to measure debris against"
            if is_debris.any():
                entry["debris_points"] = int(is_debris.sum())
            out.append(entry)
            continue
        area = len(floor_cells) * cell * cell
        d = pts[is_debris]
        if len(d) == 0:
            entry |= {"volume_m3": 0.0, "floor_area_m2": round(area, 2), "floor_share": 0.0}
            out.append(entry)
            continue
        if s.get("plane") is not None:
            floor_z = _plane_z(s["plane"], d[:, :2])
        else:
            floor_z = np.full(len(d), float(np.median(pts[is_floor, 2])))
        keys = np.floor(d[:, :2] / cell).astype(np.int64)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        top = np.full(len(uniq), -np.inf)
        np.maximum.at(top, inv.reshape(-1), d[:, 2] - floor_z)
        volume = float(np.clip(top, 0.0, None).sum() * cell * cell)
        entry |= {
            "volume_m3": round(volume, 3),
            "floor_area_m2": round(area, 2),
            "floor_share": round(len(uniq) / max(len(floor_cells), 1), 4),
            "centre": [round(float(v), 3) for v in d.mean(axis=0)],
        }
        out.append(entry)
    return out


def _element_at(m: MissionData, position: np.ndarray) -> str:
    """The class of the map point nearest a finding (the element a crack lies on)."""
    cloud = m.cloud
    if cloud is None or cloud.class_ids is None or len(cloud) == 0:
        return "unknown element"
    i = int(np.argmin(((cloud.points - position) ** 2).sum(axis=1)))
    c = int(cloud.class_ids[i])
    return CLASS_NAMES[c] if c < len(CLASS_NAMES) else "unlabelled"


def cracks(m: MissionData, full: Config) -> dict[str, Any]:
    """Cracks where elements were assessed: the map's own elements (`run --damage`) and element scans
    (`aftershock cracks --report FILE.json` in the mission's folder). Each element states the narrowest
    width its point spacing resolves; a narrower crack is not detectable there, which is not "absent"."""
    elements: list[dict[str, Any]] = []
    dmg = m.damage or {}
    if dmg.get("elements_checked"):
        found = []
        for c in dmg.get("cracks") or []:
            pos = np.asarray(c["position"], float)
            found.append(_crack_entry(c, _element_at(m, pos)))
        elements.append(
            {
                "element": f"{dmg['elements_checked']} element(s) of the map",
                "file": "damage.json",
                "narrowest_detectable_m": None,
                "narrowest_reason": "the map's elements do not record their point spacing; at most "
                f"{full.cracks.max_spacing_m * 1000:.0f} mm (coarser elements are not assessed)",
                "cracks": found,
            }
        )
    for name, data in m.crack_reports:
        spacing = _num(data.get("spacing_m"), 4)
        element = PurePath(str(data.get("input") or name)).stem
        elements.append(
            {
                "element": element,
                "file": name,
                "narrowest_detectable_m": spacing,
                "narrowest_reason": None if spacing is not None else "the report gives no point spacing",
                "cracks": [_crack_entry(c, _kind_of(element)) for c in data.get("cracks") or []],
            }
        )
    out: dict[str, Any] = {"assessed": bool(elements), "elements": elements, "reason": None}
    if not elements:
        if m.damage is None:
            out["reason"] = "no crack assessment was run (run --damage, or aftershock cracks on element scans)"
        else:
            sparse = [n for n in dmg.get("notes") or [] if "too sparse" in n or "no structural element" in n]
            out["reason"] = "; ".join(sparse) or "no element of the map was assessed for cracks"
            out["reason"] += " (not detectable from this data, which does not mean there are none)"
    return out


def _kind_of(element: str) -> str:
    low = element.lower()
    for kind in ("column", "wall", "slab", "beam", "floor", "ceiling"):
        if kind in low:
            return kind
    return element


def _crack_entry(c: dict[str, Any], element: str) -> dict[str, Any]:
    resolved = bool(c.get("width_resolved", True))
    return {
        "id": c.get("id"),
        "element": element,
        "position": c.get("position"),
        "length_m": _num(c.get("length_m")),
        "width_m": _num(c.get("width_m")) if resolved else None,
        "width_text": f"{c['width_m'] * 1000:.1f} mm"
        if resolved
        else "present, width not measurable (narrower than the scan resolves here)",
        "severity": "severe" if c.get("severe") else "minor",
        "resolvable_mm": c.get("resolvable_mm"),  # the narrowest width the scan resolves at this crack
    }


# ------------------------------------------------------------------------------------------------ checklist


def _item(item: str, status: str, evidence: str, where: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    return {"item": item, "status": status, "evidence": evidence, "where": where or []}


def _structural_count(inv: list[dict[str, Any]], key: str) -> int:
    return sum(int(s[key]) for s in inv)


def _near_doors(m: MissionData, cfg: ReportConfig) -> tuple[int, np.ndarray | None, int]:
    """(door points, where debris lies within the clearance of a door (mean position) or None, debris points
    there)."""
    cloud = m.cloud
    if cloud is None or cloud.class_ids is None:
        return 0, None, 0
    door = cloud.points[cloud.class_ids == SemanticClass.DOOR]
    deb = cloud.points[cloud.class_ids == SemanticClass.DEBRIS]
    if len(door) == 0 or len(deb) == 0:
        return len(door), None, 0
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(door[:, :2]).query(deb[:, :2], distance_upper_bound=cfg.exit_clearance_m)
    near = np.isfinite(dist)
    if not near.any():
        return len(door), None, 0
    return len(door), deb[near].mean(axis=0), int(near.sum())


def checklist_and_findings(
    m: MissionData,
    levels: list[dict[str, Any]],
    inv: list[dict[str, Any]],
    deb: list[dict[str, Any]],
    crk: dict[str, Any],
    cfg: ReportConfig,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    findings: list[dict[str, Any]] = []

    def finding(kind: str, text: str, position: Any, storey: int, where: dict[str, Any]) -> int:
        n = len(findings) + 1
        pos = [round(float(v), 3) for v in position] if position is not None else None
        findings.append({"number": n, "kind": kind, "text": text, "position": pos, "storey": storey, "where": where})
        return n

    items = []
    # Collapse or partial collapse: debris over a share of a storey's floor
    measured = [d for d in deb if d["floor_share"] is not None]
    heavy = [d for d in measured if d["floor_share"] >= cfg.collapse_debris_share]
    if heavy:
        parts = []
        for d in heavy:
            n = finding(
                "debris",
                f"debris over {d['floor_share']:.1%} of storey {d['storey']}'s floor ({d['volume_m3']:.2f} m³)",
                d.get("centre"),
                d["storey"],
                _where(m, ENTITY_MAP),
            )
            parts.append(f"storey {d['storey']}: debris covers {d['floor_share']:.1%} of the floor (finding {n})")
        items.append(_item("collapse or partial collapse", FOUND, "; ".join(parts), [_where(m, ENTITY_MAP)]))
    elif measured:
        shares = ", ".join(f"storey {d['storey']} {d['floor_share']:.1%}" for d in measured)
        text = f"debris share of the floor: {shares} (partial collapse from {cfg.collapse_debris_share:.0%})"
        items.append(_item("collapse or partial collapse", NONE, text, [_where(m, ENTITY_MAP)]))
    else:
        why = str(next((d.get("reason") for d in deb if d.get("reason")), "no floor seen"))
        items.append(_item("collapse or partial collapse", NOT_ASSESSABLE, why))
    # Building or storey leaning: drift ratio per storey
    drifted = [s for s in levels if s["drift_ratio"] is not None]
    limit_text = f"1/{round(1 / cfg.drift_restricted_ratio)}"
    exceeded = [s for s in drifted if exceeds(s["drift_ratio"], ratio_uncertainty(s), cfg.drift_restricted_ratio)]
    close = [s for s in drifted if straddles(s["drift_ratio"], ratio_uncertainty(s), cfg.drift_restricted_ratio)]
    close_text = "".join(
        f"; storey {s['index']}: {s['drift_mm']:.1f} ± {_pm(s)} mm = {s['drift_ratio_text']}, {NEAR_LIMIT} {limit_text}"
        for s in close
    )
    if exceeded:
        parts = []
        for s in exceeded:
            n = finding(
                "drift",
                f"storey {s['index']}: drift {s['drift_mm']:.1f} mm ({s['drift_ratio_text']} of its height)",
                None,
                s["index"],
                _where(m, ENTITY_DRIFT),
            )
            parts.append(
                f"storey {s['index']}: drift {s['drift_mm']:.1f} ± {_pm(s)} mm = {s['drift_ratio_text']} of "
                f"{s['height_m']:.2f} m (limit {limit_text} exceeded by more than the uncertainty; finding {n})"
            )
        text = "; ".join(parts) + close_text
        items.append(_item("building or storey leaning", FOUND, text, [_where(m, ENTITY_DRIFT)]))
    elif drifted:
        below = [s for s in drifted if s not in close]
        parts = [f"storey {s['index']}: {s['drift_mm']:.1f} ± {_pm(s)} mm = {s['drift_ratio_text']}" for s in below]
        rest = len(levels) - len(drifted)
        text = "; ".join(parts) + (f" (below {limit_text})" if parts else "") + close_text
        text = text.removeprefix("; ")
        if rest:
            text += f"; {rest} storey(s) not measured"
        items.append(_item("building or storey leaning", NONE, text, [_where(m, ENTITY_DRIFT)]))
    else:
        items.append(_item("building or storey leaning", NOT_ASSESSABLE, levels[0]["reason"] or "not measured"))
    # Columns, walls, slabs: cracks on them (and the slabs' tilt)
    crack_list = [c for e in crk["elements"] for c in e["cracks"]]
    for item, kinds, key in (
        ("columns", ("column",), "columns"),
        ("walls", ("wall",), "walls"),
        ("floors and slabs", ("floor", "ceiling", "slab"), "slabs"),
    ):
        seen = _structural_count(inv, key)
        on = [c for c in crack_list if c["element"] in kinds]
        extra = ""
        tilted: list[dict[str, Any]] = []
        if key == "slabs":
            lim = cfg.tilt_restricted_deg
            tilted = [s for s in levels if exceeds(s["tilt_deg"], s["tilt_uncertainty_deg"], lim)]
            tilts = [s for s in levels if s["tilt_deg"] is not None]
            if tilts:
                extra = "; slab tilt " + ", ".join(_tilt_text(s, lim) for s in tilts)
        if on or tilted:
            parts = []
            for c in on:
                pos = np.asarray(c["position"], float) if c.get("position") is not None else None
                st = int(storey_of(pos[None], levels)[0]) if pos is not None else 0
                n = finding(
                    "crack",
                    f"{c['severity']} crack on a {c['element']}: {c['length_m']} m long, {c['width_text']}",
                    pos,
                    st,
                    _where(m, ENTITY_CRACKS, c.get("id")),
                )
                parts.append(f"{c['severity']} crack {c['length_m']:.2f} m × {c['width_text']} (finding {n})")
            for s in tilted:
                n = finding(
                    "tilt", f"storey {s['index']}: slab tilt {s['tilt_deg']:.2f}°", None, s["index"],
                    _where(m, ENTITY_STORIES),
                )  # fmt: skip
                parts.append(
                    f"storey {s['index']}: ceiling slab tilted {_tilt_pm(s)}, above {cfg.tilt_restricted_deg}° by "
                    f"more than the uncertainty (finding {n})"
                )
            lim = cfg.tilt_restricted_deg
            parts += [
                "slab tilt " + _tilt_text(s, lim)
                for s in levels
                if straddles(s["tilt_deg"], s["tilt_uncertainty_deg"], lim)
            ]
            where = [_where(m, ENTITY_CRACKS)] if on else [_where(m, ENTITY_STORIES)]
            items.append(_item(item, FOUND, "; ".join(parts), where))
        elif seen == 0 and key != "slabs":
            items.append(_item(item, NOT_ASSESSABLE, f"no {item[:-1]} seen in the map"))
        elif not crk["assessed"] and not extra:
            items.append(_item(item, NOT_ASSESSABLE, f"{seen} seen; cracks: {crk['reason']}"))
        else:
            assessed = "no crack found where assessed" if crk["assessed"] else f"cracks: {crk['reason']}"
            # a tilt whose uncertainty reaches across the limit settles nothing: with no crack assessment either,
            # the slabs were not assessable (which does not escalate the posting on its own)
            unsettled = any(
                straddles(s["tilt_deg"], s["tilt_uncertainty_deg"], cfg.tilt_restricted_deg) for s in levels
            )
            status = NONE if crk["assessed"] or (extra and not unsettled) else NOT_ASSESSABLE
            where = [_where(m, ENTITY_STORIES)] if extra else []
            items.append(_item(item, status, f"{seen} seen; {assessed}{extra}", where))
    # Debris blocking exits
    doors, spot, near = _near_doors(m, cfg)
    if doors == 0:
        items.append(
            _item("debris blocking exits", NOT_ASSESSABLE, "no door identified in the map: exits cannot be located")
        )
    elif spot is not None:
        st = int(storey_of(spot[None], levels)[0])
        n = finding("exit", f"debris within {cfg.exit_clearance_m:.1f} m of a door", spot, st, _where(m, ENTITY_MAP))
        text = f"{near} debris points within {cfg.exit_clearance_m:.1f} m of a door (finding {n})"
        items.append(_item("debris blocking exits", FOUND, text, [_where(m, ENTITY_MAP)]))
    else:
        text = f"no debris within {cfg.exit_clearance_m:.1f} m of the {doors} door points seen"
        items.append(_item("debris blocking exits", NONE, text, [_where(m, ENTITY_MAP)]))
    return items, findings


def _tilt_pm(s: dict[str, Any]) -> str:
    u = s.get("tilt_uncertainty_deg")
    return f"{s['tilt_deg']:.2f} ± {u:.2f}°" if u is not None else f"{s['tilt_deg']:.2f}° (uncertainty not measured)"


def _tilt_text(s: dict[str, Any], limit: float) -> str:
    """`storey 0 0.36 ± 1.32°`, and when the limit lies inside value ± uncertainty, saying so."""
    text = f"storey {s['index']} {_tilt_pm(s)}"
    if straddles(s["tilt_deg"], s.get("tilt_uncertainty_deg"), limit):
        text += f" ({NEAR_LIMIT} {limit}°)"
    return text


def _pm(s: dict[str, Any]) -> str:
    return f"{s['uncertainty_mm']:.1f}" if s["uncertainty_mm"] is not None else "?"


def posting(items: list[dict[str, Any]], levels: list[dict[str, Any]], crk: dict[str, Any]) -> dict[str, Any]:
    """The suggested ATC-20 posting by `POSTING_RULE` (advisory), with the reasons that decided it."""
    by = {i["item"]: i for i in items}
    reasons: list[str] = []
    level = INSPECTED
    if by["collapse or partial collapse"]["status"] == FOUND:
        level, reasons = UNSAFE, [*reasons, "collapse or partial collapse found"]
    for s in levels:
        if s["flag"] == UNSAFE:
            level = UNSAFE
            reasons.append(f"storey {s['index']} at or above the unsafe drift/tilt limit")
        elif s["flag"] == RESTRICTED:
            level = max(level, RESTRICTED, key=_SEVERITY.__getitem__)
            reasons.append(f"storey {s['index']} at or above the restricted drift/tilt limit")
    severe = [c for e in crk["elements"] for c in e["cracks"] if c["severity"] == "severe"]
    if severe:
        level = max(level, RESTRICTED, key=_SEVERITY.__getitem__)
        reasons.append(f"{len(severe)} severe crack(s)")
    if by["debris blocking exits"]["status"] == FOUND:
        level = max(level, RESTRICTED, key=_SEVERITY.__getitem__)
        reasons.append("debris blocking an exit")
    unassessed = [
        k for k in ("collapse or partial collapse", "building or storey leaning") if by[k]["status"] == NOT_ASSESSABLE
    ]
    if level == INSPECTED and unassessed:
        level = RESTRICTED
        reasons.append("not assessable from this data: " + ", ".join(unassessed))
    if not reasons:
        reasons.append("collapse and leaning assessed, nothing found")
    return {"suggested": level, "rule": POSTING_RULE, "reasons": reasons, "advisory": True}


def worst_posting(postings: list[dict[str, Any]]) -> str | None:
    return max((p["suggested"] for p in postings), key=_SEVERITY.__getitem__, default=None)


# ------------------------------------------------------------------------------------------------ the mission


def _path_length(poses: np.ndarray) -> float:
    if len(poses) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(poses[:, 1:4], axis=0), axis=1).sum())


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="seconds")


def what_was_run(m: MissionData) -> list[str]:
    ran = ["registration (KISS-ICP)", f"labelling ({m.summary.get('source', {}).get('labeller') or 'unknown'})"]
    ran.append("clustering into objects")
    if m.folder is not None and (m.folder / "refined.ply").is_file():
        ran.append("LRGNet refinement (--refine)")
    if m.damage is not None:
        ran.append("damage assessment: cracks, storey drift and tilt (--damage)")
    if m.structure is not None:
        ran.append("structure model (structure.json)")
    if m.crack_reports:
        ran.append(f"crack assessment of {len(m.crack_reports)} element scan(s)")
    return ran


def assess_mission(m: MissionData, full: Config) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The report's content for one mission (a failed one: its name, status and error only), and its storeys
    with their floor planes (for the plan views)."""
    cfg = full.report
    base: dict[str, Any] = {"name": m.name, "status": m.status, "error": m.error, "source": m.source}
    base["folder"] = str(m.folder) if m.folder is not None else None
    if m.status == "failed":
        return base | {"storeys": [], "checklist": [], "findings": [], "posting": None}, []
    source = m.summary.get("source")
    src = source if isinstance(source, dict) else {}
    poses = m.poses
    measured = measure_levels(m, full)
    levels = storeys(m, measured, cfg)
    inv = inventory(m, levels)
    deb = debris(m, levels, cfg)
    crk = cracks(m, full)
    items, findings = checklist_and_findings(m, levels, inv, deb, crk, cfg)
    return base | {
        "recording": str(m.recording) if m.recording is not None else None,
        "started_utc": _iso(float(poses[0, 0])) if len(poses) and poses[0, 0] > CLOCK_SINCE_S else None,
        "duration_s": round(float(poses[-1, 0] - poses[0, 0]), 2) if len(poses) > 1 else None,
        "path_length_m": round(_path_length(poses), 2),
        "scans": m.summary.get("scans"),
        "map_points": m.summary.get("map_points"),
        "sensor": {k: src.get(k) for k in ("source_kind", "topic", "environment", "labeller")},
        "what_was_run": what_was_run(m),
        "storeys": [{k: v for k, v in s.items() if k != "plane"} for s in levels],
        "inventory": inv,
        "cracks": crk,
        "debris": deb,
        "checklist": items,
        "findings": findings,
        "posting": posting(items, levels, crk),
        "drift_measured": {
            "from": measured.measured_from,
            "up": measured.gravity,
            "up_text": UP_TEXT.get(str(measured.gravity), "unknown"),
        },
        "notes": list(dict.fromkeys([*measured.notes, *((m.damage or {}).get("notes") or [])])),
    }, levels
