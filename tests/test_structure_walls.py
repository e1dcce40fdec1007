"""Wall objects (issue #28): one object per wall, as the simulator's truth has one instance per wall (both faces,
the whole line, its openings their own), and a bookcase's or a cabinet's face against a wall no wall."""

from __future__ import annotations

import numpy as np
from test_structure_openings import DOOR, WINDOW, scene
from test_structure_openings import _run as _run_openings

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.config import Environment, StructureConfig
from aftershock.pipeline.structure import Kind, StructureModel
from aftershock.pipeline.voxel_map import VoxelMap

C = SemanticClass
STEP = 0.05


def _grid(a0: float, a1: float, b0: float, b1: float) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.meshgrid(np.arange(a0, a1, STEP), np.arange(b0, b1, STEP), indexing="ij")
    return a.ravel(), b.ravel()


def _wall_keys(model: StructureModel, vmap: VoxelMap, rows: np.ndarray) -> np.ndarray:
    return model.object_keys(len(vmap))[rows]


def test_a_wall_with_a_door_in_it_is_one_object_and_its_door_and_window_are_not_in_it() -> None:
    pts, truth = scene()
    model, vmap, rows = _run_openings(pts)
    keys = _wall_keys(model, vmap, rows)
    south = (truth == C.WALL) & (np.abs(pts[:, 1]) < 0.01) & (pts[:, 2] < DOOR[2])  # both sides of the door
    left, right = south & (pts[:, 0] < DOOR[0] - 0.2), south & (pts[:, 0] > DOOR[1] + 0.2)
    key = np.bincount(keys[left][keys[left] >= 0]).argmax()
    assert np.mean(keys[left] == key) > 0.9 and np.mean(keys[right] == key) > 0.9
    openings = [e for e in model.elements(vmap) if e.kind in (Kind.DOOR, Kind.WINDOW)]
    assert len(openings) == 2
    glass = truth == C.WINDOW
    north = (truth == C.WALL) & (np.abs(pts[:, 1] - 6.0) < 0.01) & (pts[:, 0] < WINDOW[0] - 0.2)
    north_key = np.bincount(keys[north][keys[north] >= 0]).argmax()
    assert north_key != key  # two walls, two objects
    assert np.mean(keys[glass] == north_key) < 0.05  # the window is its own instance, not its wall's


def test_a_cabinet_against_a_wall_is_no_wall_object_and_the_wall_behind_it_is_one() -> None:
    pts, truth = scene()
    model, vmap, rows = _run_openings(pts)
    keys = _wall_keys(model, vmap, rows)
    cabinet = truth == C.BOOKCASE
    west = (truth == C.WALL) & (np.abs(pts[:, 0]) < 0.01)
    wkey = np.bincount(keys[west][keys[west] >= 0]).argmax()
    assert np.mean(keys[west] == wkey) > 0.8
    assert np.mean(keys[cabinet] >= 0) < 0.05


def _two_rooms(thickness: float) -> tuple[VoxelMap, np.ndarray, np.ndarray, np.ndarray, StructureModel]:
    """Two 6 x 5 m rooms, 3 m high, either side of a wall at y = 0 (its faces `thickness` apart), each seen from
    its middle; the far walls stand 5 m off. The map, each point's row, its true class, which face of the shared
    wall it is (0 south, 1 north, -1 none), and the model."""
    parts: list[tuple[np.ndarray, int, int, int]] = []  # points, class, face, room
    h = thickness / 2
    for room, (y0, y1) in enumerate(((-5.0 - h, -h), (h, 5.0 + h))):
        x, y = _grid(0, 6, y0, y1)
        parts += [
            (np.c_[x, y, np.zeros_like(x)], C.FLOOR, -1, room),
            (np.c_[x, y, np.full_like(x, 3.0)], C.CEILING, -1, room),
        ]
        u, z = _grid(0, 6, 0.05, 2.95)
        shared, far = (y1, y0) if room == 0 else (y0, y1)
        parts.append((np.c_[u, np.full_like(u, shared), z], C.WALL, room, room))
        parts.append((np.c_[u, np.full_like(u, far), z], C.WALL, -1, room))
        v, z = _grid(y0, y1, 0.05, 2.95)
        parts += [
            (np.c_[np.zeros_like(v), v, z], C.WALL, -1, room),
            (np.c_[np.full_like(v, 6.0), v, z], C.WALL, -1, room),
        ]
    vmap = VoxelMap(0.1)
    model = StructureModel(StructureConfig(), Environment.INDOOR, 0.1)
    rows, cls, face = [], [], []
    for room in (0, 1):  # one scan from each room's middle
        mine = [p for p in parts if p[3] == room]
        pts = np.concatenate([p[0] for p in mine])
        _, r = vmap.insert(pts)
        vmap.class_ids[r] = C.CLUTTER
        vmap.scores[r] = 0.5
        model.observe(vmap, np.array([3.0, -2.5 if room == 0 else 2.5, 1.0]))
        rows.append(r)
        cls.append(np.concatenate([np.full(len(p[0]), p[1], np.uint16) for p in mine]))
        face.append(np.concatenate([np.full(len(p[0]), p[2]) for p in mine]))
    model.update(vmap, sensor_z=1.0)
    model.finish(vmap)
    model.apply(vmap)
    return vmap, np.concatenate(rows), np.concatenate(cls), np.concatenate(face), model


def test_the_two_faces_of_a_wall_between_two_rooms_are_one_object() -> None:
    vmap, rows, cls, face, model = _two_rooms(0.2)
    keys = model.object_keys(len(vmap))[rows]
    south, north = keys[face == 0], keys[face == 1]
    key = np.bincount(south[south >= 0]).argmax()
    assert np.mean(south == key) > 0.9 and np.mean(north == key) > 0.9
    far = (cls == C.WALL) & (face < 0)
    assert np.mean(keys[far] == key) < 0.05  # the rooms' other walls are other objects


def test_faces_farther_apart_than_a_wall_is_thick_are_two_objects() -> None:
    # back to back 1.2 m apart: two walls (a duct or a shaft between them), not one wall's faces
    vmap, rows, _, face, model = _two_rooms(1.2)
    keys = model.object_keys(len(vmap))[rows]
    south, north = keys[face == 0], keys[face == 1]
    assert np.bincount(south[south >= 0]).argmax() != np.bincount(north[north >= 0]).argmax()


def test_without_wall_objects_a_walls_voxels_are_left_to_the_clustering() -> None:
    pts, truth = scene()
    model, vmap, rows = _run_openings(pts, StructureConfig(wall_objects=False))
    assert np.mean(_wall_keys(model, vmap, rows)[truth == C.WALL] < 0) > 0.9
