"""Furniture and contents as lists of box parts in the object's own frame (origin on the floor, at its centre).

Each builder draws its sizes from the generator it is given, so a seed fixes every chair leg.
`place` puts the parts into the mesh under one rigid pose (which may tip the object over).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.sources.simulator.meshes import FABRIC, METAL, WHITEBOARD, WOOD, Material, MeshBuilder


@dataclass(frozen=True, slots=True)
class Part:
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    material: Material
    color: tuple[int, int, int] | None = None


@dataclass(frozen=True, slots=True)
class Piece:
    """A furniture object: its class, parts and floor footprint (x, y half extents)."""

    cls: SemanticClass
    parts: tuple[Part, ...]
    half_extent: tuple[float, float]
    height: float


def _color(rng: np.random.Generator, palette: list[tuple[int, int, int]]) -> tuple[int, int, int]:
    return palette[int(rng.integers(len(palette)))]


WOOD_TONES = [(150, 104, 64), (186, 150, 104), (110, 76, 48), (200, 190, 170), (90, 90, 95)]
FABRIC_TONES = [(70, 84, 120), (120, 40, 40), (60, 100, 70), (150, 140, 120), (45, 45, 50), (190, 120, 50)]
CLUTTER_TONES = [(200, 60, 50), (40, 40, 45), (230, 230, 220), (60, 120, 180), (210, 180, 60), (90, 150, 80)]


def table(rng: np.random.Generator) -> Piece:
    w, d, h = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9), rng.uniform(0.70, 0.76)
    top = rng.uniform(0.025, 0.045)
    col = _color(rng, WOOD_TONES)
    parts = [Part((0, 0, h - top / 2), (w, d, top), WOOD, col)]
    leg = 0.05
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(Part((sx * (w / 2 - 0.06), sy * (d / 2 - 0.06), (h - top) / 2), (leg, leg, h - top), METAL))
    return Piece(SemanticClass.TABLE, tuple(parts), (w / 2, d / 2), h)


def chair(rng: np.random.Generator) -> Piece:
    w, seat_h = rng.uniform(0.42, 0.52), rng.uniform(0.43, 0.48)
    back_h = rng.uniform(0.35, 0.55)
    col = _color(rng, FABRIC_TONES)
    parts = [
        Part((0, 0, seat_h), (w, w, 0.06), FABRIC, col),
        Part((0, -w / 2 + 0.03, seat_h + back_h / 2 + 0.03), (w, 0.05, back_h), FABRIC, col),
    ]
    if rng.random() < 0.5:  # four legs
        for sx in (-1, 1):
            for sy in (-1, 1):
                parts.append(Part((sx * (w / 2 - 0.04), sy * (w / 2 - 0.04), seat_h / 2), (0.03, 0.03, seat_h), METAL))
    else:  # office chair: column and star base
        parts.append(Part((0, 0, seat_h / 2), (0.05, 0.05, seat_h), METAL))
        parts.append(Part((0, 0, 0.04), (0.6, 0.06, 0.05), METAL))
        parts.append(Part((0, 0, 0.04), (0.06, 0.6, 0.05), METAL))
    return Piece(SemanticClass.CHAIR, tuple(parts), (w / 2 + 0.05, w / 2 + 0.05), seat_h + back_h)


def sofa(rng: np.random.Generator) -> Piece:
    w, d = rng.uniform(1.5, 2.2), rng.uniform(0.8, 0.95)
    seat_h, back_h, arm = 0.42, rng.uniform(0.35, 0.5), 0.18
    col = _color(rng, FABRIC_TONES)
    parts = [
        Part((0, 0.05, seat_h / 2), (w - 2 * arm, d - 0.1, seat_h), FABRIC, col),
        Part((0, -d / 2 + 0.1, (seat_h + back_h + 0.25) / 2), (w, 0.2, seat_h + back_h + 0.25), FABRIC, col),
        Part((-w / 2 + arm / 2, 0, 0.3), (arm, d, 0.6), FABRIC, col),
        Part((w / 2 - arm / 2, 0, 0.3), (arm, d, 0.6), FABRIC, col),
    ]
    return Piece(SemanticClass.SOFA, tuple(parts), (w / 2, d / 2), seat_h + back_h + 0.25)


def bookcase(rng: np.random.Generator) -> Piece:
    w, d, h = rng.uniform(0.8, 1.4), rng.uniform(0.3, 0.42), rng.uniform(1.6, 2.2)
    t = 0.025
    col = _color(rng, WOOD_TONES)
    parts = [
        Part((0, -d / 2 + t / 2, h / 2), (w, t, h), WOOD, col),
        Part((-w / 2 + t / 2, 0, h / 2), (t, d, h), WOOD, col),
        Part((w / 2 - t / 2, 0, h / 2), (t, d, h), WOOD, col),
        Part((0, 0, h - t / 2), (w, d, t), WOOD, col),
    ]
    shelves = int(rng.integers(3, 6))
    for i in range(shelves):
        z = 0.05 + i * (h - 0.1) / shelves
        parts.append(Part((0, 0, z), (w - 2 * t, d, t), WOOD, col))
        x = -w / 2 + t
        while x < w / 2 - t - 0.05 and rng.random() < 0.93:  # books fill the shelf from the left
            bw = rng.uniform(0.02, 0.06)
            bh = min(rng.uniform(0.15, 0.3), (h - 0.1) / shelves - 0.04)
            bd = rng.uniform(0.15, d - 0.05)
            parts.append(
                Part(
                    (x + bw / 2, -d / 2 + t + bd / 2, z + t / 2 + bh / 2),
                    (bw, bd, bh),
                    FABRIC,
                    _color(rng, CLUTTER_TONES),
                )
            )
            x += bw + 0.002
    return Piece(SemanticClass.BOOKCASE, tuple(parts), (w / 2, d / 2), h)


def board(rng: np.random.Generator) -> Piece:
    """A wall board; its origin is on the wall, the board faces +y."""
    w, h = rng.uniform(1.2, 2.6), rng.uniform(0.8, 1.2)
    z0 = rng.uniform(0.85, 1.05)
    frame = (160, 160, 165)
    parts = [
        Part((0, 0.012, z0 + h / 2), (w, 0.02, h), WHITEBOARD, None),
        Part((0, 0.02, z0 - 0.03), (w, 0.06, 0.03), METAL, frame),
    ]
    return Piece(SemanticClass.BOARD, tuple(parts), (w / 2, 0.05), z0 + h)


def clutter(rng: np.random.Generator) -> Piece:
    """A small object: box, bin, monitor, plant pot or a stack of papers."""
    kind = int(rng.integers(5))
    col = _color(rng, CLUTTER_TONES)
    if kind == 0:  # cardboard box
        s = rng.uniform(0.2, 0.6, 3)
        parts = [Part((0, 0, s[2] / 2), tuple(s), WOOD, (170, 130, 85))]
    elif kind == 1:  # bin
        r, h = rng.uniform(0.25, 0.4), rng.uniform(0.3, 0.6)
        parts = [Part((0, 0, h / 2), (r, r, h), METAL, col)]
    elif kind == 2:  # monitor
        w = rng.uniform(0.45, 0.7)
        parts = [
            Part((0, 0, 0.01), (0.22, 0.18, 0.02), METAL, (30, 30, 30)),
            Part((0, 0, 0.12), (0.04, 0.04, 0.22), METAL, (30, 30, 30)),
            Part((0, 0, 0.22 + w * 0.3), (w, 0.03, w * 0.6), METAL, (20, 20, 25)),
        ]
    elif kind == 3:  # plant in a pot
        r, h = rng.uniform(0.25, 0.4), rng.uniform(0.6, 1.2)
        parts = [
            Part((0, 0, 0.15), (r, r, 0.3), METAL, (150, 80, 50)),
            Part((0, 0, 0.3 + h / 2), (r * 1.6, r * 1.6, h), FABRIC, (50, 120, 50)),
        ]
    else:  # stack of papers or files
        stack = (rng.uniform(0.2, 0.35), rng.uniform(0.25, 0.35), rng.uniform(0.03, 0.15))
        parts = [Part((0, 0, stack[2] / 2), stack, FABRIC, (235, 235, 225))]
    xs = [abs(p.center[0]) + p.size[0] / 2 for p in parts]
    ys = [abs(p.center[1]) + p.size[1] / 2 for p in parts]
    zs = [p.center[2] + p.size[2] / 2 for p in parts]
    return Piece(SemanticClass.CLUTTER, tuple(parts), (max(xs), max(ys)), max(zs))


def pose(x: float, y: float, z: float, rotation: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = (x, y, z)
    return m


def place(
    builder: MeshBuilder,
    piece: Piece,
    transform: np.ndarray,
    *,
    story: int,
    shade: float = 1.0,
    instance: int | None = None,
) -> int:
    """Add a piece under a rigid 4 x 4 transform (object frame -> world); returns its instance id."""
    inst = builder.new_instance(piece.cls) if instance is None else instance
    rot, trans = transform[:3, :3], transform[:3, 3]
    for p in piece.parts:
        builder.add_box(
            rot @ np.asarray(p.center) + trans,
            p.size,
            cls=piece.cls,
            instance=inst,
            material=p.material,
            rotation=rot,
            color=p.color,
            shade=shade,
            story=story,
        )
    return inst
