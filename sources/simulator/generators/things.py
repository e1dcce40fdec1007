"""Furniture and clutter of the independent generators, shaped unlike the families' (`furniture.py`): steel racks
and lockers, trestle workbenches, pedestal round tables, stools and bulky armchairs, waiting benches, screens
and pinboards, crates, drums, pallets, cones and bags. Same `Piece` container, other shapes and sizes."""

from __future__ import annotations

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.furniture import Part, Piece
from aftershock.sources.simulator.meshes import FABRIC, METAL, WHITEBOARD, WOOD, Material

Color = tuple[int, int, int]

STEEL_TONES: list[Color] = [
    (70, 90, 140),
    (200, 120, 40),
    (120, 124, 130),
    (40, 110, 70),
    (180, 40, 40),
    (230, 200, 60),
]
LAMINATE_TONES: list[Color] = [(235, 232, 224), (170, 140, 110), (60, 60, 64), (205, 190, 160), (150, 170, 180)]
UPHOLSTERY_TONES: list[Color] = [
    (30, 60, 110),
    (150, 30, 50),
    (90, 90, 90),
    (200, 170, 120),
    (40, 110, 110),
    (230, 140, 40),
]
THING_TONES: list[Color] = [(210, 180, 120), (30, 30, 35), (240, 110, 30), (20, 90, 170), (160, 40, 30), (80, 140, 60)]


def _pick(rng: np.random.Generator, tones: list[Color]) -> Color:
    return tones[int(rng.integers(len(tones)))]


def _octagon(center: tuple[float, float, float], d: float, h: float, mat: Material, col: Color | None) -> list[Part]:
    """A round-ish slab: two squares, the second turned 45 degrees (as two axis-aligned boxes of a piece
    cannot turn, the turned one is approximated by a cross of two narrower boxes)."""
    s = d / np.sqrt(2)
    return [Part(center, (d, s, h), mat, col), Part(center, (s, d, h), mat, col)]


def rack(rng: np.random.Generator) -> Piece:
    """Steel shelving: four posts, 3-5 open shelves, boxes on them (a bookcase to the class table)."""
    w, d, h = rng.uniform(1.4, 2.7), rng.uniform(0.45, 1.0), rng.uniform(1.8, 2.6)
    col = _pick(rng, STEEL_TONES)
    parts = [Part((sx * (w / 2 - 0.03), sy * (d / 2 - 0.03), h / 2), (0.06, 0.06, h), METAL, col)
             for sx in (-1, 1) for sy in (-1, 1)]  # fmt: skip
    n = int(rng.integers(3, 6))
    for i in range(n):
        z = 0.12 + i * (h - 0.2) / (n - 1)
        parts.append(Part((0, 0, z), (w, d, 0.03), METAL, (150, 150, 150)))
        if i < n - 1:
            x = -w / 2 + 0.1
            while x < w / 2 - 0.3 and rng.random() < 0.8:
                bw, bh = rng.uniform(0.25, 0.6), min(rng.uniform(0.2, 0.5), (h - 0.2) / (n - 1) - 0.08)
                parts.append(Part((x + bw / 2, 0, z + 0.015 + bh / 2), (bw, d * rng.uniform(0.6, 0.95), bh), WOOD,
                                  _pick(rng, THING_TONES)))  # fmt: skip
                x += bw + rng.uniform(0.02, 0.3)
    return Piece(C.BOOKCASE, tuple(parts), (w / 2, d / 2), h)


def cabinet(rng: np.random.Generator) -> Piece:
    """A closed filing cabinet or a locker bank: a box with drawer or door fronts standing a little proud."""
    tall = rng.random() < 0.5
    w, d = rng.uniform(0.4, 1.8) if tall else rng.uniform(0.45, 1.0), rng.uniform(0.4, 0.6)
    h = rng.uniform(1.7, 2.0) if tall else rng.uniform(0.7, 1.35)
    col = _pick(rng, STEEL_TONES + LAMINATE_TONES)
    parts = [Part((0, 0, h / 2), (w, d, h), METAL, col)]
    rows = 1 if tall else int(rng.integers(2, 5))
    cols = max(int(w / 0.4), 1) if tall else 1
    for i in range(rows):
        for j in range(cols):
            fw, fh = w / cols - 0.03, h / rows - 0.03
            parts.append(Part((-w / 2 + (j + 0.5) * w / cols, d / 2 + 0.008, (i + 0.5) * h / rows), (fw, 0.016, fh),
                              METAL, col))  # fmt: skip
    return Piece(C.BOOKCASE, tuple(parts), (w / 2, d / 2 + 0.02), h)


