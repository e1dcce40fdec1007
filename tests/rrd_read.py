"""Read an .rrd back for tests: entities, timelines and component values, through rerun-sdk's chunk reader
(`rerun.chunk.RrdReader`), plus the `rerun rrd verify` command line check."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader

ROW_ID: Final = "rerun.controls.RowId"


@dataclass
class Recording:
    """What one recording store of an .rrd holds, entity by entity (leading "/" removed from paths)."""

    application_id: str
    recording_id: str
    blueprints: int
    timelines: set[str] = field(default_factory=set)
    static: dict[str, list[pa.RecordBatch]] = field(default_factory=lambda: defaultdict(list))
    temporal: dict[str, list[pa.RecordBatch]] = field(default_factory=lambda: defaultdict(list))

    @property
    def entities(self) -> set[str]:
        return set(self.static) | set(self.temporal)

    def under(self, prefix: str) -> set[str]:
        return {e for e in self.entities if e == prefix or e.startswith(prefix + "/")}

    def components(self, entity: str) -> set[str]:
        return {n for b in self.static.get(entity, []) + self.temporal.get(entity, []) for n in b.schema.names}

    def rows(self, entity: str, component: str, *, static: bool = False) -> list:
        """The logged values of one component, one entry per row (Python lists), in log order: by row id, as
        the viewer orders them. The file's chunk order is not log order: rows of one entity with different
        components go to different chunks, which one flush writes in no set order."""
        batches = (self.static if static else self.temporal).get(entity, [])
        keyed: list[tuple[bytes, int, object]] = []
        for b in batches:
            if component not in b.schema.names:
                continue
            row_ids = b.column(ROW_ID).to_pylist() if ROW_ID in b.schema.names else [b""] * b.num_rows
            for row_id, v in zip(row_ids, b.column(component).to_pylist(), strict=True):
                if v is not None:
                    keyed.append((row_id, len(keyed), v))
        keyed.sort(key=lambda k: (k[0], k[1]))  # row ids are big-endian TUIDs: their bytes sort in time order
        return [v for _, _, v in keyed]

    def times(self, entity: str, component: str, timeline: str) -> np.ndarray:
        """The time of each row of `component` on `timeline` (int64: sequence numbers or ns)."""
        out: list[int] = []
        for b in self.temporal.get(entity, []):
            if component in b.schema.names and timeline in b.schema.names:
                has = b.column(component).is_valid().to_numpy(zero_copy_only=False)
                t = b.column(timeline).cast(pa.int64()).to_numpy(zero_copy_only=False)
                out.extend(t[has].tolist())
        return np.asarray(sorted(out), dtype=np.int64)

    def texts(self, entity: str, component: str = "TextLog:text", *, static: bool = False) -> list[str]:
        """Every string logged on an entity (text logs by default), flattened over rows."""
        return [t for row in self.rows(entity, component, static=static) for t in row]

    def values(self, entity: str, component: str) -> np.ndarray:
        """All values of a per-point component over every row, flattened into one array."""
        rows = self.rows(entity, component)
        return np.concatenate([np.asarray(r) for r in rows]) if rows else np.zeros(0)


def read_rrd(path: str | Path) -> Recording:
    """Every chunk of the first recording store of an .rrd (works with and without the footer)."""
    with warnings.catch_warnings():  # a recording received over gRPC has no footer: read it front to back
        warnings.simplefilter("ignore")
        reader = RrdReader(path)
    stores = reader.recordings()
    if not stores:
        raise ValueError(f"{path}: no recording in the file")
    rec = Recording(stores[0].application_id, stores[0].recording_id, len(reader.blueprints()))
    for chunk in reader.stream(store=stores[0]):
        entity = chunk.entity_path.lstrip("/")
        rec.timelines.update(chunk.timeline_names)
        (rec.static if chunk.is_static else rec.temporal)[entity].append(chunk.to_record_batch())
    return rec


def rerun_rrd(subcommand: str, path: str | Path) -> subprocess.CompletedProcess:
    """`rerun rrd SUBCOMMAND PATH` with the rerun command next to this Python."""
    rerun = Path(sys.executable).with_name("rerun")
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    cmd = [str(rerun), "rrd", subcommand, str(path)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)


def rrd_verify(path: str | Path) -> subprocess.CompletedProcess:
    """`rerun rrd verify PATH`: whether the file is a complete, valid recording."""
    return rerun_rrd("verify", path)


def rrd_print(path: str | Path) -> subprocess.CompletedProcess:
    """`rerun rrd print PATH`: what a recording holds, read as far as it goes."""
    return rerun_rrd("print", path)


def record_structure(path: Path, elements: list) -> Recording:
    """The structure layer of `elements` (pipeline.structure.elements.Element) written to an .rrd at `path`, read
    back: what a viewer would get from `sinks.structure_layer.log_structure`."""
    import rerun as rr

    from aftershock.sinks.structure_layer import log_structure

    rec = rr.RecordingStream("aftershock-test")
    rec.save(str(path))
    log_structure(rec, elements)
    rec.flush()
    rec.disconnect()
    return read_rrd(path)
