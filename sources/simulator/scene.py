"""A simulated building: its labelled mesh, its rooms, and the ground truth of its damage.

`Scene.look` gives the colour and intensity of surface points (material, mottled texture, lighting of
the object, incidence angle, cracks); `Scene.sample_static_cloud` is the terrestrial "static scan" of
the whole building that missions are matched against.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

import numpy as np

from aftershock.pipeline.types import LabelledCloud
from aftershock.sources.simulator.damage import CrackTruth, LevelMotion, crack_segments, distance_to_polylines
from aftershock.sources.simulator.meshes import LabelledMesh

if TYPE_CHECKING:
    from aftershock.sources.simulator.raycast import Raycaster

STATION_HEIGHT_M: Final = 1.6  # tripod height of the static-scan stations above the floor
STATIC_RANGE_NOISE_M: Final = 0.002  # a terrestrial scanner is millimetre-accurate


@dataclass(frozen=True, slots=True)
class StoryTruth:
    """One story: its floor (top of slab `index`) and ceiling (bottom of slab `index + 1`).

    Drift and tilt are those of the story's floor slab against the ground slab (level 0); the
    inter-story values are ceiling slab minus floor slab. Tilt x is the rotation about the x axis.
    Heights are nominal (undamaged) and measured at the building centre, where tilt moves nothing.
    """

    index: int
    floor_z_m: float
    ceiling_z_m: float
    drift_x_mm: float
    drift_y_mm: float
    tilt_x_deg: float
    tilt_y_deg: float
    inter_story_drift_x_mm: float
    inter_story_drift_y_mm: float
    floor_plane: np.ndarray  # (4,) a, b, c, d of the damaged floor surface, unit normal up
    ceiling_plane: np.ndarray  # (4,) of the damaged ceiling surface, unit normal up
    floor_instance_id: int = 0  # the floor's instance (a collapsed panel is an instance of its own)
    ceiling_instance_id: int = 0

    @property
    def drift_mm(self) -> float:
        return float(np.hypot(self.drift_x_mm, self.drift_y_mm))


@dataclass(frozen=True, slots=True)
class SceneTruth:
    family: str
    seed: int
    footprint_m: tuple[float, float]  # width (x) and depth (y) of the undamaged building
    stories: tuple[StoryTruth, ...]
    levels: tuple[LevelMotion, ...]
    cracks: tuple[CrackTruth, ...]
    instance_classes: dict[int, int]  # instance id -> class id, ids from 1


@dataclass(frozen=True, slots=True)
class Room:
    story: int
    x0: float
    y0: float
    x1: float
    y1: float
    kind: str  # room | corridor | open

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1))


def plane_of(matrix: np.ndarray, z: float) -> np.ndarray:
    """Plane a, b, c, d (unit normal up) of the horizontal plane at height z after a rigid transform."""
    n = matrix[:3, :3] @ np.array([0.0, 0.0, 1.0])
    p = matrix[:3, :3] @ np.array([0.0, 0.0, z]) + matrix[:3, 3]
    return np.r_[n, -float(n @ p)]


@dataclass(slots=True)
class Scene:
    """A building of a family and seed, ready to be scanned."""

    family: str
    seed: int
    mesh: LabelledMesh
    truth: SceneTruth
    rooms: tuple[Room, ...]
    floor_z: tuple[float, ...]  # nominal floor height of each story
    ceiling_z: tuple[float, ...]
    light: float = 1.0  # overall brightness of this building's lighting
    _waves: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    _raycaster: Raycaster | None = None
    _crack_segs: tuple[np.ndarray, ...] | None = None  # segments and a crack-bearing instance table

    @property
    def num_stories(self) -> int:
        return len(self.floor_z)

    def floor_transform(self, story: int) -> np.ndarray:
        """4 x 4 rigid motion of a story's floor (identity for an intact building and for story 0)."""
        return self.truth.levels[story].matrix()

    @property
    def raycaster(self) -> Raycaster:
        if self._raycaster is None:
            from aftershock.sources.simulator.raycast import Raycaster

            self._raycaster = Raycaster(self.mesh)
        return self._raycaster

    # ------------------------------------------------------------------ looks

    def look(
        self, tri: np.ndarray, points: np.ndarray, cos_incidence: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Colour (N, 3) uint8, intensity (N,) float32 and crack mask (N,) of surface points hit on triangles."""
        m = self.mesh
        n = len(tri)
        base = m.colors[tri].astype(np.float32) * (m.shade[tri] * self.light)[:, None]
        # mottling: a few plane waves of different lengths (float32 is plenty here and twice as fast)
        arg = points.astype(np.float32) @ self._waves[:, :3].T.astype(np.float32) + self._waves[:, 3].astype(np.float32)
        tex = np.sin(arg).mean(axis=1) if len(self._waves) else np.zeros(n, np.float32)
        rgb = base * (1.0 + m.texture[tri] * 2.0 * tex)[:, None] + rng.standard_normal((n, 3), np.float32) * 1.5
        refl = m.reflectivity[tri].copy()
        crack = self.crack_mask(points, m.instance_ids[tri])
        if crack.any():
            rgb[crack] = rgb[crack] * 0.45 + 15.0
            refl[crack] *= 0.5
        inten = 255.0 * refl * (0.25 + 0.75 * np.abs(cos_incidence)) * (1 + 0.04 * rng.standard_normal(n, np.float32))
        return (
            np.clip(np.round(rgb), 0, 255).astype(np.uint8),
            np.clip(inten, 0, 255).astype(np.float32),
            crack,
        )

    def crack_mask(self, points: np.ndarray, instance_ids: np.ndarray) -> np.ndarray:
        """Points that fall inside a crack opening of their element."""
        mask = np.zeros(len(points), bool)
        if not self.truth.cracks:
            return mask
        if self._crack_segs is None:
            cracked = np.zeros(int(self.mesh.instance_ids.max()) + 1, bool)
            cracked[[c.element_instance_id for c in self.truth.cracks]] = True
            self._crack_segs = (*crack_segments(list(self.truth.cracks)), cracked)
        a, b, w, idx, cracked = self._crack_segs
        on = np.flatnonzero(cracked[instance_ids])
        if len(on) == 0:
            return mask
        on = on[np.argsort(instance_ids[on], kind="stable")]
        inst_sorted = instance_ids[on]
        for i, c in enumerate(self.truth.cracks):
            lo_i, hi_i = np.searchsorted(inst_sorted, [c.element_instance_id, c.element_instance_id + 1])
            if hi_i == lo_i:
                continue
            cand = on[lo_i:hi_i]
            reach = float(c.widths.max())
            lo, hi = c.polyline.min(0) - reach, c.polyline.max(0) + reach
            near = cand[((points[cand] >= lo) & (points[cand] <= hi)).all(1)]
            if len(near) == 0:
                continue
            sel = idx == i
            d, _ = distance_to_polylines(points[near], a[sel], b[sel], w[sel])
            mask[near[d <= 0]] = True
        return mask

    # ------------------------------------------------------------------ static scan

    def static_stations(self) -> np.ndarray:
        """Scanner stations (S, 3): one per room and every ~6 m of corridor, on every story, in free space."""
        from aftershock.sources.simulator.trajectory import free_space

        out = []
        for story in range(self.num_stories):
            grid = free_space(self, story)
            for room in self.rooms:
                if room.story != story:
                    continue
                cell = grid.best_cell_in(room.x0, room.y0, room.x1, room.y1)
                if cell is None:
                    continue
                out.append(grid.world_point(cell, STATION_HEIGHT_M))
                if room.kind in ("corridor", "open"):  # long spaces get more stations
                    length = max(room.x1 - room.x0, room.y1 - room.y0)
                    for f in np.linspace(0, 1, max(int(length // 6), 1) + 2)[1:-1]:
                        if room.x1 - room.x0 >= room.y1 - room.y0:
                            xa = room.x0 + f * (room.x1 - room.x0)
                            c = grid.best_cell_in(xa - 1.0, room.y0, xa + 1.0, room.y1)
                        else:
                            ya = room.y0 + f * (room.y1 - room.y0)
                            c = grid.best_cell_in(room.x0, ya - 1.0, room.x1, ya + 1.0)
                        if c is not None:
                            out.append(grid.world_point(c, STATION_HEIGHT_M))
        return np.asarray(out, dtype=np.float64).reshape(-1, 3)

    def sample_static_cloud(self, spacing_m: float = 0.05, seed: int = 0, max_range_m: float = 30.0) -> LabelledCloud:
        """The labelled full-building "static scan": ray cast from stations in every room, thinned to one
        point per `spacing_m` voxel (the first in station order), with millimetre range noise."""
        from aftershock.pipeline.geometry import voxel_downsample

        if spacing_m <= 0:
            raise ValueError("spacing must be positive")
        rng = np.random.default_rng([self.seed, seed, 7])
        stations = self.static_stations()
        # Angular step so that surfaces ~6 m away are sampled at the spacing (nearer ones more densely,
        # farther ones are nearer to another station); capped per station.
        step = spacing_m / 6.0
        n_rays = int(min(4 * np.pi / step**2, 1_000_000))
        dirs = fibonacci_sphere(n_rays)
        keep_pts, keep_tri, keep_cos = [], [], []
        for st in stations:
            t, tri, cos = self.raycaster.cast(np.broadcast_to(st, dirs.shape), dirs)
            ok = np.isfinite(t) & (t < max_range_m)
            r = t[ok] + rng.normal(0, STATIC_RANGE_NOISE_M, ok.sum())
            keep_pts.append(st + dirs[ok] * r[:, None])
            keep_tri.append(tri[ok])
            keep_cos.append(cos[ok])
        pts = np.concatenate(keep_pts)
        tri = np.concatenate(keep_tri)
        cos = np.concatenate(keep_cos)
        first, _ = voxel_downsample(pts, spacing_m)
        pts, tri, cos = pts[first], tri[first], cos[first]
        colors, inten, _ = self.look(tri, pts, cos, rng)
        return LabelledCloud(
            points=pts,
            colors=colors,
            intensity=inten,
            class_ids=self.mesh.class_ids[tri].copy(),
            instance_ids=self.mesh.instance_ids[tri].copy(),
        )


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly evenly spread unit directions."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    phi = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
