"""The whole report of a folder: every mission assessed, a plan view per storey, the site's worst posting."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, Final

from aftershock.pipeline.config import Config
from aftershock.pipeline.report.assess import CITATIONS, assess_mission, worst_posting
from aftershock.pipeline.report.gather import gather
from aftershock.pipeline.report.plan import draw_plan
from aftershock.pipeline.report.tilt import COVERAGE as TILT_COVERAGE

REPORT_VERSION: Final = 1  # report.json's layout; keys are only ever added


@dataclass
class Report:
    data: dict[str, Any]  # report.json
    plans: dict[tuple[str, int], bytes]  # (mission, storey) -> PNG


def _version() -> str:
    try:
        return version("aftershock")
    except PackageNotFoundError:
        return "unknown"


def make_report(folder: Path, cfg: Config) -> Report:
    site = gather(folder)
    missions = []
    plans: dict[tuple[str, int], bytes] = {}
    for m in site.missions:  # one iteration per mission
        entry, levels = assess_mission(m, cfg)
        missions.append(entry)
        for s in levels:
            plans[(m.name, s["index"])] = draw_plan(m, levels, s["index"], entry["findings"], cfg.report)
    postings = [e["posting"] for e in missions if e.get("posting")]
    r = cfg.report
    data = {
        "report_version": REPORT_VERSION,
        "generated_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "aftershock": _version(),
        "site": {
            "folder": str(site.folder),
            "kind": site.kind,
            "missions": len(missions),
            "failed": sum(e["status"] == "failed" for e in missions),
            "suggested_posting": worst_posting(postings),
            "advisory": True,
        },
        "limits": {
            "drift_restricted_ratio": r.drift_restricted_ratio,
            "drift_unsafe_ratio": r.drift_unsafe_ratio,
            "tilt_restricted_deg": r.tilt_restricted_deg,
            "tilt_unsafe_deg": r.tilt_unsafe_deg,
            "drift_uncertainty_mm": r.drift_uncertainty_mm,
            "tilt_uncertainty_coverage": TILT_COVERAGE,
            "level_uncertainty_deg": r.level_uncertainty_deg,
            "drift_gravity": r.drift_gravity,
            "collapse_debris_share": r.collapse_debris_share,
            "exit_clearance_m": r.exit_clearance_m,
            "sources": CITATIONS,
        },
        "missions": missions,
    }
    return Report(data, plans)
