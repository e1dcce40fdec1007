"""The structural elements of a building as the structure model keeps them, and their JSON form.

An element is one floor or ceiling slab face, one wall (its pieces in every tile merged), one column, one beam,
the ground outdoors, or one mass of debris on a floor. Each carries an id (stable while the element lives), its
kind, its extent (an axis-aligned box in the levelled map), a plane (slabs, walls) or an axis (columns, beams), and
its support: the map voxels on it and the scans that saw them.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass


class Kind(StrEnum):
    FLOOR = "floor"
    CEILING = "ceiling"
    WALL = "wall"
    COLUMN = "column"
    BEAM = "beam"
    GROUND = "ground"
    WINDOW = "window"  # openings: a rectangle in a wall's face
    DOOR = "door"
    DEBRIS = "debris"  # a mass on a floor slab shaped like no furniture (not structure: see CONTENT_CLASS)


CLASS_OF: Final[dict[Kind, SemanticClass]] = {
    Kind.FLOOR: SemanticClass.FLOOR,
    Kind.CEILING: SemanticClass.CEILING,
    Kind.WALL: SemanticClass.WALL,
    Kind.COLUMN: SemanticClass.COLUMN,
    Kind.BEAM: SemanticClass.BEAM,
    Kind.GROUND: SemanticClass.GROUND,
}
OPENING_CLASS: Final[dict[Kind, SemanticClass]] = {Kind.WINDOW: SemanticClass.WINDOW, Kind.DOOR: SemanticClass.DOOR}
# what lies on the structure, found from its shape: not in CLASS_OF, so that the network's confident debris on a
# wall or a floor stays non-structural (pipeline.structure.model NON_STRUCTURAL)
CONTENT_CLASS: Final[dict[Kind, SemanticClass]] = {Kind.DEBRIS: SemanticClass.DEBRIS}


@dataclass(slots=True)
class Element:
    id: int
    kind: Kind
    lo: np.ndarray  # (3,) extent, lowest corner
    hi: np.ndarray  # (3,) extent, highest corner
    plane: np.ndarray | None = None  # (4,) a, b, c, d with a unit normal: slabs and walls
    axis: np.ndarray | None = None  # (3,) unit direction: columns (up) and beams (along their length)
    voxels: int = 0
    scans: int = 0

    @property
    def class_id(self) -> int:
        for table in (CLASS_OF, OPENING_CLASS, CONTENT_CLASS):
            if self.kind in table:
                return int(table[self.kind])
        raise KeyError(self.kind)

    def outline(self) -> np.ndarray:
        """(5, 3) closed outline of a slab (its extent on its plane), a wall (its face between its ends) or an
        opening (its rectangle in the wall's face)."""
        lo, hi = self.lo, self.hi
        if self.kind in (Kind.WALL, Kind.WINDOW, Kind.DOOR) and self.plane is not None:
            n = self.plane[:2] / max(float(np.linalg.norm(self.plane[:2])), 1e-9)
            along = np.array([-n[1], n[0]])
            corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
            u = corners @ along
            # the face's ends: the extent's corners projected on the wall line
            base = -self.plane[3] * n
            a, b = base + u.min() * along, base + u.max() * along
            return np.array([[*a, lo[2]], [*b, lo[2]], [*b, hi[2]], [*a, hi[2]], [*a, lo[2]]])
        z = lo[2] if self.plane is None else None
        xy = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]], [lo[0], lo[1]]])
        if z is None and self.plane is not None:
            p = self.plane
            heights = -(xy @ p[:2] + p[3]) / p[2] if abs(p[2]) > 1e-6 else np.full(5, lo[2])
        else:
            heights = np.full(5, lo[2])
        return np.c_[xy, heights]

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "id": self.id,
            "kind": self.kind.value,
            "class_id": self.class_id,
            "extent": {"min": [round(float(v), 3) for v in self.lo], "max": [round(float(v), 3) for v in self.hi]},
            "support": {"voxels": int(self.voxels), "scans": int(self.scans)},
        }
        if self.plane is not None:
            out["plane"] = [round(float(v), 5) for v in self.plane]
        if self.axis is not None:
            out["axis"] = [round(float(v), 5) for v in self.axis]
        return out
