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

# RGB colours, chosen so that every two classes stay apart (CIE76 ΔE at least 28; tests/test_palette.py prints
# the closest pair): structure in blues and tans, contents in saturated hues, debris dark brown.
CLASS_COLORS: Final[np.ndarray] = np.array(
    [
        [170, 220, 255],  # ceiling: pale sky blue
        [165, 140, 95],  # floor: tan
        [100, 140, 230],  # wall: mid blue
        [255, 170, 60],  # beam: orange
        [220, 30, 40],  # column: red
        [40, 200, 190],  # window: teal
        [150, 70, 210],  # door: purple
        [120, 200, 60],  # table: green
        [255, 110, 200],  # chair: pink
        [215, 215, 40],  # sofa: yellow
        [30, 70, 120],  # bookcase: navy
        [255, 240, 170],  # board: cream
        [128, 128, 128],  # clutter: grey
        [115, 60, 20],  # debris: dark brown
        [110, 150, 80],  # ground: moss green
    ],
    dtype=np.uint8,
)
UNLABELLED_COLOR: Final[np.ndarray] = np.array([40, 40, 40], dtype=np.uint8)
# Voxels whose label the labeller is unsure of are drawn again in this colour over the map (no class has it).
UNCERTAIN_COLOR: Final[np.ndarray] = np.array([255, 0, 200], dtype=np.uint8)  # magenta

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


def cie_lab(rgb: np.ndarray) -> np.ndarray:
    """sRGB (0-255, D65) to CIE L*a*b*: the space in which palette distances (ΔE76) are measured."""
    c = np.asarray(rgb, np.float64) / 255.0
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    m = np.array(
        [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
    )
    xyz = c @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)
