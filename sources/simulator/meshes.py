"""Labelled triangle meshes built from boxes: every triangle carries its class, instance, colour and material.

A `MeshBuilder` collects oriented boxes (the building blocks of slabs, walls, furniture and debris) and turns
them into one `LabelledMesh` of flat per-triangle arrays that the ray caster indexes by primitive id.
Each box also remembers which story it belongs to and whether it spans the story height, so damage can
deform the building (drift, tilt) vertex by vertex after it was laid out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass

# Corners of the unit cube centred at the origin, and its 12 outward-facing triangles.
_CUBE_CORNERS: Final[np.ndarray] = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float64
)
_CUBE_TRIANGLES: Final[np.ndarray] = np.array(
    [
        [0, 1, 3], [0, 3, 2],  # -x
        [4, 6, 7], [4, 7, 5],  # +x
        [0, 4, 5], [0, 5, 1],  # -y
        [2, 3, 7], [2, 7, 6],  # +y
        [0, 2, 6], [0, 6, 4],  # -z
        [1, 5, 7], [1, 7, 3],  # +z
    ],
    dtype=np.int64,
)  # fmt: skip


@dataclass(frozen=True, slots=True)
class Material:
    """How a surface looks to the camera and the laser."""

    name: str
    color: tuple[int, int, int]
    reflectivity: float  # 0..1, scales the intensity return
    texture: float = 0.08  # relative amplitude of the colour mottling


CONCRETE: Final = Material("concrete", (178, 174, 166), 0.35, 0.10)
PLASTER: Final = Material("plaster", (226, 222, 212), 0.55, 0.04)
TILE: Final = Material("tile", (150, 146, 140), 0.4, 0.06)
WOOD: Final = Material("wood", (150, 104, 64), 0.45, 0.10)
METAL: Final = Material("metal", (120, 124, 130), 0.8, 0.03)
FABRIC: Final = Material("fabric", (70, 84, 120), 0.25, 0.05)
GLASS: Final = Material("glass", (130, 170, 190), 0.1, 0.02)
WHITEBOARD: Final = Material("whiteboard", (238, 240, 242), 0.7, 0.01)
RUBBLE: Final = Material("rubble", (140, 128, 112), 0.3, 0.2)
MIRROR: Final = Material("mirror", (200, 205, 210), 0.05, 0.0)

# What a laser does at a surface (LabelledMesh.optic): returns from it, may pass through it, is reflected.
OPAQUE: Final = 0
TRANSPARENT: Final = 1
SPECULAR: Final = 2
_OPTICS: Final = {"glass": TRANSPARENT, "mirror": SPECULAR}


def rotation_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation R = Rz @ Ry @ Rx (radians)."""
    cx, sx, cy, sy = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    rot_y = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return rotation_z(rz) @ rot_y @ rot_x


