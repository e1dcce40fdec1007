"""The plane finder behind `make bench-real` (pipeline.planecheck) on synthetic rooms whose planes and labels
are known: it finds the floor, ceiling and walls, measures agreement as the labelled share, and says "no such
plane" (None) rather than 0 where a room lacks one."""

from __future__ import annotations

from typing import Final

import numpy as np
import pytest

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.pipeline.planecheck import check_map, class_shares, find_planes

STEP: Final = 0.1  # sample spacing, as the 0.1 m voxel maps the pipeline exports
SENSOR_Z: Final = 1.2


def _grid(u: tuple[float, float], v: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    uu, vv = np.meshgrid(np.arange(u[0], u[1] + 1e-9, STEP), np.arange(v[0], v[1] + 1e-9, STEP), indexing="ij")
    return uu.reshape(-1), vv.reshape(-1)


def _slab(z: float, x: tuple[float, float], y: tuple[float, float]) -> np.ndarray:
    a, b = _grid(x, y)
    return np.stack([a, b, np.full_like(a, z)], axis=1)


def _wall_x(x: float, y: tuple[float, float], z: tuple[float, float]) -> np.ndarray:
    a, b = _grid(y, z)
    return np.stack([np.full_like(a, x), a, b], axis=1)


def _wall_y(y: float, x: tuple[float, float], z: tuple[float, float]) -> np.ndarray:
    a, b = _grid(x, z)
    return np.stack([a, np.full_like(a, y), b], axis=1)


def _room(ceiling: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A 6 x 5 x 3 m room (floor at 0) with a table; labels: 20 % of the floor clutter, walls half window on
    one of them, the table's top `table` (a horizontal plane too small to be a floor)."""
    rng = np.random.default_rng(0)
    parts: list[tuple[np.ndarray, np.ndarray]] = []
    floor = _slab(0.0, (0, 6), (0, 5))
    fl = np.where(rng.random(len(floor)) < 0.2, C.CLUTTER, C.FLOOR)
    parts.append((floor, fl))
    if ceiling:
        top = _slab(3.0, (0, 6), (0, 5))
        parts.append((top, np.full(len(top), C.CEILING)))
    for w in (
        _wall_x(0.0, (0.2, 4.8), (0.2, 2.8)),
        _wall_x(6.0, (0.2, 4.8), (0.2, 2.8)),
        _wall_y(5.0, (0.2, 5.8), (0.2, 2.8)),
    ):
        parts.append((w, np.full(len(w), C.WALL)))
    south = _wall_y(0.0, (0.2, 5.8), (0.2, 2.8))
    parts.append((south, np.where(south[:, 0] < 3.0, C.WALL, C.WINDOW)))
    table = _slab(0.75, (2.0, 3.0), (2.0, 2.6))
    parts.append((table, np.full(len(table), C.TABLE)))
    points = np.concatenate([p for p, _ in parts]) + rng.normal(0, 0.005, (sum(len(p) for p, _ in parts), 3))
    return points, np.concatenate([c for _, c in parts]).astype(np.uint16)


def test_floor_ceiling_and_walls_of_a_room_with_their_labelled_share() -> None:
    points, classes = _room()
    check = check_map(points, classes, SENSOR_Z)
    assert check.room.floor is not None and check.room.ceiling is not None
    assert check.room.floor.z_m == pytest.approx(0.0, abs=0.03)
    assert check.room.ceiling.z_m == pytest.approx(3.0, abs=0.03)
    assert len(check.room.walls) == 4
    assert check.floor == pytest.approx(0.8, abs=0.03)
    assert check.ceiling == pytest.approx(1.0, abs=0.01)
    south = 0.5 * 57 / (57 + 47 + 47 + 57)  # half of the south wall's columns are window, of all wall points
    assert check.wall == pytest.approx(1.0 - south, abs=0.03)
    assert check.shares["floor"] + check.shares["clutter"] + check.shares["ceiling"] > 0.5


def test_a_room_without_a_ceiling_has_no_ceiling_agreement_not_zero() -> None:
    points, classes = _room(ceiling=False)
    check = check_map(points, classes, SENSOR_Z)
    assert check.room.ceiling is None and check.ceiling is None
    assert check.floor is not None


def test_a_large_table_with_things_under_it_is_not_the_floor() -> None:
    """Without the floor in view, the lowest large horizontal plane is a 2 x 2 m table; the boxes under it
    (a floor hides everything below it) make it no floor."""
    top = _slab(0.75, (1.0, 3.0), (1.0, 3.0))
    under = np.concatenate([_wall_x(x, (1.2, 2.8), (0.2, 0.5)) for x in (1.5, 2.0, 2.5)])
    walls = np.concatenate([_wall_x(0.0, (0, 4), (0.2, 2.8)), _wall_y(0.0, (0, 4), (0.2, 2.8))])
    points = np.concatenate([top, under, walls])
    classes = np.full(len(points), C.TABLE, np.uint16)
    check = check_map(points, classes, SENSOR_Z)
    assert check.room.floor is None and check.floor is None
    assert check.wall == 0.0  # the walls are there, and none of their points is labelled wall


def test_planes_come_largest_first_with_their_kind() -> None:
    points, _ = _room()
    planes = find_planes(points)
    sizes = [len(q.indices) for q in planes]
    assert sizes == sorted(sizes, reverse=True)
    assert {q.kind for q in planes[:6]} == {"horizontal", "vertical"}
    assert class_shares(np.array([C.FLOOR, C.FLOOR, C.WALL, 65535], np.uint16)) == {
        "floor": 0.5,
        "wall": 0.25,
        "unlabelled": 0.25,
    }


def test_a_plane_at_the_sensors_height_is_no_floor() -> None:
    """A large horizontal plane 0.2 m under the sensor, with nothing under it, is taken for a cut along the
    sensor's level rings, not for the floor."""
    top = _slab(SENSOR_Z - 0.2, (0.0, 4.0), (0.0, 4.0))
    walls = _wall_x(0.0, (0, 4), (0.2, 2.8))
    points = np.concatenate([top, walls])
    check = check_map(points, np.full(len(points), C.FLOOR, np.uint16), SENSOR_Z)
    assert check.room.floor is None and check.floor is None
