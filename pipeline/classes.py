"""The one class table: ids, names and colours shared by the simulator, the networks, the metrics and Rerun.

The ids are part of the file formats (DESIGN.md): the order of the Stanford indoor benchmark, then debris.
New classes are appended after the last one; 65535 means unlabelled. The networks predict the first
`NETWORK_CLASSES` (their output heads); the classes after them come from the structure model alone
(pipeline.structure): ground, the terrain a robot drives on outdoors.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

import numpy as np


class SemanticClass(IntEnum):
    CEILING = 0
    FLOOR = 1
    WALL = 2
    BEAM = 3
    COLUMN = 4
    WINDOW = 5
    DOOR = 6
    TABLE = 7
    CHAIR = 8
    SOFA = 9
    BOOKCASE = 10
    BOARD = 11
    CLUTTER = 12
    DEBRIS = 13
    GROUND = 14  # outdoors: the terrain (the structure model's, never a network's)


UNLABELLED: Final = 65535
NUM_CLASSES: Final = len(SemanticClass)  # every class a map can hold (metrics, formats, the viewer)
NETWORK_CLASSES: Final = SemanticClass.DEBRIS + 1  # the classes the networks predict (their output heads)

CLASS_NAMES: Final[tuple[str, ...]] = tuple(c.name.lower() for c in SemanticClass)

# RGB colours, chosen to stay distinguishable in the viewer (structure in muted tones, contents bright).
CLASS_COLORS: Final[np.ndarray] = np.array(
    [
        [158, 218, 229],  # ceiling
        [152, 138, 114],  # floor
        [174, 199, 232],  # wall
        [255, 187, 120],  # beam
        [214, 39, 40],  # column
        [44, 160, 44],  # window
        [148, 103, 189],  # door
        [140, 86, 75],  # table
        [227, 119, 194],  # chair
        [188, 189, 34],  # sofa
        [31, 119, 180],  # bookcase
        [255, 127, 14],  # board
        [127, 127, 127],  # clutter
        [90, 60, 30],  # debris
        [110, 150, 80],  # ground
    ],
    dtype=np.uint8,
)
UNLABELLED_COLOR: Final[np.ndarray] = np.array([40, 40, 40], dtype=np.uint8)

STRUCTURAL_CLASSES: Final[frozenset[SemanticClass]] = frozenset(
    {SemanticClass.CEILING, SemanticClass.FLOOR, SemanticClass.WALL, SemanticClass.BEAM, SemanticClass.COLUMN}
)


def class_colors(class_ids: np.ndarray) -> np.ndarray:
    """Colour per point for an array of class ids (unlabelled and unknown ids in dark grey)."""
    ids = np.asarray(class_ids)
    out = np.broadcast_to(UNLABELLED_COLOR, (*ids.shape, 3)).copy()
    known = ids < NUM_CLASSES
    out[known] = CLASS_COLORS[ids[known].astype(np.intp)]
    return out


def instance_colors(instance_ids: np.ndarray) -> np.ndarray:
    """A stable, well-spread colour per instance id (0, "no object", in dark grey)."""
    ids = np.asarray(instance_ids, dtype=np.uint64)
    # Golden-ratio hue steps keep neighbouring ids apart; a hash of the id mixes brightness.
    hue = (ids.astype(np.float64) * 0.618033988749895) % 1.0
    mixed = (ids * np.uint64(2654435761)) % np.uint64(1000)
    value = 0.65 + 0.35 * (mixed.astype(np.float64) / 1000.0)
    rgb = _hsv_to_rgb(hue, np.full_like(hue, 0.75), value)
    out = (rgb * 255).astype(np.uint8)
    out[ids == 0] = UNLABELLED_COLOR
    return out


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    i = np.floor(h * 6.0).astype(np.int64) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    choices = [
        np.stack([v, t, p], -1),
        np.stack([q, v, p], -1),
        np.stack([p, v, t], -1),
        np.stack([p, q, v], -1),
        np.stack([t, p, v], -1),
        np.stack([v, p, q], -1),
    ]
    out = np.zeros((*h.shape, 3))
    for k, c in enumerate(choices):
        out[i == k] = c[i == k]
    return out
