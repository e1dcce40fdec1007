"""Procedural multi-story reinforced-concrete buildings: one integer seed, the same building every time.

Layout of a story: a column grid carrying beams and slab panels; outer walls with windows; a corridor
along x with rooms on both sides (or an open-plan side), partition walls with doors; furniture and clutter
in every room. The `disaster` family then adds damage (see `damage.py`): drifted and tilted levels,
spalled and leaning columns, broken walls, collapsed slab panels, debris piles, cracks, tipped furniture.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator import furniture as fur
from aftershock.sources.simulator.contents import furnish
from aftershock.sources.simulator.damage import (
    CrackTruth,
    debris_pile,
    deform,
    level_motions,
    make_crack,
    random_crack_size,
)
from aftershock.sources.simulator.families import family_spec
from aftershock.sources.simulator.layout import Opening, Plan, Wall, make_plan
from aftershock.sources.simulator.meshes import (
    CONCRETE,
    GLASS,
    METAL,
    PLASTER,
    TILE,
    WOOD,
    MeshBuilder,
    rotation_xyz,
    rotation_z,
)
from aftershock.sources.simulator.raycast import Raycaster
from aftershock.sources.simulator.scene import Scene, SceneTruth, StoryTruth, plane_of

CRACK_COLOR: Final = (62, 58, 52)


def build_scene(family: str, seed: int) -> Scene:
    """The building of `family` drawn from `seed` (deterministic), with its labelled mesh and truth."""
    spec = family_spec(family)
    root = np.random.SeedSequence([int(seed), sum(map(ord, family))])
    rngs = [np.random.default_rng(s) for s in root.spawn(6)]
    r_plan, r_struct, r_furn, r_damage, r_crack, r_look = rngs
    plan = make_plan(spec, r_plan)
    b = MeshBuilder(r_struct)
    cracks_on: list[tuple[int, int, np.ndarray, np.ndarray, int, bool]] = []  # candidates for cracks
    _structure(plan, b, r_struct, r_damage, cracks_on)
    for room in plan.rooms:
        furnish(plan, room, b, r_furn, r_damage)
    if spec.damage > 0:
        _damage_stories(plan, b, r_damage)
    mesh, v_level, v_span = b.build()
    center = (plan.width / 2, plan.depth / 2)
    levels_z = [*plan.floor_z, plan.ceiling_z[-1] + plan.slab_t]
    motions = level_motions(r_damage, levels_z, center, plan.story_h, spec.drift_ratio, spec.tilt_deg)
    mesh.vertices = deform(mesh.vertices, v_level, v_span, motions, plan.floor_z, plan.ceiling_z)
    caster = Raycaster(mesh)
    cracks = _cracks(plan, r_crack, cracks_on, motions, caster) if spec.cracks[1] > 0 else []
    stories = []
    for k in range(len(plan.story_h)):
        lo, hi = motions[k], motions[k + 1]
        stories.append(
            StoryTruth(
                index=k,
                floor_z_m=plan.floor_z[k],
                ceiling_z_m=plan.ceiling_z[k],
                drift_x_mm=lo.drift_x_mm,
                drift_y_mm=lo.drift_y_mm,
                tilt_x_deg=lo.tilt_x_deg,
                tilt_y_deg=lo.tilt_y_deg,
                inter_story_drift_x_mm=round(hi.drift_x_mm - lo.drift_x_mm, 3),
                inter_story_drift_y_mm=round(hi.drift_y_mm - lo.drift_y_mm, 3),
                floor_plane=plane_of(lo.matrix(), plan.floor_z[k]),
                ceiling_plane=plane_of(hi.matrix(), plan.ceiling_z[k]),
                floor_instance_id=plan.floor_instances[k],
                ceiling_instance_id=plan.ceiling_instances[k + 1],
            )
        )
    truth = SceneTruth(
        family=family,
        seed=int(seed),
        footprint_m=(plan.width, plan.depth),
        stories=tuple(stories),
        levels=tuple(motions),
        cracks=tuple(cracks),
        instance_classes=dict(b.instance_class),
    )
    waves = np.c_[
        r_look.normal(0, 1, (4, 3)) * np.array([[9.0], [4.0], [1.5], [25.0]]), r_look.uniform(0, 2 * np.pi, 4)
    ]
    return Scene(
        family=family,
        seed=int(seed),
        mesh=mesh,
        truth=truth,
        rooms=tuple(plan.rooms),
        floor_z=tuple(plan.floor_z),
        ceiling_z=tuple(plan.ceiling_z),
        light=float(r_look.uniform(0.85, 1.1)),
        _waves=waves,
        _raycaster=caster,
    )


def _structure(
    plan: Plan,
    b: MeshBuilder,
    rng: np.random.Generator,
    r_damage: np.random.Generator,
    cracks_on: list[tuple[int, int, np.ndarray, np.ndarray, int, bool]],
) -> None:
    spec, w, d, t = plan.spec, plan.width, plan.depth, plan.slab_t
    n_st = len(plan.story_h)
    struct_col = spec.structure_colors[int(rng.integers(len(spec.structure_colors)))]
    collapsed: set[tuple[int, int, int]] = set()
    if spec.collapsed_panels[1] > 0 and n_st > 1:
        for _ in range(int(r_damage.integers(spec.collapsed_panels[0], spec.collapsed_panels[1] + 1))):
            collapsed.add(
                (
                    int(r_damage.integers(1, n_st + 1)),
                    int(r_damage.integers(len(plan.xs) - 1)),
                    int(r_damage.integers(len(plan.ys) - 1)),
                )
            )
    # Slabs: level j top at floor_z[j] (the roof above the last story); each bay panel is a floor half on a
    # ceiling half, so the floor of story j and the ceiling of story j-1 are separate instances.
    for j in range(n_st + 1):
        top = plan.floor_z[j] if j < n_st else plan.ceiling_z[-1] + t
        floor_inst = b.new_instance(C.FLOOR)
        ceil_inst = b.new_instance(C.CEILING) if j > 0 else 0
        plan.floor_instances[j], plan.ceiling_instances[j] = floor_inst, ceil_inst
        floor_col = spec.floor_colors[int(rng.integers(len(spec.floor_colors)))]
        ceil_col = spec.ceiling_colors[int(rng.integers(len(spec.ceiling_colors)))]
        floor_mat = TILE if spec.plastered else CONCRETE
        for ix in range(len(plan.xs) - 1):
            for iy in range(len(plan.ys) - 1):
                x0, x1, y0, y1 = plan.xs[ix], plan.xs[ix + 1], plan.ys[iy], plan.ys[iy + 1]
                cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
                rot, shift = None, np.zeros(3)
                f_inst, c_inst = floor_inst, ceil_inst
                if (j, ix, iy) in collapsed:
                    # hinged on one edge, the panel hangs down into the story below
                    ang = np.deg2rad(r_damage.uniform(8, 22)) * r_damage.choice([-1, 1])
                    rot = rotation_xyz(ang, 0.0, 0.0)
                    hinge = np.array([cx, y0 if ang < 0 else y1, top])
                    shift = (rot @ (np.array([cx, cy, top]) - hinge) + hinge) - np.array([cx, cy, top])
                    f_inst, c_inst = b.new_instance(C.FLOOR), b.new_instance(C.CEILING)
                    debris_pile(
                        b,
                        r_damage,
                        (cx, y1 - 1.0 if ang < 0 else y0 + 1.0),
                        plan.floor_z[j - 1],
                        1.2,
                        0.8,
                        j - 1,
                        spec.structure_colors,
                    )
                top_c = np.array([cx, cy, top - t / 4])
                bot_c = np.array([cx, cy, top - 3 * t / 4])
                if rot is not None:
                    top_c = rot @ (top_c - np.array([cx, cy, top])) + np.array([cx, cy, top]) + shift
                    bot_c = rot @ (bot_c - np.array([cx, cy, top])) + np.array([cx, cy, top]) + shift
                b.add_box(
                    top_c,
                    (x1 - x0, y1 - y0, t / 2),
                    cls=C.FLOOR,
                    instance=f_inst,
                    material=floor_mat,
                    color=floor_col,
                    story=j,
                    rotation=rot,
                )
                if j > 0:
                    b.add_box(
                        bot_c,
                        (x1 - x0, y1 - y0, t / 2),
                        cls=C.CEILING,
                        instance=c_inst,
                        material=PLASTER if spec.plastered else CONCRETE,
                        color=ceil_col,
                        story=j,
                        rotation=rot,
                    )
                    if rot is None:
                        cracks_on.append(
                            (
                                c_inst,
                                int(C.CEILING),
                                np.array([cx, cy, top - t]),
                                np.array([x1 - x0, y1 - y0, 0.0]),
                                j,
                                False,
                            )
                        )
        # Beams under slab j along every column line.
        if j > 0:
            z = top - t - plan.beam_d / 2
            for x in plan.xs:
                inst = b.new_instance(C.BEAM)
                b.add_box(
                    (x, d / 2, z),
                    (0.3, d, plan.beam_d),
                    cls=C.BEAM,
                    instance=inst,
                    material=CONCRETE,
                    color=struct_col,
                    story=j,
                )
            for y in plan.ys:
                inst = b.new_instance(C.BEAM)
                b.add_box(
                    (w / 2, y, z),
                    (w, 0.3, plan.beam_d),
                    cls=C.BEAM,
                    instance=inst,
                    material=CONCRETE,
                    color=struct_col,
                    story=j,
                )
    # Columns at every grid point of every story.
    cw = plan.column_w
    for k in range(n_st):
        z0, z1 = plan.floor_z[k], plan.ceiling_z[k]
        for x in plan.xs:
            for y in plan.ys:
                inst = b.new_instance(C.COLUMN)
                if r_damage.random() < spec.damaged_column_prob:
                    _damaged_column(b, r_damage, inst, x, y, z0, z1, cw, struct_col, k)
                else:
                    b.add_box(
                        (x, y, (z0 + z1) / 2),
                        (cw, cw, z1 - z0),
                        cls=C.COLUMN,
                        instance=inst,
                        material=CONCRETE,
                        color=struct_col,
                        story=k,
                        span=True,
                    )
                cracks_on.append(
                    (inst, int(C.COLUMN), np.array([x, y, (z0 + z1) / 2]), np.array([cw, cw, z1 - z0]), k, True)
                )
    for wall in plan.walls:
        _wall(plan, wall, b, rng, r_damage, cracks_on)


def _damaged_column(
    b: MeshBuilder,
    rng: np.random.Generator,
    inst: int,
    x: float,
    y: float,
    z0: float,
    z1: float,
    cw: float,
    col: tuple[int, int, int],
    k: int,
) -> None:
    """A column spalled over part of its height: the core shifted and thinned there, rebar exposed."""
    h = z1 - z0
    a = z0 + h * rng.uniform(0.1, 0.6)
    c = a + h * rng.uniform(0.12, 0.3)
    core = cw * rng.uniform(0.55, 0.8)
    off = rng.uniform(-0.06, 0.06, 2)
    for lo, hi in ((z0, a), (c, z1)):
        b.add_box(
            (x, y, (lo + hi) / 2),
            (cw, cw, hi - lo),
            cls=C.COLUMN,
            instance=inst,
            material=CONCRETE,
            color=col,
            story=k,
            span=True,
        )
    tilt_x, tilt_y = rng.uniform(-0.08, 0.08, 2)
    b.add_box(
        (x + off[0], y + off[1], (a + c) / 2),
        (core, core, c - a),
        cls=C.COLUMN,
        instance=inst,
        material=CONCRETE,
        color=col,
        story=k,
        span=True,
        rotation=rotation_xyz(tilt_x, tilt_y, 0),
    )
    for sx in (-1, 1):
        for sy in (-1, 1):
            bend = rng.uniform(-0.08, 0.08, 2)
            b.add_box(
                (x + sx * (cw / 2 - 0.05) + bend[0] / 2, y + sy * (cw / 2 - 0.05) + bend[1] / 2, (a + c) / 2),
                (0.02, 0.02, c - a),
                cls=C.COLUMN,
                instance=inst,
                material=METAL,
                color=(95, 70, 55),
                story=k,
                span=True,
                rotation=rotation_xyz(bend[1] * 2, -bend[0] * 2, 0),
            )


def _wall(
    plan: Plan,
    wall: Wall,
    b: MeshBuilder,
    rng: np.random.Generator,
    r_damage: np.random.Generator,
    cracks_on: list[tuple[int, int, np.ndarray, np.ndarray, int, bool]],
) -> None:
    spec = plan.spec
    k = wall.story
    z0, z1 = plan.floor_z[k], plan.ceiling_z[k]
    h = z1 - z0
    inst = b.new_instance(C.WALL)
    color = spec.wall_colors[int(rng.integers(len(spec.wall_colors)))]
    mat = PLASTER if spec.plastered else CONCRETE
    ops = sorted(wall.openings, key=lambda o: o.u0)
    pieces: list[tuple[float, float, float, float]] = []  # u0, u1, z0, z1 (relative)
    u = 0.0
    for o in ops:
        if o.u0 > u:
            pieces.append((u, o.u0, 0.0, h))
        if o.z0 > 0:
            pieces.append((o.u0, o.u1, 0.0, o.z0))
        if o.z1 < h:
            pieces.append((o.u0, o.u1, o.z1, h))
        u = o.u1
    if u < wall.length:
        pieces.append((u, wall.length, 0.0, h))
    if wall.broken:
        _broken_wall(plan, wall, b, r_damage, inst, color, mat, pieces)
    else:
        for pu0, pu1, pz0, pz1 in pieces:
            _wall_box(wall, b, inst, color, mat, pu0, pu1, z0 + pz0, z0 + pz1)
    for pu0, pu1, pz0, pz1 in pieces:
        if pu1 - pu0 > 1.0 and pz1 - pz0 > 1.5 and not wall.broken:
            x, y = wall.point((pu0 + pu1) / 2)
            size = (
                np.array([pu1 - pu0, wall.thickness, pz1 - pz0])
                if wall.along_x
                else np.array([wall.thickness, pu1 - pu0, pz1 - pz0])
            )
            cracks_on.append((inst, int(C.WALL), np.array([x, y, z0 + (pz0 + pz1) / 2]), size, k, True))
    for o in ops:
        if o.kind == "door":
            _door(plan, wall, o, b, rng)
        elif o.kind == "window":
            _window(plan, wall, o, b, rng)


def _wall_box(
    wall: Wall, b: MeshBuilder, inst: int, color: tuple[int, int, int], mat, u0: float, u1: float, z0: float, z1: float
) -> None:
    if u1 - u0 < 1e-3 or z1 - z0 < 1e-3:
        return
    x, y = wall.point((u0 + u1) / 2)
    size = (u1 - u0, wall.thickness, z1 - z0) if wall.along_x else (wall.thickness, u1 - u0, z1 - z0)
    b.add_box(
        (x, y, (z0 + z1) / 2),
        size,
        cls=C.WALL,
        instance=inst,
        material=mat,
        color=color,
        story=wall.story,
        span=True,
        jitter_color=0.0,
    )


def _broken_wall(
    plan: Plan,
    wall: Wall,
    b: MeshBuilder,
    rng: np.random.Generator,
    inst: int,
    color: tuple[int, int, int],
    mat,
    pieces: list[tuple[float, float, float, float]],
) -> None:
    """A partition that partly collapsed: a jagged stump along part of its length, its rubble beside it."""
    z0 = plan.floor_z[wall.story]
    h = plan.ceiling_z[wall.story] - z0
    a = rng.uniform(0.0, 0.5) * wall.length
    c = min(wall.length, a + rng.uniform(1.5, 3.5))
    for pu0, pu1, pz0, pz1 in pieces:
        for lo, hi in ((pu0, min(pu1, a)), (max(pu0, c), pu1)):
            if hi - lo > 1e-3:
                _wall_box(wall, b, inst, color, mat, lo, hi, z0 + pz0, z0 + pz1)
        lo, hi = max(pu0, a), min(pu1, c)
        u = lo
        while u < hi - 1e-3:  # jagged top
            step = min(hi - u, rng.uniform(0.15, 0.5))
            top = min(pz1, max(pz0, h * rng.uniform(0.1, 0.6)))
            _wall_box(wall, b, inst, color, mat, u, u + step, z0 + pz0, z0 + top)
            u += step
    x, y = wall.point((a + c) / 2)
    side = rng.choice([-1, 1]) * 0.7
    pos = (x, y + side) if wall.along_x else (x + side, y)
    debris_pile(b, rng, pos, z0, 0.5 * (c - a) * 0.6 + 0.3, 0.5, wall.story, plan.spec.structure_colors)


def _door(plan: Plan, wall: Wall, o: Opening, b: MeshBuilder, rng: np.random.Generator) -> None:
    k, z0 = wall.story, plan.floor_z[wall.story]
    inst = b.new_instance(C.DOOR)
    col = fur.WOOD_TONES[int(rng.integers(len(fur.WOOD_TONES)))]
    frame = 0.05
    t = wall.thickness + 0.02
    for uu, size_u, zc, hz in (
        (o.u0 + frame / 2, frame, o.z1 / 2, o.z1),
        (o.u1 - frame / 2, frame, o.z1 / 2, o.z1),
        ((o.u0 + o.u1) / 2, o.u1 - o.u0, o.z1 - frame / 2, frame),
    ):
        x, y = wall.point(uu)
        size = (size_u, t, hz) if wall.along_x else (t, size_u, hz)
        b.add_box((x, y, z0 + zc), size, cls=C.DOOR, instance=inst, material=WOOD, color=(200, 200, 196), story=k)
    leaf_w = o.u1 - o.u0 - 2 * frame
    closed = rng.random() < plan.spec.door_closed_prob
    ang = 0.0 if closed else np.deg2rad(rng.uniform(75, 100)) * rng.choice([-1, 1])
    hinge_u = o.u0 + frame
    hx, hy = wall.point(hinge_u)
    base = 0.0 if wall.along_x else np.pi / 2
    rot = rotation_z(base + ang)
    center = np.array([hx, hy, z0 + (o.z1 - frame) / 2]) + rot @ np.array([leaf_w / 2, 0, 0])
    b.add_box(
        center,
        (leaf_w, 0.04, o.z1 - frame - 0.01),
        cls=C.DOOR,
        instance=inst,
        material=WOOD,
        color=col,
        story=k,
        rotation=rot,
    )


def _window(plan: Plan, wall: Wall, o: Opening, b: MeshBuilder, rng: np.random.Generator) -> None:
    k, z0 = wall.story, plan.floor_z[wall.story]
    inst = b.new_instance(C.WINDOW)
    frame_col = (230, 230, 230) if rng.random() < 0.6 else (70, 70, 75)
    fw = 0.06
    t = 0.08
    for uu, su, zc, sz in (
        (o.u0 + fw / 2, fw, (o.z0 + o.z1) / 2, o.z1 - o.z0),
        (o.u1 - fw / 2, fw, (o.z0 + o.z1) / 2, o.z1 - o.z0),
        ((o.u0 + o.u1) / 2, o.u1 - o.u0, o.z0 + fw / 2, fw),
        ((o.u0 + o.u1) / 2, o.u1 - o.u0, o.z1 - fw / 2, fw),
        ((o.u0 + o.u1) / 2, fw, (o.z0 + o.z1) / 2, o.z1 - o.z0),
    ):
        x, y = wall.point(uu)
        size = (su, t, sz) if wall.along_x else (t, su, sz)
        b.add_box((x, y, z0 + zc), size, cls=C.WINDOW, instance=inst, material=METAL, color=frame_col, story=k)
    x, y = wall.point((o.u0 + o.u1) / 2)
    size = (o.u1 - o.u0, 0.01, o.z1 - o.z0) if wall.along_x else (0.01, o.u1 - o.u0, o.z1 - o.z0)
    if plan.spec.damage > 0 and rng.random() < 0.6:
        return  # blown-out glass
    b.add_box((x, y, z0 + (o.z0 + o.z1) / 2), size, cls=C.WINDOW, instance=inst, material=GLASS, story=k)


def _damage_stories(plan: Plan, b: MeshBuilder, rng: np.random.Generator) -> None:
    """Debris piles on every story: in rooms, and against a corridor wall (narrowing but not closing it)."""
    spec = plan.spec
    for k in range(len(plan.story_h)):
        rooms = [r for r in plan.rooms if r.story == k]
        n = int(rng.integers(spec.debris_piles_per_story[0], spec.debris_piles_per_story[1] + 1))
        for _ in range(n):
            # a third of the piles narrow a corridor, where the robot has to get past them
            corridors = [r for r in rooms if r.kind == "corridor"]
            room = corridors[0] if corridors and rng.random() < 0.35 else rooms[int(rng.integers(len(rooms)))]
            if room.kind == "corridor":
                width = room.y1 - room.y0
                r = width * rng.uniform(0.2, 0.35)
                y = room.y0 + r * 0.5 if rng.random() < 0.5 else room.y1 - r * 0.5
                x = rng.uniform(room.x0 + 1.0, room.x1 - 1.0)
                debris_pile(b, rng, (x, y), plan.floor_z[k], r, rng.uniform(0.2, 0.6), k, spec.structure_colors)
            else:
                r = rng.uniform(0.5, 1.5)
                x = rng.uniform(room.x0 + r * 0.5, max(room.x0 + r * 0.5 + 0.01, room.x1 - r * 0.5))
                y = rng.uniform(room.y0 + r * 0.5, max(room.y0 + r * 0.5 + 0.01, room.y1 - r * 0.5))
                debris_pile(b, rng, (x, y), plan.floor_z[k], r, rng.uniform(0.3, 1.0), k, spec.structure_colors)


def _cracks(
    plan: Plan,
    rng: np.random.Generator,
    candidates: list[tuple[int, int, np.ndarray, np.ndarray, int, bool]],
    motions: list,
    caster: Raycaster,
) -> list[CrackTruth]:
    """Cracks on columns (mostly), walls and ceilings, laid out undamaged then moved with their element."""
    spec = plan.spec
    n = int(rng.integers(spec.cracks[0], spec.cracks[1] + 1))
    weights = np.array([3.0 if c[1] == C.COLUMN else 1.5 if c[1] == C.WALL else 1.0 for c in candidates])
    picks = rng.choice(len(candidates), size=min(n, len(candidates)), replace=False, p=weights / weights.sum())
    out = []
    for i in sorted(picks):
        inst, cls, center, size, level, span = candidates[int(i)]
        length, width, depth = random_crack_size(rng)
        if cls == C.CEILING:
            normal = np.array([0.0, 0.0, -1.0])
            u, v = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
            length = min(length * 2, 0.8 * min(size[0], size[1]))
            face_c = center + np.r_[rng.uniform(-0.3, 0.3, 2) * size[:2], 0.0]
            angle = rng.uniform(0, np.pi)
        else:
            # a vertical face: pick one of the sides of the column / wall
            faces = [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)]
            if cls == C.WALL:
                faces = [(int(np.argmin(size[:2])), 1.0), (int(np.argmin(size[:2])), -1.0)]
            axis, sgn = faces[int(rng.integers(len(faces)))]
            normal = np.zeros(3)
            normal[axis] = sgn
            u = np.zeros(3)
            u[1 - axis] = 1.0
            v = np.array([0.0, 0.0, 1.0])
            half_u = size[1 - axis] / 2
            length = min(length, 0.9 * size[2], 2.5 * half_u * 2 if cls == C.COLUMN else 3.0)
            kind = rng.random()
            angle = (
                rng.uniform(0.5, 1.1) * rng.choice([-1, 1])
                if kind < 0.5
                # diagonal shear crack
                else rng.normal(0, 0.12)
                if kind < 0.8
                else np.pi / 2 + rng.normal(0, 0.1)
            )  # flexural / vertical
            reach_u = max(half_u - abs(np.cos(angle)) * length / 2, 0.0)
            reach_v = max(size[2] / 2 - abs(np.sin(angle)) * length / 2 - 0.05, 0.0)
            face_c = (
                center
                + normal * (size[axis] / 2)
                + u * rng.uniform(-reach_u, reach_u) * 0.9
                + v * rng.uniform(-reach_v, reach_v)
            )
            if cls == C.COLUMN:
                # keep the crack on its face: it may not be longer than the face is wide unless near-vertical
                length = min(length, (2 * half_u) / max(abs(np.cos(angle)), 1e-3) * 0.95)
        crack = make_crack(rng, inst, cls, face_c, normal, u, v, length, angle, width, depth, CRACK_COLOR)
        out.append(_move_crack(crack, level, span, motions, plan, caster))
    return out


def _move_crack(crack: CrackTruth, level: int, span: bool, motions: list, plan: Plan, caster: Raycaster) -> CrackTruth:
    """The crack moved with its element: deformed like its level or story, then laid back onto the face
    (the mesh interpolates a sheared face linearly between its corners, the deformation is bilinear)."""
    n = len(crack.polyline)
    lv = np.full(n + 1, level)
    sp = np.full(n + 1, span)
    pts = np.r_[crack.polyline, [crack.polyline.mean(0) + crack.normal]]
    moved = deform(pts, lv, sp, motions, plan.floor_z, plan.ceiling_z)
    nrm = moved[-1] - moved[:-1].mean(0)
    poly, _ = caster.closest_points(moved[:-1])
    direction = poly[-1] - poly[0]
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    return CrackTruth(
        element_instance_id=crack.element_instance_id,
        element_class=crack.element_class,
        center=poly.mean(0),
        direction=direction / np.linalg.norm(direction),
        normal=nrm / np.linalg.norm(nrm),
        length_m=float(seg.sum()),
        width_m=crack.width_m,
        max_width_m=crack.max_width_m,
        depth_m=crack.depth_m,
        color=crack.color,
        polyline=poly,
        widths=crack.widths,
    )
