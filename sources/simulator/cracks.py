"""Dense scans (millimetre spacing) of cracked concrete elements with a per-point crack mask and crack truth.

An element is scanned as a terrestrial scanner sees it from one side: two faces of a column, one face
of a wall panel, the top of a slab, the side and soffit of a beam. The surface is a jittered grid with
scanner noise (0.2-1.5 mm), gentle unevenness, shallow pits, and what is dark but *not* a crack (so colour
alone cannot find cracks): stains, run-off dirt streaks (long and thin, like a crack, but flat), shade that
varies across the element and from face to face. Concrete is bare (grey or buff, speckled with aggregate) or
painted (a smooth, even coat). Parts of the surface can be hidden (occlusion: no points there).

With `marks`, what a site adds on top, each long, thin or straight-edged but no crack: formwork board marks
(straight lips across a face), a construction joint (a straight recessed groove across a face), a pour step (one
side proud of the other: an edge in depth), a cast shadow (a straight-edged darker part of a face), and paint in
hue (a painted stripe, a scribbled line and a patch, each of a colour the concrete does not have).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import LabelledCloud
from aftershock.sources.simulator.damage import CrackTruth, crack_polyline, distance_to_polylines

SCANNER_NOISE_M: Final = (0.0002, 0.0015)  # range of the per-element scanner noise (standard deviation)
ELEMENT_INSTANCE: Final = 1
MAX_CRACKS: Final = 16
BRANCH_CHANCE: Final = 0.4  # share of cracks with one or two branches
SPALL_CHANCE: Final = 0.3  # share of cracks with a spalled stretch
PAINT_CHANCE: Final = 0.35  # share of painted elements


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
    # a 0.3 m wide, 0.5 m deep beam, 1.6 m of it: one side and the soffit seen from below
    "beam": ElementKind("beam", SemanticClass.BEAM, (1.6, 0.3, 0.5), 0.005, False),
}

_CONCRETE_TONES: Final = ((236, 214, 176), (200, 196, 188), (182, 176, 166), (222, 206, 180), (170, 162, 150))
_PAINT_TONES: Final = ((238, 236, 228), (214, 214, 210), (232, 222, 196), (196, 208, 214), (206, 214, 196))


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
    if kind.name == "beam":
        return [
            _Face(np.array([-sx / 2, -sy / 2, 0.0]), ex, ez, -ey, sx, sz),
            _Face(np.array([-sx / 2, sy / 2, 0.0]), ex, -ey, -ez, sx, sy),
        ]
    return [_Face(np.array([-sx / 2, -sy / 2, sz]), ex, ey, ez, sx, sy)]


def _blobs(pts: np.ndarray, rng: np.random.Generator, count: int, radius: tuple[float, float]) -> np.ndarray:
    """Sum of `count` Gaussian bumps (peak 1, random radius) at random points: (N,)."""
    out = np.zeros(len(pts), np.float32)
    for _ in range(count):  # a handful of bumps per element
        c = pts[int(rng.integers(len(pts)))]
        r = rng.uniform(*radius)
        out += np.exp(-((pts - c) ** 2).sum(1) / (r * r)).astype(np.float32)
    return out


def _streaks(pts: np.ndarray, faces: list[_Face], face_of: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Run-off dirt: a few long, thin, flat dark streaks down the faces (0..1 strength per point)."""
    out = np.zeros(len(pts), np.float32)
    for _ in range(int(rng.integers(0, 4))):
        fi = int(rng.integers(len(faces)))
        f = faces[fi]
        on = face_of == fi
        uv = np.c_[(pts[on] - f.origin) @ f.u, (pts[on] - f.origin) @ f.v]
        cu, top = rng.uniform(0, f.size_u), rng.uniform(0.3, 1.0) * f.size_v
        half, length = rng.uniform(0.004, 0.02), rng.uniform(0.1, 0.5)
        wobble = 0.01 * np.sin(uv[:, 1] * rng.uniform(5, 20))
        across = np.exp(-(((uv[:, 0] - cu - wobble) / half) ** 2))
        along = np.clip(1 - (top - uv[:, 1]) / length, 0, 1) * (uv[:, 1] <= top)
        out[on] += (across * along).astype(np.float32)
    return np.clip(out, 0, 1)


_MARK_HUES: Final = ((178, 52, 44), (40, 84, 170), (214, 180, 30), (60, 140, 70), (120, 60, 140))