def workbench(rng: np.random.Generator) -> Piece:
    """A heavy bench on two trestle panels with a low shelf."""
    w, d, h = rng.uniform(1.5, 2.4), rng.uniform(0.7, 1.0), rng.uniform(0.85, 0.95)
    top = _pick(rng, LAMINATE_TONES)
    frame = _pick(rng, STEEL_TONES)
    parts = [Part((0, 0, h - 0.03), (w, d, 0.06), WOOD, top), Part((0, 0, 0.2), (w - 0.2, d - 0.1, 0.03), WOOD, top)]
    for sx in (-1, 1):
        parts.append(Part((sx * (w / 2 - 0.1), 0, (h - 0.06) / 2), (0.05, d - 0.1, h - 0.06), METAL, frame))
    return Piece(C.TABLE, tuple(parts), (w / 2, d / 2), h)


def round_table(rng: np.random.Generator) -> Piece:
    """A café or meeting table: a round-ish top on one pedestal and a cross foot."""
    dia, h = rng.uniform(0.7, 1.3), rng.uniform(0.72, 1.05)
    col = _pick(rng, LAMINATE_TONES)
    parts = _octagon((0, 0, h - 0.02), dia, 0.035, WOOD, col)
    parts.append(Part((0, 0, (h - 0.04) / 2), (0.08, 0.08, h - 0.04), METAL, (50, 50, 55)))
    parts += [Part((0, 0, 0.03), (dia * 0.7, 0.07, 0.05), METAL, (50, 50, 55)),
              Part((0, 0, 0.03), (0.07, dia * 0.7, 0.05), METAL, (50, 50, 55))]  # fmt: skip
    return Piece(C.TABLE, tuple(parts), (dia / 2, dia / 2), h)


def l_desk(rng: np.random.Generator) -> Piece:
    """A corner desk: two tops in an L on panel legs, a drawer pedestal under one end."""
    w, d2, d = rng.uniform(1.4, 1.9), rng.uniform(1.0, 1.5), rng.uniform(0.6, 0.8)
    h = 0.74
    col = _pick(rng, LAMINATE_TONES)
    parts = [
        Part((0, 0, h - 0.015), (w, d, 0.03), WOOD, col),
        Part((w / 2 - d / 2, d / 2 + (d2 - d) / 2, h - 0.015), (d, d2 - d, 0.03), WOOD, col),
        Part((-w / 2 + 0.02, 0, (h - 0.03) / 2), (0.03, d, h - 0.03), WOOD, col),
        Part((w / 2 - d / 2, d2 - d / 2 - 0.02, (h - 0.03) / 2), (d, 0.03, h - 0.03), WOOD, col),
        Part((w / 2 - 0.25, -d / 2 + 0.3, 0.3), (0.42, 0.55, 0.6), METAL, _pick(rng, STEEL_TONES)),
    ]
    return Piece(C.TABLE, tuple(parts), (w / 2, d2 - d / 2), h)


def stool(rng: np.random.Generator) -> Piece:
    """A bar or lab stool: a round seat on one post, a foot ring."""
    dia, h = rng.uniform(0.32, 0.42), rng.uniform(0.45, 0.78)
    col = _pick(rng, UPHOLSTERY_TONES)
    parts = _octagon((0, 0, h - 0.03), dia, 0.06, FABRIC, col)
    parts.append(Part((0, 0, (h - 0.06) / 2), (0.05, 0.05, h - 0.06), METAL, (160, 160, 165)))
    parts += [Part((0, 0, 0.02), (dia * 1.1, 0.04, 0.04), METAL, (160, 160, 165)),
              Part((0, 0, 0.02), (0.04, dia * 1.1, 0.04), METAL, (160, 160, 165))]  # fmt: skip
    return Piece(C.CHAIR, tuple(parts), (dia * 0.55, dia * 0.55), h)


