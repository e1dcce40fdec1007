"""A `batch` output folder: the configuration its results were made with (`batch.json`), which missions in it
are complete (`<mission>/mission.json`), and the plan of what is left to run."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from aftershock.pipeline.batch.site_index import INDEX_FILE, STATUS_FAILED, STATUS_OK, empty_row, read_index
from aftershock.pipeline.batch.sources import MissionSource
from aftershock.pipeline.config import Config
from aftershock.pipeline.errors import AftershockError, OutputError

MANIFEST_FILE: Final = "batch.json"
MARKER_FILE: Final = "mission.json"
RECORDING_FILE: Final = "recording.rrd"
ERROR_FILE: Final = "error.txt"
OUTPUT_COLUMNS: Final[tuple[str, ...]] = ("recording", "map", "poses_tum", "poses_kitti", "summary", "damage")


# ----------------------------------------------------------------------------------- the configuration


def config_fingerprint(cfg: Config, damage: bool) -> tuple[str, dict[str, Any]]:
    """A short hash of everything that shapes a mission's results, and the settings it was made from."""
    settings = json.loads(cfg.model_dump_json()) | {"damage": damage}
    text = json.dumps(settings, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16], settings


def _differences(a: Mapping[str, Any], b: Mapping[str, Any], prefix: str = "") -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            out.extend(_differences(va, vb, f"{prefix}{key}."))
        elif va != vb:
            out.append(f"{prefix}{key}")
    return out


def prepare_output(out: Path, fingerprint: str, settings: dict[str, Any], force: bool) -> None:
    """Make the output folder, or refuse one that holds other results (another configuration, or files
    that are not a batch's) unless `force`; then record this configuration in it."""
    manifest = out / MANIFEST_FILE
    if out.exists() and not out.is_dir():
        raise OutputError("exists and is not a folder", out)
    if out.is_dir() and any(out.iterdir()) and not force:
        try:
            old = json.loads(manifest.read_text())
        except FileNotFoundError:
            raise OutputError(
                "holds files that are not a batch's results; pass --force to write into it anyway", out
            ) from None
        except (OSError, ValueError, RecursionError) as exc:
            raise OutputError(f"unreadable {MANIFEST_FILE} ({exc}); pass --force to replace it", out) from None
        if not isinstance(old, dict):
            raise OutputError(f"{MANIFEST_FILE} is not a batch manifest; pass --force to replace it", out)
        if old.get("config_hash") != fingerprint:
            old_settings = old.get("settings")
            old_settings = old_settings if isinstance(old_settings, dict) else {}
            changed = ", ".join(_differences(old_settings, settings)[:6]) or "unknown settings"
            raise OutputError(
                f"holds results of another configuration (differs in {changed}); "
                "pass --force to replace them, or choose another --out",
                out,
            )
    try:
        out.mkdir(parents=True, exist_ok=True)
        data = {"config_hash": fingerprint, "settings": settings, "written_by": "aftershock batch"}
        atomic_write(manifest, json.dumps(data, indent=2) + "\n")
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", out) from None


def atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------------ the missions


@dataclass(frozen=True, slots=True)
class MissionTask:
    """Everything a Ray worker needs to run one mission (plain data: it is pickled to the worker)."""

    name: str
    source: str
    folder: str
    config_json: str
    config_hash: str
    damage: bool
    memory_limit_bytes: int


def completed_row(folder: Path, source: str, fingerprint: str) -> dict[str, Any] | None:
    """The index row of a complete mission in `folder` (same source, same configuration, every output
    present), or None when it has to be (re)done."""
    try:
        marker = json.loads((folder / MARKER_FILE).read_text())
    except (OSError, ValueError, RecursionError):
        return None
    row = marker.get("row", {}) if isinstance(marker, dict) else None  # a file edited by hand: `[]`, "x" ...
    if not isinstance(row, dict) or not _row_types_fit(row):
        return None
    if marker.get("config_hash") != fingerprint or row.get("source") != source or row.get("status") != STATUS_OK:
        return None
    if not all((folder / Path(row[c]).name).is_file() for c in OUTPUT_COLUMNS if row.get(c)):
        return None
    return row


def _row_types_fit(row: dict[str, Any]) -> bool:
    """Whether every value of a marker's row has its index column's type (a string where a number belongs, from
    a hand edit, would break the index): a row that does not is redone, not trusted."""
    import pyarrow as pa

    from aftershock.pipeline.batch.site_index import COLUMNS

    kinds = {name: kind for name, kind, _ in COLUMNS}
    for name, value in row.items():
        kind = kinds.get(name)
        if kind is None or value is None:
            continue
        if pa.types.is_string(kind):
            ok = isinstance(value, str)
        elif pa.types.is_boolean(kind):
            ok = isinstance(value, bool)
        elif pa.types.is_integer(kind):
            ok = isinstance(value, int) and not isinstance(value, bool) and -(2**63) <= value < 2**63
        elif pa.types.is_floating(kind):
            ok = isinstance(value, int | float) and not isinstance(value, bool)
        else:
            ok = True
        if not ok:
            return False
    return all(isinstance(row.get(c), str | None) for c in OUTPUT_COLUMNS)


def taken_names(out: Path) -> dict[str, str]:
    """Mission folders already in the output folder, by name, with the source each holds."""
    names: dict[str, str] = {}
    if not out.is_dir():
        return names
    for marker in out.glob(f"*/{MARKER_FILE}"):
        try:
            source = json.loads(marker.read_text())["row"]["source"]
        except (OSError, ValueError, KeyError, TypeError, IndexError, RecursionError):
            continue
        if isinstance(source, str):
            names[marker.parent.name] = source
    return names


# ------------------------------------------------------------------------------------------ the index


def merge_index(out: Path, rows: Sequence[dict[str, Any]], fingerprint: str) -> list[dict[str, Any]]:
    """This run's rows over the rows already in the index (missions of earlier batches into the same
    folder stay listed as long as they were made with the same configuration)."""
    path = out / INDEX_FILE
    merged: dict[str, dict[str, Any]] = {}
    if path.is_file():
        try:
            old = read_index(path)
        except AftershockError:
            old = []
        merged = {r["mission"]: r for r in old if r.get("config_hash") == fingerprint}
    merged |= {r["mission"]: r for r in rows}
    return sorted(merged.values(), key=lambda r: r["mission"])


def plan(
    missions: Sequence[MissionSource], out: Path, cfg: Config, damage: bool, force: bool, worker_memory: int
) -> tuple[list[MissionTask], list[dict[str, Any]], str]:
    """Split the missions into tasks to run and rows known without running (reused complete missions,
    sources that are no mission); returns those and the configuration's fingerprint."""
    from aftershock import sources

    fingerprint, _ = config_fingerprint(cfg, damage)
    tasks: list[MissionTask] = []
    known: list[dict[str, Any]] = []
    cfg_json = cfg.model_dump_json()
    for m in missions:
        folder = out / m.name
        error = m.error
        if error is None:
            try:
                sources.kind_of(m.source)  # a missing, unreadable or non-log file: no task, no folder
            except AftershockError as exc:
                error = str(exc)
        if error is not None:
            row = empty_row(m.name, m.source) | {"status": STATUS_FAILED, "error": error, "config_hash": fingerprint}
            known.append(row)
            continue
        done = None if force else completed_row(folder, m.source, fingerprint)
        if done is not None:
            known.append(done | {"reused": True})
            continue
        tasks.append(MissionTask(m.name, m.source, str(folder), cfg_json, fingerprint, damage, worker_memory))
    return tasks, known, fingerprint
