"""The structure model's debris (pipeline/structure/debris.py): what lies on a floor slab, on no element, shaped
like no furniture, is debris; furniture standing on the floor is not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from test_structure import _box_faces, _grid, _map, room

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.config import Environment, StructureConfig
from aftershock.pipeline.structure import Kind, StructureModel
from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.voxel_map import VoxelMap
from aftershock.sinks.structure_layer import structure_json

C = SemanticClass


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _rotated_box(centre: np.ndarray, size: np.ndarray, rot: np.ndarray, step: float = 0.03) -> np.ndarray:
    """Points on the six faces of a box of `size` turned by `rot` about its centre."""
    faces = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        u, v = np.meshgrid(
            np.arange(-size[a] / 2, size[a] / 2 + 1e-9, step),
            np.arange(-size[b] / 2, size[b] / 2 + 1e-9, step),
            indexing="ij",
        )
        for side in (-0.5, 0.5):
            p = np.zeros((u.size, 3))
            p[:, a], p[:, b], p[:, axis] = u.ravel(), v.ravel(), side * size[axis]
            faces.append(p)
    return np.concatenate(faces) @ rot.T + centre


def pile(cx: float, cy: float, radius: float = 0.7, height: float = 0.5, seed: int = 0) -> np.ndarray:
    """A mound of broken pieces: many small boxes at random angles, larger and higher towards the middle (the
    simulator's `debris_pile`, without its colours)."""
    rng = np.random.default_rng(seed)
    n = 90
    rho = radius * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    sizes = rng.uniform(0.08, 0.35, (n, 3)) * np.clip(1.2 - rho / radius, 0.3, 1.0)[:, None]
    z = height * (1 - (rho / radius) ** 2) * rng.uniform(0.3, 1.0, n) + sizes[:, 2] / 2
    centres = np.c_[cx + rho * np.cos(phi), cy + rho * np.sin(phi), z]
    return np.concatenate([_rotated_box(c, s, _rotation(rng)) for c, s in zip(centres, sizes, strict=True)])


def table(x0: float, y0: float, w: float = 1.4, d: float = 0.8, h: float = 0.75) -> np.ndarray:
    """A table top on four legs."""
    x, y = _grid(x0, x0 + w, y0, y0 + d)
    parts = [np.c_[x, y, np.full_like(x, h)]]
    for lx, ly in ((x0, y0), (x0 + w - 0.05, y0), (x0, y0 + d - 0.05), (x0 + w - 0.05, y0 + d - 0.05)):
        parts.append(_box_faces(lx, lx + 0.05, ly, ly + 0.05, 0.05, h))
    return np.concatenate(parts)


def chair(x0: float, y0: float) -> np.ndarray:
    """A seat at 0.45 m on four legs and a back up to 0.9 m."""
    return np.concatenate([table(x0, y0, 0.45, 0.45, 0.45), _box_faces(x0, x0 + 0.45, y0 + 0.4, y0 + 0.45, 0.45, 0.9)])


def _seen(
    parts: list[tuple[np.ndarray, int]], network: int = C.CLUTTER, score: float = 0.5, **settings: object
) -> tuple[StructureModel, VoxelMap, np.ndarray, np.ndarray]:
    """A 10 x 8 m room with `parts` (points, true class) in it, the network's `network` class everywhere, seen
    from its middle: the model, the map, each point's fused class and its truth."""
    pts, truth = room(x1=10.0, y1=8.0)
    pts = np.concatenate([pts, *[p for p, _ in parts]])
    truth = np.r_[truth, *[np.full(len(p), c, np.uint16) for p, c in parts]]
    vmap, rows = _map(pts, np.full(len(pts), network, np.uint16), score)
    model = StructureModel(StructureConfig(**settings), Environment.INDOOR, vmap.voxel_size)  # type: ignore[arg-type]
    model.observe(vmap, np.array([5.0, 5.0, 1.0]))
    model.update(vmap, sensor_z=1.0)
    model.finish(vmap)
    model.apply(vmap)
    return model, vmap, vmap.class_ids[rows], truth


def _off_floor(truth: np.ndarray, pts_z: np.ndarray, cls: int) -> np.ndarray:
    return (truth == cls) & (pts_z > 0.08)


def test_a_pile_of_small_boxes_at_random_angles_on_the_floor_becomes_debris() -> None:
    heap = pile(6.5, 5.5)
    model, vmap, got, truth = _seen([(heap, C.DEBRIS)])
    assert np.mean(got[truth == C.DEBRIS] == C.DEBRIS) > 0.8
    found = [e for e in model.elements(vmap) if e.kind is Kind.DEBRIS]
    assert len(found) == 1 and found[0].class_id == C.DEBRIS
    assert np.allclose((found[0].lo[:2] + found[0].hi[:2]) / 2, [6.5, 5.5], atol=0.3)
    assert np.mean(got[truth == C.FLOOR] == C.FLOOR) > 0.95  # the floor around and under it stays floor


def test_a_panel_fallen_flat_onto_the_floor_becomes_debris() -> None:
    x, y = _grid(6.0, 7.1, 5.0, 5.9)
    panel = np.c_[x, y, 0.1 + 0.04 * (x - 6.0)]  # lying a little tilted, 0.1-0.14 m above the floor
    _, _, got, truth = _seen([(panel, C.DEBRIS)])
    assert np.mean(got[truth == C.DEBRIS] == C.DEBRIS) > 0.8


def test_a_table_a_chair_and_a_cabinet_on_the_floor_are_not_debris() -> None:
    things = [
        (table(6.0, 5.0), C.TABLE),
        (chair(3.0, 5.5), C.CHAIR),
        (_box_faces(7.5, 8.5, 2.5, 3.0, 0.05, 0.9), C.BOOKCASE),  # a low cabinet: flat faces at right angles
        (_box_faces(2.0, 2.4, 2.0, 2.4, 0.05, 0.3), C.CLUTTER),  # a box on the floor: too small for a heap
    ]
    model, vmap, got, _ = _seen(things)
    assert not np.any(got == C.DEBRIS)
    assert not any(e.kind is Kind.DEBRIS for e in model.elements(vmap))


def test_a_pile_the_network_is_sure_is_something_else_keeps_the_networks_class() -> None:
    _, _, got, truth = _seen([(pile(6.5, 5.5), C.DEBRIS)], network=C.SOFA, score=0.95)
    assert np.mean(got[truth == C.DEBRIS] == C.SOFA) > 0.95


def test_a_pile_leaning_on_a_wall_is_debris_and_the_wall_stays_wall() -> None:
    _, _, got, truth = _seen([(pile(5.0, 7.35, radius=0.6), C.DEBRIS)])  # against the wall at y = 8
    assert np.mean(got[truth == C.DEBRIS] == C.DEBRIS) > 0.6
    assert np.mean(got[truth == C.WALL] == C.WALL) > 0.9


def test_debris_off_leaves_the_networks_label() -> None:
    _, _, got, _ = _seen([(pile(6.5, 5.5), C.DEBRIS)], debris=False)
    assert not np.any(got == C.DEBRIS)


def test_debris_goes_to_structure_json_as_its_own_kind() -> None:
    e = Element(7, Kind.DEBRIS, np.zeros(3), np.ones(3), voxels=40)
    doc = structure_json([e])
    assert doc["counts"] == {"debris": 1}
    assert doc["elements"][0]["class_id"] == C.DEBRIS and doc["elements"][0]["kind"] == "debris"


def test_every_kind_of_element_has_its_class() -> None:
    expected = {Kind.CEILING: C.CEILING, Kind.FLOOR: C.FLOOR, Kind.DOOR: C.DOOR, Kind.DEBRIS: C.DEBRIS}
    for kind in Kind:
        cls = Element(1, kind, np.zeros(3), np.ones(3)).class_id
        assert cls == expected.get(kind, cls) and 0 <= cls < 15


def test_debris_goes_to_the_recording_as_boxes_under_world_structure_debris(tmp_path: Path) -> None:
    from rrd_read import record_structure

    model, vmap, _, _ = _seen([(pile(6.5, 5.5), C.DEBRIS)])
    got = record_structure(tmp_path / "structure.rrd", model.elements(vmap))
    assert "world/structure/debris" in got.under("world/structure")
    assert any("Boxes3D" in c for c in got.components("world/structure/debris"))