def armchair(rng: np.random.Generator) -> Piece:
    """A bulky upholstered chair: seat block, a tall back, two arms, no visible legs."""
    w, d = rng.uniform(0.7, 0.9), rng.uniform(0.7, 0.85)
    seat, back = rng.uniform(0.38, 0.45), rng.uniform(0.75, 1.05)
    col = _pick(rng, UPHOLSTERY_TONES)
    parts = [
        Part((0, 0.05, seat / 2), (w - 0.2, d - 0.1, seat), FABRIC, col),
        Part((0, -d / 2 + 0.08, back / 2), (w, 0.16, back), FABRIC, col),
        Part((-w / 2 + 0.05, 0, 0.3), (0.1, d, 0.6), FABRIC, col),
        Part((w / 2 - 0.05, 0, 0.3), (0.1, d, 0.6), FABRIC, col),
    ]
    return Piece(C.CHAIR, tuple(parts), (w / 2, d / 2), back)


def bench(rng: np.random.Generator) -> Piece:
    """A waiting-room bench: a row of padded seats on a steel beam with two feet (a sofa to the class table)."""
    n = int(rng.integers(2, 5))
    w, d = n * rng.uniform(0.5, 0.6), rng.uniform(0.55, 0.7)
    col = _pick(rng, UPHOLSTERY_TONES)
    parts = [Part((0, 0.03, 0.44), (w, d - 0.1, 0.08), FABRIC, col),
             Part((0, -d / 2 + 0.05, 0.7), (w, 0.08, 0.45), FABRIC, col),
             Part((0, 0, 0.3), (w - 0.2, 0.08, 0.08), METAL, (90, 90, 95))]  # fmt: skip
    for sx in (-1, 1):
        parts.append(Part((sx * (w / 2 - 0.15), 0, 0.2), (0.06, d - 0.1, 0.4), METAL, (90, 90, 95)))
    return Piece(C.SOFA, tuple(parts), (w / 2, d / 2), 0.93)


def screen(rng: np.random.Generator) -> Piece:
    """A wall screen (dark panel) or a cork pinboard; origin on the wall, facing +y."""
    if rng.random() < 0.5:
        w = rng.uniform(1.0, 1.9)
        h, z0, mat, col = w * 0.56, rng.uniform(1.2, 1.6), METAL, (20, 22, 26)
    else:
        w, h, z0 = rng.uniform(0.8, 2.0), rng.uniform(0.6, 1.2), rng.uniform(0.9, 1.3)
        mat, col = WHITEBOARD, (180, 140, 90)
    return Piece(C.BOARD, (Part((0, 0.02, z0 + h / 2), (w, 0.04, h), mat, col),), (w / 2, 0.04), z0 + h)


def thing(rng: np.random.Generator) -> Piece:
    """Floor clutter: a crate, an oil drum, a pallet (perhaps stacked), a traffic cone or a bulging bag."""
    kind = int(rng.integers(5))
    col = _pick(rng, THING_TONES)
    if kind == 0:
        s = rng.uniform(0.3, 0.8, 3)
        parts = [Part((0, 0, s[2] / 2), tuple(s), WOOD, (180, 150, 100))]
    elif kind == 1:
        r, h = rng.uniform(0.55, 0.6), rng.uniform(0.85, 0.9)
        parts = _octagon((0, 0, h / 2), r, h, METAL, col)
    elif kind == 2:
        n = int(rng.integers(1, 5))
        parts = [Part((0, 0, 0.075 + 0.15 * i), (1.2, 0.8, 0.14), WOOD, (190, 160, 110)) for i in range(n)]
    elif kind == 3:
        h = rng.uniform(0.45, 0.75)
        parts = [Part((0, 0, 0.02), (0.38, 0.38, 0.04), FABRIC, (30, 30, 30))]
        parts += [Part((0, 0, 0.04 + h * (i + 0.5) / 3), (0.25 * (1 - i / 3.5),) * 2 + (h / 3,), FABRIC, (240, 100, 20))
                  for i in range(3)]  # fmt: skip
    else:
        s = (rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.5), rng.uniform(0.25, 0.5))
        parts = [Part((0, 0, s[2] / 2), s, FABRIC, col), Part((0, 0, s[2] * 0.9), (s[0] * 0.8, s[1] * 1.05, s[2] * 0.3),
                                                              FABRIC, col)]  # fmt: skip
    xs = [abs(p.center[0]) + p.size[0] / 2 for p in parts]
    ys = [abs(p.center[1]) + p.size[1] / 2 for p in parts]
    zs = [p.center[2] + p.size[2] / 2 for p in parts]
    return Piece(C.CLUTTER, tuple(parts), (max(xs), max(ys)), max(zs))
