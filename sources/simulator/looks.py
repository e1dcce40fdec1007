"""Repainting a scene: other colour palettes and materials than its generator chose, so that a network cannot
lean on the simulator's colours.

- `natural`: as built.
- `random`: every object its own colour, drawn uniformly over hue with random saturation and brightness.
- `grey`: every object a grey level (a desaturated or monochrome camera).
- `swap`: the scene's own colours, shuffled between objects (walls may take a sofa's colour).

Every non-natural palette also draws each object's reflectivity (0.5-1.6x) and texture (0-2.5x) anew,
which changes LiDAR intensity the way other materials would. Deterministic in (scene, seed).
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.errors import InputError
from aftershock.sources.simulator.scene import Scene

PALETTES: Final[tuple[str, ...]] = ("natural", "random", "grey", "swap")


def check_palette(name: str) -> None:
    if name not in PALETTES:
        raise InputError(f"unknown palette {name!r} (known: {', '.join(PALETTES)})")


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    i = np.floor(h * 6).astype(np.int64) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack([np.stack(c, -1) for c in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))])
    return table[i, np.arange(len(h))]


def repaint(scene: Scene, palette: str, seed: int) -> None:
    """Recolour the scene's mesh in place, one colour per object (instance)."""
    check_palette(palette)
    if palette == "natural":
        return
    m = scene.mesh
    rng = np.random.default_rng([scene.seed, seed, 17, PALETTES.index(palette)])
    n = int(m.instance_ids.max()) + 1
    inst = m.instance_ids.astype(np.int64)
    if palette == "random":
        rgb = _hsv_to_rgb(rng.uniform(0, 1, n), rng.uniform(0, 0.9, n), rng.uniform(0.15, 1.0, n)) * 255
    elif palette == "grey":
        rgb = np.repeat(rng.uniform(25, 245, n)[:, None], 3, axis=1)
    else:  # swap: the colour of each object's first triangle, handed to a random other object
        first = np.zeros(n, np.int64)
        first[inst[::-1]] = np.arange(len(inst))[::-1]
        rgb = m.colors[first].astype(np.float64)[rng.permutation(n)]
    m.colors = np.clip(np.round(rgb[inst]), 0, 255).astype(np.uint8)
    m.reflectivity = np.clip(m.reflectivity * rng.uniform(0.5, 1.6, n)[inst], 0.02, 1.0).astype(np.float32)
    m.texture = (m.texture * rng.uniform(0.0, 2.5, n)[inst]).astype(np.float32)
