"""Openings of the structure model (pipeline.structure.openings): a door and a window are gaps in a wall's face
the sensor saw through; a stretch of wall hidden behind furniture is not an opening."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.config import Environment, StructureConfig
from aftershock.pipeline.structure import Kind, StructureModel
from aftershock.pipeline.voxel_map import VoxelMap

C = SemanticClass
STEP = 0.05
SENSOR = np.array([4.0, 3.0, 1.0])
DOOR = (2.0, 3.0, 2.1)  # along x in the wall y = 0: from, to, head height
WINDOW = (4.0, 5.5, 0.9, 2.2)  # along x in the wall y = 6: from, to, sill, head
HIDDEN = (2.2, 3.0)  # along y in the wall x = 0: the stretch a cabinet in front of it hides from the sensor


def _grid(a0: float, a1: float, b0: float, b1: float) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.meshgrid(np.arange(a0, a1, STEP), np.arange(b0, b1, STEP), indexing="ij")
    return a.ravel(), b.ravel()


def _seen_through(pts: np.ndarray, y_face: float, x0: float, x1: float, z0: float, z1: float) -> np.ndarray:
    """Points whose ray from the sensor crosses the face y = `y_face` inside the rectangle."""
    f = (y_face - SENSOR[1]) / (pts[:, 1] - SENSOR[1])
    cross = SENSOR + f[:, None] * (pts - SENSOR)
    return (cross[:, 0] > x0) & (cross[:, 0] < x1) & (cross[:, 2] > z0) & (cross[:, 2] < z1)


def scene() -> tuple[np.ndarray, np.ndarray]:
    """A room 8 x 6 m, 3 m high, seen from one sensor at 1 m: a door in its south wall with a corridor beyond,
    a window in its north wall (glass returns behind the face, nothing beyond), a cabinet in front of its west
    wall hiding a stretch of it."""
    parts: list[tuple[np.ndarray, int]] = []
    x, y = _grid(0, 8, 0, 6)
    parts += [(np.c_[x, y, np.zeros_like(x)], C.FLOOR), (np.c_[x, y, np.full_like(x, 3.0)], C.CEILING)]
    u, z = _grid(0, 8, 0.05, 2.95)
    south = (u < DOOR[0]) | (u >= DOOR[1]) | (z >= DOOR[2])
    parts.append((np.c_[u[south], np.zeros(south.sum()), z[south]], C.WALL))
    north = (u < WINDOW[0]) | (u >= WINDOW[1]) | (z < WINDOW[2]) | (z >= WINDOW[3])
    parts.append((np.c_[u[north], np.full(north.sum(), 6.0), z[north]], C.WALL))
    u, z = _grid(0, 6, 0.05, 2.95)
    west = (u < HIDDEN[0]) | (u >= HIDDEN[1]) | (z >= 2.4)
    parts.append((np.c_[np.zeros(west.sum()), u[west], z[west]], C.WALL))
    parts.append((np.c_[np.full_like(u, 8.0), u, z], C.WALL))
    # beyond the door: the corridor's floor and far wall, where the sensor saw them through the door
    x, y = _grid(0, 8, -2.0, -0.05)
    floor = np.c_[x, y, np.zeros_like(x)]
    parts.append((floor[_seen_through(floor, 0.0, DOOR[0], DOOR[1], 0.0, DOOR[2])], C.FLOOR))
    u, z = _grid(0, 8, 0.05, 2.95)
    far = np.c_[u, np.full_like(u, -2.0), z]
    parts.append((far[_seen_through(far, 0.0, DOOR[0], DOOR[1], 0.0, DOOR[2])], C.WALL))
    # the window: glass 0.12 m behind the face (every other scan line returned), its frame's jambs
    u, z = _grid(WINDOW[0], WINDOW[1], WINDOW[2], WINDOW[3])
    glass = (np.round(z / STEP) % 4) < 2
    parts.append((np.c_[u[glass], np.full(glass.sum(), 6.12), z[glass]], C.WINDOW))
    # the cabinet in front of the west wall (0.5 m deep, 2.4 m high)
    v, z = _grid(HIDDEN[0] - 0.3, HIDDEN[1] + 0.3, 0.05, 2.4)
    parts.append((np.c_[np.full_like(v, 0.8), v, z], C.BOOKCASE))
    pts = np.concatenate([p for p, _ in parts])
    cls = np.concatenate([np.full(len(p), c, np.uint16) for p, c in parts])
    return pts, cls


def _run(pts: np.ndarray, cfg: StructureConfig | None = None) -> tuple[StructureModel, VoxelMap, np.ndarray]:
    vmap = VoxelMap(0.1)
    _, rows = vmap.insert(pts)
    vmap.class_ids[rows] = C.WALL  # the network takes windows and doors in walls for wall
    vmap.scores[rows] = 0.5
    model = StructureModel(cfg or StructureConfig(), Environment.INDOOR, vmap.voxel_size)
    model.observe(vmap, SENSOR)
    model.update(vmap, sensor_z=float(SENSOR[2]))
    model.finish(vmap)
    model.apply(vmap)
    return model, vmap, rows


def test_a_door_and_a_window_are_found_with_their_size_and_the_hidden_stretch_is_not() -> None:
    pts, truth = scene()
    model, vmap, rows = _run(pts)
    openings = [e for e in model.elements(vmap) if e.kind in (Kind.WINDOW, Kind.DOOR)]
    assert sorted(e.kind.value for e in openings) == ["door", "window"]
    door = next(e for e in openings if e.kind is Kind.DOOR)
    window = next(e for e in openings if e.kind is Kind.WINDOW)
    # in their walls' faces, of their size (to a voxel or two: the grid's cells are 0.1 m)
    assert abs(door.lo[1]) < 0.1 and abs(door.hi[1]) < 0.1
    assert abs(door.lo[0] - DOOR[0]) < 0.15 and abs(door.hi[0] - DOOR[1]) < 0.15
    assert abs(door.lo[2]) < 0.1 and abs(door.hi[2] - DOOR[2]) < 0.15
    assert abs(window.lo[1] - 6.0) < 0.1
    assert abs(window.lo[0] - WINDOW[0]) < 0.15 and abs(window.hi[0] - WINDOW[1]) < 0.15
    assert abs(window.lo[2] - WINDOW[2]) < 0.15 and abs(window.hi[2] - WINDOW[3]) < 0.15
    # the glass takes the window's class over the network's "wall"
    got = vmap.class_ids[rows]
    assert np.mean(got[truth == C.WINDOW] == C.WINDOW) > 0.9
    # the walls stay walls, the wall behind the cabinet is no opening
    assert np.mean(got[truth == C.WALL] == C.WALL) > 0.9
    assert all(abs(e.lo[0]) > 0.5 or abs(e.hi[0]) > 0.5 for e in openings)
    # and they go to the outputs as elements with a plane
    doc = door.to_json()
    assert doc["kind"] == "door" and doc["class_id"] == C.DOOR and len(doc["plane"]) == 4
    assert {e.kind: e.class_id for e in model.elements(vmap)}[Kind.CEILING] == C.CEILING  # class 0 too


def test_without_the_rays_through_it_a_gap_is_no_opening() -> None:
    pts, _ = scene()
    behind = pts[:, 1] < -0.02
    model, vmap, _ = _run(pts[~behind])  # nothing seen through the door: a shadow would look the same
    kinds = [e.kind for e in model.elements(vmap)]
    assert Kind.DOOR not in kinds and Kind.WINDOW in kinds
    model, vmap, _ = _run(pts, StructureConfig(openings=False))
    assert not [e for e in model.elements(vmap) if e.kind in (Kind.WINDOW, Kind.DOOR)]


@pytest.mark.parametrize(
    "value", ["structure.opening_min_seen=1.5", "structure.door_min_width_m=0", "structure.sill_min_m=-0.1"]
)
def test_an_opening_setting_out_of_range_names_itself(value: str) -> None:
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.errors import InputError

    with pytest.raises(InputError, match=value.split("=")[0]):
        load_config(None, [value])


def test_the_openings_go_to_the_recording_as_outlines_in_their_walls(tmp_path: Path) -> None:
    from rrd_read import record_structure

    pts, _ = scene()
    model, vmap, _ = _run(pts)
    got = record_structure(tmp_path / "structure.rrd", model.elements(vmap))
    assert "world/structure/openings" in got.under("world/structure")
    assert any("LineStrips3D:strips" in c for c in got.components("world/structure/openings"))


def test_a_window_takes_what_stands_in_its_reveal_and_the_face_around_it_stays_wall() -> None:
    # the window's glass lies 0.12 m behind the wall's face; the face beside its jambs, over its head and under
    # its sill is the wall's own surface (a real log's window took it, and cost the wall its edge)
    pts, truth = scene()
    _, vmap, rows = _run(pts)
    got = vmap.class_ids[rows]
    face = (truth == C.WALL) & (np.abs(pts[:, 1] - 6.0) < 0.01)
    around = face & (pts[:, 0] > WINDOW[0] - 0.3) & (pts[:, 0] < WINDOW[1] + 0.3)
    around &= (pts[:, 2] > WINDOW[2] - 0.3) & (pts[:, 2] < WINDOW[3] + 0.3)
    assert around.sum() > 100
    assert np.all(got[around] == C.WALL), int(np.sum(got[around] == C.WINDOW))
    assert np.mean(got[truth == C.WINDOW] == C.WINDOW) > 0.9


def _box(x0: float, x1: float, y0: float, y1: float, z1: float) -> np.ndarray:
    """The four upright faces of a box standing on the floor, `z1` high."""
    u, z = _grid(x0, x1, 0.05, z1)
    v, w = _grid(y0, y1, 0.05, z1)
    faces = [np.c_[u, np.full_like(u, y0), z], np.c_[u, np.full_like(u, y1), z]]
    return np.concatenate([*faces, np.c_[np.full_like(v, x0), v, w], np.c_[np.full_like(v, x1), v, w]])


def _leaf_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The room with its door's leaf open square off the south wall from the west jamb, seen 0.35 m thick
    (both faces and drift) and 0.8 m long, and a free column 0.45 m square in the room's middle."""
    pts, truth = scene()
    leaf = _box(DOOR[0] - 0.35, DOOR[0], 0.2, 1.0, 2.05)  # beside the gap (hinged at its jamb)
    column = _box(5.8, 6.25, 2.8, 3.25, 2.95)
    pts = np.concatenate([pts, leaf, column])
    truth = np.r_[truth, np.full(len(leaf), C.DOOR, np.uint16), np.full(len(column), C.COLUMN, np.uint16)]
    n = len(pts)
    return pts, truth, np.arange(n - len(leaf) - len(column), n - len(column)), np.arange(n - len(column), n)


def test_an_open_door_leaf_beside_its_doorway_is_no_column_and_a_column_in_the_room_stays_one() -> None:
    pts, _, leaf, column = _leaf_scene()
    model, vmap, rows = _run(pts, StructureConfig(door_leaf_columns=False))
    got = vmap.class_ids[rows]
    assert np.mean(got[leaf] == C.COLUMN) > 0.5  # the free-column test alone takes the leaf for a column
    model, vmap, rows = _run(pts)
    got = vmap.class_ids[rows]
    assert Kind.DOOR in [e.kind for e in model.elements(vmap)]
    assert np.mean(got[leaf] == C.COLUMN) < 0.05
    assert np.mean(got[leaf] == C.DOOR) > 0.5  # the door's leaf takes them
    keys = model.object_keys(model.n)[rows[leaf]][got[leaf] == C.DOOR]
    assert np.all(keys >= 0) and len(np.unique(keys)) == 1  # and stays one object (one panel)
    assert np.mean(got[column] == C.COLUMN) > 0.8
    assert len([e for e in model.elements(vmap) if e.kind is Kind.COLUMN]) == 1