@dataclass(slots=True)
class LabelledMesh:
    """Triangles with per-triangle labels and looks; vertices in metres (world frame)."""

    vertices: np.ndarray  # (V, 3) float64
    triangles: np.ndarray  # (T, 3) int32
    class_ids: np.ndarray  # (T,) uint16
    instance_ids: np.ndarray  # (T,) uint32
    colors: np.ndarray  # (T, 3) uint8 base colour
    reflectivity: np.ndarray  # (T,) float32
    texture: np.ndarray  # (T,) float32 mottling amplitude
    shade: np.ndarray  # (T,) float32 lighting factor of the object (lighting-like variation)
    optic: np.ndarray | None = None  # (T,) uint8 OPAQUE / TRANSPARENT (glass) / SPECULAR (mirror); None: all opaque

    def __len__(self) -> int:
        return len(self.triangles)

    def normals(self) -> np.ndarray:
        """Unit face normals (T, 3)."""
        v = self.vertices[self.triangles]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)

    def areas(self) -> np.ndarray:
        v = self.vertices[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


@dataclass(slots=True)
class _Boxes:
    centers: list[np.ndarray] = field(default_factory=list)
    sizes: list[np.ndarray] = field(default_factory=list)
    rotations: list[np.ndarray] = field(default_factory=list)
    class_ids: list[int] = field(default_factory=list)
    instance_ids: list[int] = field(default_factory=list)
    colors: list[np.ndarray] = field(default_factory=list)
    reflectivity: list[float] = field(default_factory=list)
    texture: list[float] = field(default_factory=list)
    shade: list[float] = field(default_factory=list)
    story: list[int] = field(default_factory=list)
    span: list[bool] = field(default_factory=list)
    optic: list[int] = field(default_factory=list)


class MeshBuilder:
    """Collects labelled boxes; `build()` returns the mesh and, per vertex, the story and span flags."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._boxes = _Boxes()
        self._next_instance = 1  # 0 means "no object"
        self.instance_class: dict[int, int] = {}

    def new_instance(self, cls: SemanticClass) -> int:
        inst = self._next_instance
        self._next_instance += 1
        self.instance_class[inst] = int(cls)
        return inst

    @property
    def num_boxes(self) -> int:
        return len(self._boxes.centers)

    def add_box(
        self,
        center: np.ndarray | tuple[float, float, float],
        size: np.ndarray | tuple[float, float, float],
        *,
        cls: SemanticClass,
        instance: int,
        material: Material,
        rotation: np.ndarray | None = None,
        color: np.ndarray | tuple[int, int, int] | None = None,
        shade: float = 1.0,
        story: int = 0,
        span: bool = False,
        jitter_color: float = 0.06,
    ) -> None:
        """One box; `color` overrides the material colour; `jitter_color` varies it a little per box."""
        b = self._boxes
        size_arr = np.maximum(np.asarray(size, dtype=np.float64), 1e-3)
        base = np.asarray(material.color if color is None else color, dtype=np.float64)
        if jitter_color:
            base = base * (1.0 + self._rng.uniform(-jitter_color, jitter_color))
        b.centers.append(np.asarray(center, dtype=np.float64))
        b.sizes.append(size_arr)
        b.rotations.append(np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64))
        b.class_ids.append(int(cls))
        b.instance_ids.append(int(instance))
        b.colors.append(np.clip(base, 0, 255))
        b.reflectivity.append(material.reflectivity)
        b.texture.append(material.texture)
        b.shade.append(shade)
        b.story.append(story)
        b.span.append(span)
        b.optic.append(_OPTICS.get(material.name, OPAQUE))

    def build(self) -> tuple[LabelledMesh, np.ndarray, np.ndarray]:
        """The mesh, and per vertex its story (int) and whether its box spans the story (bool)."""
        b = self._boxes
        n = len(b.centers)
        if n == 0:
            raise ValueError("no boxes to build a mesh from")
        centers, sizes, rots = np.stack(b.centers), np.stack(b.sizes), np.stack(b.rotations)
        local = _CUBE_CORNERS[None, :, :] * sizes[:, None, :]  # (n, 8, 3)
        verts = np.einsum("nij,nkj->nki", rots, local) + centers[:, None, :]
        tris = (_CUBE_TRIANGLES[None, :, :] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
        per_tri = np.repeat(np.arange(n), len(_CUBE_TRIANGLES))
        mesh = LabelledMesh(
            vertices=verts.reshape(-1, 3),
            triangles=tris.astype(np.int32),
            class_ids=np.asarray(b.class_ids, np.uint16)[per_tri],
            instance_ids=np.asarray(b.instance_ids, np.uint32)[per_tri],
            colors=np.round(np.stack(b.colors)).astype(np.uint8)[per_tri],
            reflectivity=np.asarray(b.reflectivity, np.float32)[per_tri],
            texture=np.asarray(b.texture, np.float32)[per_tri],
            shade=np.asarray(b.shade, np.float32)[per_tri],
            optic=np.asarray(b.optic, np.uint8)[per_tri],
        )
        story = np.repeat(np.asarray(b.story, np.int64), 8)
        span = np.repeat(np.asarray(b.span, bool), 8)
        return mesh, story, span
