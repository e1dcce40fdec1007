"""The structure model's elements as the outputs show them: `world/structure/...` in Rerun (slabs and walls as
outlined planes, columns, beams and debris as boxes, in their class colours) and `structure.json` beside an export."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import rerun as rr

from aftershock.pipeline.classes import CLASS_COLORS
from aftershock.pipeline.structure.elements import Element, Kind

ROOT: Final = "world/structure"
OUTLINED: Final = (Kind.FLOOR, Kind.CEILING, Kind.WALL, Kind.GROUND)
BOXED: Final = (Kind.COLUMN, Kind.BEAM, Kind.DEBRIS)
OPENINGS: Final = (Kind.WINDOW, Kind.DOOR)  # outlined rectangles in their wall's face, in one entity
LINE_RADIUS: Final = 0.02
PLURAL: Final = {Kind.DEBRIS: "debris"}  # entity names: `world/structure/debris`, not `debriss`


def structure_json(elements: Sequence[Element], notes: Sequence[str] = ()) -> dict[str, Any]:
    """The document `structure.json` holds: every element, a count per kind, and what the model said."""
    counts: dict[str, int] = {}
    for e in elements:
        counts[e.kind.value] = counts.get(e.kind.value, 0) + 1
    return {"elements": [e.to_json() for e in elements], "counts": counts, "notes": list(notes)}


def write_structure_json(path: Path, elements: Sequence[Element], notes: Sequence[str] = ()) -> None:
    path.write_text(json.dumps(structure_json(elements, notes), indent=2) + "\n")


def log_structure(rec: rr.RecordingStream, elements: Sequence[Element]) -> None:
    """One entity per kind under `world/structure` (each logged whole, replacing the last: elements come and go);
    windows and doors together in `world/structure/openings`."""
    for kind in (*OUTLINED, *BOXED):  # one iteration per kind of element
        mine = [e for e in elements if e.kind is kind]
        path = f"{ROOT}/{PLURAL.get(kind, kind.value + 's')}"
        if not mine:
            rec.log(path, rr.Clear(recursive=False))
            continue
        colors = np.array([CLASS_COLORS[e.class_id] for e in mine], np.uint8)
        labels = [f"{kind.value} {e.id}" for e in mine]
        if kind in OUTLINED:
            strips = [e.outline() for e in mine]
            rec.log(path, rr.LineStrips3D(strips, colors=colors, radii=LINE_RADIUS, labels=labels))
        else:
            lo = np.array([e.lo for e in mine])
            hi = np.array([e.hi for e in mine])
            rec.log(path, rr.Boxes3D(centers=(lo + hi) / 2, half_sizes=(hi - lo) / 2, colors=colors, labels=labels))
    openings = [e for e in elements if e.kind in OPENINGS]
    if not openings:
        rec.log(f"{ROOT}/openings", rr.Clear(recursive=False))
        return
    rec.log(
        f"{ROOT}/openings",
        rr.LineStrips3D(
            [e.outline() for e in openings],
            colors=np.array([CLASS_COLORS[e.class_id] for e in openings], np.uint8),
            radii=LINE_RADIUS,
            labels=[f"{e.kind.value} {e.id}" for e in openings],
        ),
    )
