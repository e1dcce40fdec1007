"""Damage of the independent generators, unlike the families' mounds and collapsed bays: ceiling or roof panels
fallen flat or hanging from one edge, a beam come down across the floor, a strip of scattered rubble, furniture
toppled onto its side."""

from __future__ import annotations

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.furniture import Piece
from aftershock.sources.simulator.generators.parts import Footprints, Rect, put
from aftershock.sources.simulator.meshes import CONCRETE, METAL, PLASTER, RUBBLE, MeshBuilder, rotation_xyz, rotation_z

Color = tuple[int, int, int]


def fallen_panels(b: MeshBuilder, rng: np.random.Generator, room: Rect, n: int, color: Color) -> None:
    """Ceiling tiles or roof sheets lying on the floor, a little tilted where they rest on each other (debris)."""
    x0, y0, x1, y1 = room
    for _ in range(n):
        inst = b.new_instance(C.DEBRIS)
        cx, cy = rng.uniform(x0 + 0.6, x1 - 0.6), rng.uniform(y0 + 0.6, y1 - 0.6)
        for _k in range(int(rng.integers(1, 4))):
            w, d = rng.uniform(0.5, 1.3), rng.uniform(0.5, 1.3)
            rot = rotation_xyz(rng.uniform(-0.12, 0.12), rng.uniform(-0.12, 0.12), rng.uniform(-np.pi, np.pi))
            b.add_box((cx + rng.uniform(-0.4, 0.4), cy + rng.uniform(-0.4, 0.4), rng.uniform(0.02, 0.08)),
                      (w, d, rng.uniform(0.015, 0.04)), cls=C.DEBRIS, instance=inst, material=PLASTER, color=color,
                      rotation=rot, jitter_color=0.1)  # fmt: skip


def hanging_panel(
    b: MeshBuilder, rng: np.random.Generator, room: Rect, ceiling_z: float, color: Color, ceiling_instance: int
) -> None:
    """A ceiling panel torn down on one side, hanging from the other: still ceiling, steeply tilted."""
    x0, y0, x1, y1 = room
    w, d = min(rng.uniform(1.0, 2.0), x1 - x0 - 0.4), min(rng.uniform(0.8, 1.4), y1 - y0 - 0.4)
    hx, hy = rng.uniform(x0 + w / 2 + 0.2, x1 - w / 2 - 0.2), rng.uniform(y0 + 0.2, y1 - d - 0.2)
    ang = rng.uniform(0.4, 0.9)  # radians about x, hinged on the panel's y0 edge
    rot = rotation_xyz(-ang, 0.0, 0.0)
    center = np.array([hx, hy, ceiling_z - 0.02]) + rot @ np.array([0.0, d / 2, 0.0])
    b.add_box(center, (w, d, 0.03), cls=C.CEILING, instance=ceiling_instance, material=PLASTER, color=color,
              rotation=rot)  # fmt: skip


def fallen_beam(b: MeshBuilder, rng: np.random.Generator, room: Rect, height: float, color: Color) -> None:
    """A beam come down: one end on the floor, the other still up on a column or a pile (a beam)."""
    x0, y0, x1, y1 = room
    length = rng.uniform(3.0, 6.0)
    yaw = rng.uniform(-np.pi, np.pi)
    lift = rng.uniform(0.6, min(height * 0.6, 2.5))
    pitch = np.arcsin(min(lift / length, 0.9))
    cx = np.clip(rng.uniform(x0, x1), x0 + length / 2, max(x0 + length / 2, x1 - length / 2))
    cy = np.clip(rng.uniform(y0, y1), y0 + length / 2, max(y0 + length / 2, y1 - length / 2))
    steel = rng.random() < 0.5
    rot = rotation_z(yaw) @ rotation_xyz(0.0, -pitch, 0.0)
    inst = b.new_instance(C.BEAM)
    b.add_box((cx, cy, lift / 2 + 0.15), (length, 0.3, 0.4), cls=C.BEAM, instance=inst,
              material=METAL if steel else CONCRETE, color=color, rotation=rot)  # fmt: skip


def rubble_strip(b: MeshBuilder, rng: np.random.Generator, room: Rect, color: Color) -> None:
    """Broken pieces strewn along a line (from a wall that shed its face), thin rather than heaped."""
    x0, y0, x1, y1 = room
    inst = b.new_instance(C.DEBRIS)
    a = np.array([rng.uniform(x0 + 0.3, x1 - 0.3), rng.uniform(y0 + 0.3, y1 - 0.3)])
    direction = rng.normal(size=2)
    direction /= np.linalg.norm(direction)
    n = int(rng.integers(25, 80))
    length = rng.uniform(1.5, 4.0)
    f = rng.uniform(0, 1, n)
    pts = a + np.outer(f * length, direction) + rng.normal(0, 0.25, (n, 2))
    pts = np.clip(pts, [x0 + 0.1, y0 + 0.1], [x1 - 0.1, y1 - 0.1])
    for (px, py), s in zip(pts, rng.uniform(0.04, 0.22, n), strict=True):
        b.add_box((px, py, s * 0.35), (s, s * rng.uniform(0.5, 1.0), s * rng.uniform(0.3, 0.7)), cls=C.DEBRIS,
                  instance=inst, material=RUBBLE, color=color,
                  rotation=rotation_xyz(*rng.uniform(-0.6, 0.6, 2), rng.uniform(-np.pi, np.pi)),
                  jitter_color=0.2)  # fmt: skip


def toppled(
    b: MeshBuilder, taken: Footprints, room: Rect, piece: Piece, rng: np.random.Generator, tries: int = 10
) -> bool:
    """A piece lying on its back or side somewhere in the room."""
    # lying down, the piece spans 0..height along its local y: a footprint of twice that keeps it clear
    lying = Piece(piece.cls, piece.parts, (piece.half_extent[0], piece.height + 0.05), piece.half_extent[1] * 2)
    for _ in range(tries):
        yaw = float(rng.uniform(-np.pi, np.pi))
        x = float(rng.uniform(room[0] + 0.5, room[2] - 0.5))
        y = float(rng.uniform(room[1] + 0.5, room[3] - 0.5))
        rot = rotation_z(yaw) @ rotation_xyz(-np.pi / 2, 0.0, 0.0)  # onto its front: its top points along +y
        if put(b, taken, room, lying, x, y, yaw, rotation=rot, lift=piece.half_extent[1]):
            return True
    return False
