"""Dense scans (millimetre spacing) of cracked concrete elements with a per-point crack mask and crack truth.

An element is scanned as a terrestrial scanner sees it from one side: two faces of a column, one face
of a wall panel, the top of a slab. The surface is a jittered grid with scanner noise, gentle unevenness,
shallow pits and dark stains that are *not* cracks (so colour alone cannot find them). Cracks wander
across a face; a point is a crack point when it lies inside the crack's visible opening; inside, the
surface drops into the crack (a V of the crack's depth), is darker and returns less intensity.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import LabelledCloud
from aftershock.sources.simulator.damage import CrackTruth, crack_polyline, crack_widths, distance_to_polylines

SCANNER_NOISE_M: Final = 0.0005
ELEMENT_INSTANCE: Final = 1
MAX_CRACKS: Final = 16


@dataclass(frozen=True, slots=True)
class _Face:
    origin: np.ndarray  # a corner
    u: np.ndarray  # unit axis along the face
    v: np.ndarray
    normal: np.ndarray  # outward
    size_u: float
    size_v: float


@dataclass(frozen=True, slots=True)
class ElementKind:
    name: str
    cls: SemanticClass
    size_m: tuple[float, float, float]
    width_median_m: float  # median visible crack opening
    horizontal: bool  # scanned from above (slab) rather than from the side


ELEMENTS: Final[dict[str, ElementKind]] = {
    # the damaged zone of a 0.4 x 0.4 m column, two faces seen
    "column": ElementKind("column", SemanticClass.COLUMN, (0.4, 0.4, 1.2), 0.006, False),
    "wall": ElementKind("wall", SemanticClass.WALL, (1.2, 0.2, 1.0), 0.006, False),
    "slab": ElementKind("slab", SemanticClass.FLOOR, (3.0, 2.0, 0.3), 0.012, True),
}

_CONCRETE_TONES: Final = ((236, 214, 176), (200, 196, 188), (182, 176, 166), (222, 206, 180), (170, 162, 150))


def _faces(kind: ElementKind) -> list[_Face]:
    sx, sy, sz = kind.size_m
    ex, ey, ez = np.eye(3)
    if kind.name == "column":
        return [
            _Face(np.array([sx / 2, -sy / 2, 0.0]), ey, ez, ex, sy, sz),
            _Face(np.array([sx / 2, sy / 2, 0.0]), -ex, ez, ey, sx, sz),
        ]
    if kind.name == "wall":
        return [_Face(np.array([-sx / 2, sy / 2, 0.0]), ex, ez, ey, sx, sz)]
    return [_Face(np.array([-sx / 2, -sy / 2, sz]), ex, ey, ez, sx, sy)]


def cracked_element(
    kind: str, seed: int, spacing_m: float = 0.004
) -> tuple[LabelledCloud, np.ndarray, list[CrackTruth]]:
    """A dense labelled cloud of a cracked `column`, `wall` or `slab`, its boolean crack mask, and its cracks.

    Coordinates are metres in the element's frame (base centre at the origin, z up). The cloud's class is
    the element's (column, wall, floor) and its instance id 1. Each crack's `width_m` is the mean width of
    the marked opening, `length_m` its length along the centre line.
    """
    if kind not in ELEMENTS:
        raise InputError(f"unknown element {kind!r} (known: {', '.join(ELEMENTS)})")
    if not 0.0005 <= spacing_m <= 0.05:
        raise InputError(f"spacing {spacing_m} m is outside 0.5 mm .. 5 cm")
    el = ELEMENTS[kind]
    # separate streams: the same seed gives the same cracks at every spacing
    rng_crack, rng = (np.random.default_rng([int(seed), sum(map(ord, kind)), 17, s]) for s in (0, 1))
    faces = _faces(el)
    pts_l, nrm_l, face_l = [], [], []
    for fi, f in enumerate(faces):
        nu, nv = max(int(f.size_u / spacing_m), 2), max(int(f.size_v / spacing_m), 2)
        uu, vv = np.meshgrid((np.arange(nu) + 0.5) * f.size_u / nu, (np.arange(nv) + 0.5) * f.size_v / nv)
        uv = np.c_[uu.ravel(), vv.ravel()] + rng.uniform(-0.2, 0.2, (uu.size, 2)) * spacing_m
        pts_l.append(f.origin + uv[:, :1] * f.u + uv[:, 1:] * f.v)
        nrm_l.append(np.broadcast_to(f.normal, (len(uv), 3)))
        face_l.append(np.full(len(uv), fi))
    pts = np.concatenate(pts_l)
    normals = np.concatenate(nrm_l)
    face_of = np.concatenate(face_l)
    n = len(pts)
    area = sum(f.size_u * f.size_v for f in faces)

    # Cracks until their marked area reaches a share of the surface like the field data's 4-15 %.
    target = rng_crack.uniform(0.04, 0.15) * area
    cracks: list[CrackTruth] = []
    covered = 0.0
    while covered < target and len(cracks) < MAX_CRACKS:
        f = faces[int(rng_crack.integers(len(faces)))]
        crack = _crack_on_face(rng_crack, f, el)
        cracks.append(crack)
        covered += crack.length_m * crack.width_m

    # Surface: unevenness, shallow pits, scanner noise.
    offset = 0.0008 * np.sin(pts @ rng.normal(0, 25, 3)) + 0.0006 * np.sin(pts @ rng.normal(0, 60, 3))
    for _ in range(int(rng.integers(3, 10))):
        c = pts[int(rng.integers(n))]
        r = rng.uniform(0.005, 0.03)
        d2 = ((pts - c) ** 2).sum(1)
        offset -= rng.uniform(0.001, 0.004) * np.exp(-d2 / (r * r))
    base = np.asarray(_CONCRETE_TONES[int(rng.integers(len(_CONCRETE_TONES)))], np.float32)
    tone = 1.0 + 0.05 * np.sin(pts @ rng.normal(0, 8, 3)).astype(np.float32)[:, None]
    colors = base[None, :] * tone + rng.normal(0, 6, (n, 3)).astype(np.float32)
    intensity = (0.55 + 0.05 * rng.standard_normal(n)).astype(np.float32)
    for _ in range(int(rng.integers(2, 7))):  # stains: dark but flat, not cracks
        c = pts[int(rng.integers(n))]
        r = rng.uniform(0.01, 0.08)
        w = np.exp(-((pts - c) ** 2).sum(1) / (r * r)).astype(np.float32)[:, None]
        colors = colors * (1 - w * rng.uniform(0.15, 0.35))

    mask = np.zeros(n, bool)
    for k, crack in enumerate(cracks):
        fi = next(i for i, f in enumerate(faces) if np.allclose(f.normal, crack.normal))
        reach = float(crack.widths.max())
        lo, hi = crack.polyline.min(0) - reach, crack.polyline.max(0) + reach
        cand = np.flatnonzero((face_of == fi) & ((pts >= lo) & (pts <= hi)).all(1))
        if len(cand) == 0:
            continue
        a, b = crack.polyline[:-1], crack.polyline[1:]
        w = np.c_[crack.widths[:-1], crack.widths[1:]]
        d, seg = distance_to_polylines(pts[cand], a, b, w)
        inside = d <= 0
        idx = cand[inside]
        half = 0.5 * 0.5 * (w[seg[inside], 0] + w[seg[inside], 1])
        frac = np.clip(1 - (d[inside] + half) / np.maximum(half, 1e-6), 0, 1)  # 1 on the centre line
        offset[idx] -= crack.depth_m * frac
        # field data: crack points only ~10-20 % darker and a little browner than the concrete around
        dark = rng.uniform(0.72, 0.9)
        colors[idx] = colors[idx] * (dark - 0.12 * frac[:, None]) * np.array([1.0, 0.95, 0.85], np.float32)
        intensity[idx] *= 0.75 - 0.25 * frac
        mask[idx] = True
        rgb = np.clip(colors[idx].mean(0), 0, 255).round().astype(int)
        cracks[k] = replace(crack, color=(int(rgb[0]), int(rgb[1]), int(rgb[2])))

    pts = pts + normals * (offset + rng.normal(0, SCANNER_NOISE_M, n))[:, None]
    cloud = LabelledCloud(
        points=pts,
        colors=np.clip(np.round(colors), 0, 255).astype(np.uint8),
        intensity=np.clip(intensity * 4096, 0, 65535).astype(np.float32),  # raw scanner units, like the field data
        class_ids=np.full(n, int(el.cls), np.uint16),
        instance_ids=np.full(n, ELEMENT_INSTANCE, np.uint32),
    )
    return cloud, mask, cracks


def _crack_on_face(rng: np.random.Generator, f: _Face, el: ElementKind) -> CrackTruth:
    """One crack on a face: shear (diagonal), flexural (across) or splitting (along), kept on the face."""
    width = float(np.clip(rng.lognormal(np.log(el.width_median_m), 0.6), 0.0008, 0.03))
    kind = rng.random()
    if el.horizontal:
        angle = rng.uniform(0, np.pi)
    elif kind < 0.5:
        angle = rng.uniform(0.5, 1.1) * rng.choice([-1, 1])
    elif kind < 0.8:
        angle = rng.normal(0, 0.12)
    else:
        angle = np.pi / 2 + rng.normal(0, 0.1)
    du, dv = abs(np.cos(angle)), abs(np.sin(angle))
    max_len = 0.9 * min(f.size_u / max(du, 1e-3), f.size_v / max(dv, 1e-3))
    length = float(min(rng.uniform(0.25, 1.0) * max(f.size_u, f.size_v), max_len))
    cu = rng.uniform(du * length / 2 + 0.02, max(f.size_u - du * length / 2 - 0.02, du * length / 2 + 0.021))
    cv = rng.uniform(dv * length / 2 + 0.02, max(f.size_v - dv * length / 2 - 0.02, dv * length / 2 + 0.021))
    center = f.origin + cu * f.u + cv * f.v
    poly = crack_polyline(rng, center, f.u, f.v, length, angle, points=16, wander=0.04)
    widths = crack_widths(rng, len(poly), width)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    direction = poly[-1] - poly[0]
    return CrackTruth(
        element_instance_id=ELEMENT_INSTANCE,
        element_class=int(el.cls),
        center=poly.mean(0),
        direction=direction / np.linalg.norm(direction),
        normal=f.normal.astype(np.float64),
        length_m=float(seg.sum()),
        width_m=float(widths.mean()),
        max_width_m=float(widths.max()),
        depth_m=float(np.clip(width * rng.uniform(2, 6), 0.002, 0.05)),
        color=(0, 0, 0),
        polyline=poly,
        widths=widths,
    )
