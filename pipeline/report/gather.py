"""Read the results of a `run --export` folder or a `batch` folder into one `Site` of `MissionData`.

A damaged file (JSON that does not parse, a map PLY that does not read, a pose file with wrong columns) raises
`InputError` naming it; a mission the batch reports as failed becomes a `MissionData` with its error, and
the others still load.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from aftershock.pipeline.cloud_io import read_cloud
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import LabelledCloud

SUMMARY_FILE: Final = "summary.json"
DAMAGE_FILE: Final = "damage.json"
MAP_FILE: Final = "map.ply"
TUM_FILE: Final = "poses_tum.txt"
STRUCTURE_FILE: Final = "structure.json"  # the structure model (issue 28), when it was made
MARKER_FILE: Final = "mission.json"  # a finished batch mission
INDEX_FILE: Final = "missions.parquet"  # the batch's site index
RECORDING_FILE: Final = "recording.rrd"
REPORT_JSON: Final = "report.json"
# JSON files of a folder that are not crack reports of an element scan (`aftershock cracks --report FILE`)
_KNOWN_JSON: Final = frozenset({SUMMARY_FILE, DAMAGE_FILE, STRUCTURE_FILE, MARKER_FILE, REPORT_JSON, "batch.json"})


@dataclass
class MissionData:
    """One mission's results as read from its folder (`status` failed: only `error` and the index row)."""

    name: str
    status: str  # ok | failed | interrupted
    folder: Path | None = None
    error: str | None = None
    source: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    damage: dict[str, Any] | None = None  # damage.json (run --damage)
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 8)))  # TUM rows: t x y z qx qy qz qw
    cloud: LabelledCloud | None = None  # map.ply
    structure: dict[str, Any] | None = None  # structure.json
    crack_reports: list[tuple[str, dict[str, Any]]] = field(default_factory=list)  # (file name, cracks JSON)
    recording: Path | None = None
    row: dict[str, Any] | None = None  # the site index row (batch)


@dataclass
class Site:
    folder: Path
    kind: str  # export | batch
    missions: list[MissionData]


def read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except UnicodeDecodeError:
        raise InputError("damaged: not a text file", path) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"damaged: not valid JSON ({exc.msg}, line {exc.lineno})", path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path) from None
    if not isinstance(data, dict):
        raise InputError(f"damaged: a JSON object was expected, not {type(data).__name__}", path)
    return data


def read_poses(path: Path) -> np.ndarray:
    """TUM poses (N, 8); an empty file is no pose."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    if not rows:
        return np.zeros((0, 8))
    if any(len(r) != 8 for r in rows):
        raise InputError("damaged: a TUM pose line has 8 numbers (t x y z qx qy qz qw)", path)
    try:
        return np.array(rows, dtype=np.float64)
    except ValueError:
        raise InputError("damaged: a pose line holds something other than numbers", path) from None


def read_map(path: Path) -> LabelledCloud:
    try:
        cloud = read_cloud(path)
    except InputError:
        raise
    except Exception as exc:  # plyfile and open3d raise their own errors for a cut or garbled file
        raise InputError(f"damaged: not a readable PLY ({type(exc).__name__}: {exc})", path) from None
    if cloud.class_ids is None:
        raise InputError("has no class_id: not a map written by aftershock run --export", path)
    return cloud


def _crack_reports(folder: Path) -> list[tuple[str, dict[str, Any]]]:
    out = []
    for path in sorted(folder.glob("*.json")):
        if path.name in _KNOWN_JSON:
            continue
        data = read_json(path)
        if "cracks" in data and "spacing_m" in data:
            out.append((path.name, data))
    return out


def read_mission(folder: Path, name: str, row: dict[str, Any] | None = None) -> MissionData:
    """A finished mission's folder: summary.json, poses and map are required; damage, structure and crack
    reports are read where present."""
    summary_path = folder / SUMMARY_FILE
    if not summary_path.is_file():
        raise InputError(f"missing {SUMMARY_FILE}: not the folder of a finished mission", folder)
    summary = read_json(summary_path)
    for required in (MAP_FILE, TUM_FILE):
        if not (folder / required).is_file():
            raise InputError(f"missing: the mission's {SUMMARY_FILE} names it", folder / required)
    status = "interrupted" if summary.get("interrupted") else "ok"
    source = (summary.get("source") or {}).get("source") if isinstance(summary.get("source"), dict) else None
    recording = folder / RECORDING_FILE
    return MissionData(
        name=name,
        status=status,
        folder=folder,
        source=source,
        summary=summary,
        damage=read_json(folder / DAMAGE_FILE) if (folder / DAMAGE_FILE).is_file() else None,
        poses=read_poses(folder / TUM_FILE),
        cloud=read_map(folder / MAP_FILE),
        structure=read_json(folder / STRUCTURE_FILE) if (folder / STRUCTURE_FILE).is_file() else None,
        crack_reports=_crack_reports(folder),
        recording=recording if recording.is_file() else None,
        row=row,
    )


def _index_rows(path: Path) -> list[dict[str, Any]]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.read_table(path).to_pylist()
    except (OSError, pa.ArrowInvalid) as exc:
        raise InputError(f"damaged: not a readable site index ({exc})", path) from None


def gather(folder: Path) -> Site:
    """The missions of an export folder (one) or a batch folder (each row of its index, failed ones too)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such folder" if not folder.exists() else "not a folder", folder)
    if (folder / SUMMARY_FILE).is_file():
        return Site(folder, "export", [read_mission(folder, folder.resolve().name)])
    index = folder / INDEX_FILE
    if index.is_file():
        missions = []
        for row in sorted(_index_rows(index), key=lambda r: str(r.get("mission"))):
            name = str(row.get("mission"))
            status = str(row.get("status") or "failed")
            sub = Path(row["folder"]) if row.get("folder") else folder / name
            if not sub.is_dir():
                sub = folder / name  # the batch folder was moved (copied to a stick): its own subfolder
            if status == "failed" or not (sub / SUMMARY_FILE).is_file():
                error = row.get("error") or f"no results in {sub}"
                missions.append(MissionData(name, "failed", error=error, source=row.get("source"), row=row))
                continue
            mission = read_mission(sub, name, row)
            if status == "interrupted":
                mission.status = "interrupted"
            missions.append(mission)
        if missions:
            return Site(folder, "batch", missions)
    subs = sorted(p.parent for p in folder.glob(f"*/{MARKER_FILE}"))
    if subs:  # a batch folder without its index (the run was cut before writing it)
        return Site(folder, "batch", [read_mission(p, p.name) for p in subs])
    raise InputError(
        f"no mission results: neither a `run --export` folder ({SUMMARY_FILE}) nor a `batch` folder ({INDEX_FILE})",
        folder,
    )
