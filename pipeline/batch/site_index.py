"""The site index: one row per mission of a `batch` output folder, as `DIR/missions.parquet`.

    duckdb.sql("SELECT mission, scans, objects_column, severe_cracks FROM 'out/missions.parquet'")
    pandas.read_parquet("out/missions.parquet")

The schema is fixed (every class has its `objects_<class>` column, absent values are null) so indexes of
different batches concatenate. Columns are only ever added, never renamed or dropped (like `--json`).
The file is replaced atomically, so a reader never sees half an index.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Final

import pyarrow as pa
import pyarrow.parquet as pq

from aftershock.pipeline.classes import CLASS_NAMES
from aftershock.pipeline.errors import InputError, OutputError

INDEX_FILE: Final = "missions.parquet"

STATUS_OK: Final = "ok"
STATUS_FAILED: Final = "failed"
STATUS_INTERRUPTED: Final = "interrupted"

OBJECT_COLUMNS: Final[tuple[str, ...]] = tuple(f"objects_{name}" for name in CLASS_NAMES)

# Elements the structure model found, per column: the element kinds (summary `structure_elements`) it counts.
STRUCTURE_COLUMNS: Final[dict[str, tuple[str, ...]]] = {
    "structure_slabs": ("floor", "ceiling"),
    "structure_walls": ("wall",),
    "structure_columns": ("column",),
    "structure_beams": ("beam",),
    "structure_grounds": ("ground",),
    "structure_openings": ("window", "door"),
}

# (name, type, what); the order is the column order of the file and of the --json rows.
COLUMNS: Final[tuple[tuple[str, pa.DataType, str], ...]] = (
    ("mission", pa.string(), "folder name under the output folder"),
    ("source", pa.string(), "the log as given (absolute path or sim:// URI)"),
    ("status", pa.string(), "ok | failed | interrupted"),
    ("error", pa.string(), "one-line error of a failed mission"),
    ("warnings", pa.string(), "warnings while reading (e.g. a log cut off part-way), one per line"),
    ("reused", pa.bool_(), "complete from an earlier run with the same configuration, not redone"),
    ("source_kind", pa.string(), "mcap | bag | files | sim"),
    ("scans", pa.int64(), "scans through every stage"),
    ("points", pa.int64(), "input points"),
    ("duration_s", pa.float64(), "log time from the first to the last scan"),
    ("path_length_m", pa.float64(), "length of the estimated trajectory"),
    ("ate_m", pa.float64(), "trajectory error (ATE RMSE) where the log has true poses"),
    ("registration_failures", pa.int64(), "scans KISS-ICP could not align"),
    ("map_voxels", pa.int64(), "voxels of the labelled map"),
    ("objects", pa.int64(), "instances in the map"),
    *((col, pa.int64(), f"instances whose majority class is {col[8:]}") for col in OBJECT_COLUMNS),
    ("cracks", pa.int64(), "cracks found (--damage)"),
    ("severe_cracks", pa.int64(), "cracks at or above the severe width (--damage)"),
    ("worst_drift_mm", pa.float64(), "largest story drift (--damage)"),
    ("worst_tilt_deg", pa.float64(), "largest story tilt (--damage)"),
    ("environment", pa.string(), "indoor | outdoor"),
    ("labeller", pa.string(), "the labeller used"),
    ("processing_s", pa.float64(), "wall time of the mission's task"),
    ("cpu_s", pa.float64(), "CPU time the mission's worker spent on it (all its threads)"),
    ("scans_per_second", pa.float64(), "stream throughput of the mission"),
    ("peak_rss_mb", pa.float64(), "largest resident memory of the worker seen during the mission"),
    ("node", pa.string(), "host that ran the mission"),
    ("finished_at", pa.string(), "UTC time the mission ended (ISO 8601)"),
    ("config_hash", pa.string(), "fingerprint of the configuration the mission ran with"),
    ("folder", pa.string(), "the mission's output folder"),
    ("recording", pa.string(), "Rerun recording (.rrd)"),
    ("map", pa.string(), "labelled map (PLY)"),
    ("poses_tum", pa.string(), "trajectory, TUM format"),
    ("poses_kitti", pa.string(), "trajectory, KITTI format"),
    ("summary", pa.string(), "summary.json"),
    ("damage", pa.string(), "damage.json (--damage)"),
    *(
        (col, pa.int64(), f"structural elements found ({' and '.join(kinds)}; null: structure model off)")
        for col, kinds in STRUCTURE_COLUMNS.items()
    ),
)
SCHEMA: Final = pa.schema([pa.field(name, kind, metadata={"doc": doc}) for name, kind, doc in COLUMNS])
COLUMN_NAMES: Final[tuple[str, ...]] = tuple(name for name, _, _ in COLUMNS)


def empty_row(mission: str, source: str) -> dict[str, Any]:
    """A row with every column, all null but the mission's name and source."""
    row: dict[str, Any] = dict.fromkeys(COLUMN_NAMES)
    row["mission"] = mission
    row["source"] = source
    row["reused"] = False
    return row


def normalise(row: Mapping[str, Any]) -> dict[str, Any]:
    """The row with exactly the index's columns (unknown keys dropped, missing ones null)."""
    return {name: row.get(name) for name in COLUMN_NAMES}


def write_index(path: Path, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write the rows (sorted by mission) to `path`, atomically."""
    ordered = sorted((normalise(r) for r in rows), key=lambda r: r["mission"])
    table = pa.Table.from_pylist(ordered, schema=SCHEMA)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write the site index: {exc.strerror}", path) from None
    return path


def read_index(path: Path) -> list[dict[str, Any]]:
    """The rows of an index (columns this version does not know are kept; missing ones are null)."""
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise InputError(f"not a readable site index ({exc})", path) from None
    return [{name: None for name in COLUMN_NAMES} | row for row in table.to_pylist()]