def _site_marks(
    pts: np.ndarray, faces: list[_Face], face_of: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Per point: offset along the normal (m), brightness factor, and paint (colour (N, 3), weight (N,)) of the
    site's marks (module docstring). Each face gets its own draw; one joint and one step per element at most."""
    n = len(pts)
    offset = np.zeros(n)
    bright = np.ones(n, np.float32)
    paint = np.zeros((n, 3), np.float32)
    weight = np.zeros(n, np.float32)
    joint_face, step_face = int(rng.integers(len(faces))), int(rng.integers(len(faces)))
    for fi, f in enumerate(faces):  # a handful of faces per element
        on = np.flatnonzero(face_of == fi)
        u = (pts[on] - f.origin) @ f.u
        v = (pts[on] - f.origin) @ f.v
        # formwork board marks: straight lips every board width, across the face's long side
        across = v if f.size_v >= f.size_u else u
        board = rng.uniform(0.1, 0.3)
        d = np.abs(((across + rng.uniform(0, board)) % board) - board / 2) - board / 2  # 0 on a board joint
        lip = np.exp(-((d / rng.uniform(0.001, 0.003)) ** 2))
        offset[on] += rng.uniform(0.0003, 0.0015) * lip
        bright[on] *= 1 - rng.uniform(0.0, 0.08) * lip
        if fi == joint_face:  # a construction joint: a straight recessed groove right across the face
            at = rng.uniform(0.2, 0.8) * across.max()
            half = rng.uniform(0.003, 0.008)
            g = np.clip(1 - np.abs(across - at) / half, 0, 1)
            offset[on] -= rng.uniform(0.002, 0.006) * g
            bright[on] *= 1 - rng.uniform(0.05, 0.25) * g
        if fi == step_face and rng.random() < 0.6:  # a pour step: one side proud of the other
            at = rng.uniform(0.2, 0.8) * across.max()
            offset[on] += rng.uniform(0.002, 0.008) * (across > at)
        if rng.random() < 0.5:  # a cast shadow: a straight-edged darker part of the face
            t = rng.uniform(0, np.pi)
            s = np.cos(t) * (u - u.mean()) + np.sin(t) * (v - v.mean())
            bright[on] *= np.where(s > rng.uniform(-0.1, 0.1), 1 - rng.uniform(0.15, 0.4), 1.0).astype(np.float32)
        hue = np.asarray(_MARK_HUES[int(rng.integers(len(_MARK_HUES)))], np.float32)
        if rng.random() < 0.5:  # a painted stripe, straight, 1-4 cm wide
            t = rng.uniform(0, np.pi)
            s = np.cos(t) * (u - u.mean()) + np.sin(t) * (v - v.mean())
            on_paint = np.abs(s - rng.uniform(-0.1, 0.1)) < rng.uniform(0.005, 0.02)
            paint[on[on_paint]], weight[on[on_paint]] = hue, rng.uniform(0.5, 0.9)
        if rng.random() < 0.5:  # a scribbled line in paint or marker, wandering, 3-8 mm wide
            c0 = np.array([rng.uniform(0.2, 0.8) * u.max(), rng.uniform(0.2, 0.8) * v.max()])
            along = np.linspace(0, 1, 40)[:, None]
            a = rng.uniform(0, np.pi)
            line = c0 + (along - 0.5) * rng.uniform(0.1, 0.4) * np.array([np.cos(a), np.sin(a)])
            line += 0.02 * np.sin(along * rng.uniform(5, 15)) * np.array([-np.sin(a), np.cos(a)])
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(line).query(np.c_[u, v], k=1)
            on_line = dist < rng.uniform(0.0015, 0.004)
            hue2 = np.asarray(_MARK_HUES[int(rng.integers(len(_MARK_HUES)))], np.float32)
            paint[on[on_line]], weight[on[on_line]] = hue2, rng.uniform(0.6, 0.95)
        if rng.random() < 0.5:  # a painted patch (a repair, a sign)
            c0 = np.array([rng.uniform(0, u.max()), rng.uniform(0, v.max())])
            r = rng.uniform(0.03, 0.12)
            patch = (np.abs(u - c0[0]) < r) & (np.abs(v - c0[1]) < r * rng.uniform(0.5, 2))
            paint[on[patch]], weight[on[patch]] = hue, rng.uniform(0.5, 0.9)
    return offset, bright, (paint, weight)


def cracked_element(
    kind: str, seed: int, spacing_m: float = 0.004, intact: bool = False, marks: bool = False
) -> tuple[LabelledCloud, np.ndarray, list[CrackTruth]]:
    """A dense labelled cloud of a cracked `column`, `wall`, `slab` or `beam`, its boolean crack mask, and its
    cracks (`intact`: the same element without any crack, for calibrating what a crack-free element scores;
    `marks`: with the site's marks of the module docstring, drawn from a stream of their own).

    Coordinates are metres in the element's frame (base centre at the origin, z up). The cloud's class is
    the element's (column, wall, floor, beam) and its instance id 1. Each crack's `width_m` is the mean width
    of the marked opening, `length_m` its length along the centre line (a branch is a crack of its own).
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
    while not intact and covered < target and len(cracks) < MAX_CRACKS:
        f = faces[int(rng_crack.integers(len(faces)))]
        family = _crack_family(rng_crack, f, el)
        cracks += family
        covered += sum(c.length_m * c.width_m for c in family)

    # Surface: unevenness, shallow pits, scanner noise.
    offset = 0.0008 * np.sin(pts @ rng.normal(0, 25, 3)) + 0.0006 * np.sin(pts @ rng.normal(0, 60, 3))
    for _ in range(int(rng.integers(3, 10))):
        c = pts[int(rng.integers(n))]
        r = rng.uniform(0.005, 0.03)
        d2 = ((pts - c) ** 2).sum(1)
        offset -= rng.uniform(0.001, 0.004) * np.exp(-d2 / (r * r))
    painted = rng.random() < PAINT_CHANCE
    tones = _PAINT_TONES if painted else _CONCRETE_TONES
    base = np.asarray(tones[int(rng.integers(len(tones)))], np.float32)
    tone = 1.0 + 0.05 * np.sin(pts @ rng.normal(0, 8, 3)).astype(np.float32)[:, None]
    speckle = rng.uniform(2, 4) if painted else rng.uniform(5, 12)  # aggregate shows through bare concrete
    colors = base[None, :] * tone + rng.normal(0, speckle, (n, 3)).astype(np.float32)
    if not painted:  # exposed aggregate: scattered small dark and light grains
        grain = rng.random(n) < rng.uniform(0.0, 0.04)
        colors[grain] *= rng.uniform(0.7, 1.15, (int(grain.sum()), 1)).astype(np.float32)
    # shade: each face lit differently, and a gradient across the element (light from one side)
    light = rng.normal(0, 1, 3)
    light /= np.linalg.norm(light)
    shade = rng.uniform(0.75, 1.1, len(faces)).astype(np.float32)[face_of]
    extent = float(np.ptp(pts, axis=0).max())
    shade *= (1 + rng.uniform(0, 0.25) * ((pts - pts.mean(0)) @ light) / extent).astype(np.float32)
    colors *= shade[:, None]
    intensity = (0.55 + 0.05 * rng.standard_normal(n)).astype(np.float32)
    stains = _blobs(pts, rng, int(rng.integers(2, 7)), (0.01, 0.08))  # stains: dark but flat, not cracks
    colors *= (1 - np.clip(stains, 0, 1) * rng.uniform(0.15, 0.35))[:, None]
    colors *= (1 - _streaks(pts, faces, face_of, rng) * rng.uniform(0.1, 0.3))[:, None]

    if marks:
        rng_marks = np.random.default_rng([int(seed), sum(map(ord, kind)), 17, 2])
        mark_offset, bright, (paint, weight) = _site_marks(pts, faces, face_of, rng_marks)
        offset += mark_offset
        colors *= bright[:, None]
        colors = colors * (1 - weight[:, None]) + paint * shade[:, None] * weight[:, None]

    mask = np.zeros(n, bool)
    concrete = np.asarray(_CONCRETE_TONES[int(rng.integers(len(_CONCRETE_TONES)))], np.float32)
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
        # a spalled stretch (much wider than the crack's typical opening) is shallow and rough
        spall = (2 * half > 2.2 * crack.width_m).astype(np.float64)
        depth = crack.depth_m * (1 - 0.7 * spall) * frac + spall * rng.uniform(0, 0.004, len(idx))
        offset[idx] -= depth
        if painted:  # the crack shows the bare concrete under the paint
            colors[idx] = 0.4 * colors[idx] + 0.6 * concrete * shade[idx, None]
        # field data: crack points only ~10-20 % darker and a little browner than the concrete around
        dark = rng.uniform(0.72, 0.9)
        colors[idx] = colors[idx] * (dark - 0.12 * frac[:, None]) * np.array([1.0, 0.95, 0.85], np.float32)
        intensity[idx] *= 0.75 - 0.25 * frac
        mask[idx] = True
        rgb = np.clip(colors[idx].mean(0), 0, 255).round().astype(int)
        cracks[k] = replace(crack, color=(int(rgb[0]), int(rgb[1]), int(rgb[2])))

    noise = rng.uniform(*SCANNER_NOISE_M)
    pts = pts + normals * (offset + rng.normal(0, noise, n))[:, None]
    # occlusion: a few patches the scanner could not see (something stood in front)
    seen = _blobs(pts, rng, int(rng.integers(0, 3)), (0.03, 0.12)) < 0.5
    cloud = LabelledCloud(
        points=pts,
        colors=np.clip(np.round(colors), 0, 255).astype(np.uint8),
        intensity=np.clip(intensity * 4096, 0, 65535).astype(np.float32),  # raw scanner units, like the field data
        class_ids=np.full(n, int(el.cls), np.uint16),
        instance_ids=np.full(n, ELEMENT_INSTANCE, np.uint32),
    )
    return cloud.select(np.flatnonzero(seen)), mask[seen], cracks


def _opening(rng: np.random.Generator, points: int, width: float, spall: bool) -> np.ndarray:
    """Opening along a crack: tapering to a hairline at both ends, varying along it (a smoothed random walk),
    and with `spall` one short stretch two to five times wider (a spalled edge)."""
    t = np.linspace(-1, 1, points)
    taper = np.clip(1.15 - 0.85 * t**2, 0.12, None)
    walk = np.convolve(rng.normal(0, 0.35, points + 4), np.ones(5) / 5, mode="valid")[:points]
    profile = taper * np.exp(walk)
    profile = width * profile / profile.mean()
    if spall:
        i = int(rng.integers(2, points - 2))
        profile[i - 1 : i + 2] *= rng.uniform(2.5, 5.0) * np.array([0.6, 1.0, 0.6])
    return profile


def _truth(el: ElementKind, f: _Face, poly: np.ndarray, widths: np.ndarray, depth: float) -> CrackTruth:
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
        depth_m=depth,
        color=(0, 0, 0),
        polyline=poly,
        widths=widths,
    )


def _crack_family(rng: np.random.Generator, f: _Face, el: ElementKind) -> list[CrackTruth]:
    """One crack on a face (shear: diagonal, flexural: across, splitting: along), kept on the face, and its
    branches: narrower cracks leaving it from an inner point at 20-50° and tapering away."""
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
    widths = _opening(rng, len(poly), width, rng.random() < SPALL_CHANCE)
    depth = float(np.clip(width * rng.uniform(2, 6), 0.002, 0.05))
    family = [_truth(el, f, poly, widths, depth)]
    if rng.random() < BRANCH_CHANCE:
        for _ in range(int(rng.integers(1, 3))):
            i = int(rng.integers(3, len(poly) - 3))
            b_len = length * rng.uniform(0.2, 0.5)
            b_angle = angle + rng.uniform(0.35, 0.9) * rng.choice([-1, 1])
            start = poly[i]
            b_dir = np.cos(b_angle) * f.u + np.sin(b_angle) * f.v
            b_poly = crack_polyline(rng, start + b_dir * b_len / 2, f.u, f.v, b_len, b_angle, points=8, wander=0.04)
            b_poly += start - b_poly[0]  # starts on its parent
            uv = np.c_[(b_poly - f.origin) @ f.u, (b_poly - f.origin) @ f.v]
            inside = (uv >= 0.01).all(1) & (uv[:, 0] <= f.size_u - 0.01) & (uv[:, 1] <= f.size_v - 0.01)
            stop = int(np.argmin(inside)) if not inside.all() else len(b_poly)
            if stop < 3:
                continue
            b_poly = b_poly[:stop]
            taper = np.linspace(1.0, 0.2, len(b_poly)) * widths[i] * rng.uniform(0.4, 0.7)
            family.append(_truth(el, f, b_poly, np.maximum(taper, 0.0005), depth * 0.6))
    return family
