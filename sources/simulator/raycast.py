"""Ray casting against a labelled mesh with open3d's `RaycastingScene` (Embree underneath)."""

from __future__ import annotations

from typing import Final

import numpy as np
import open3d as o3d

from aftershock.sources.simulator.meshes import LabelledMesh

INVALID: Final = int(o3d.t.geometry.RaycastingScene.INVALID_ID)


def _tensor(array: np.ndarray) -> o3d.core.Tensor:
    """A copy of `array` as an Open3D tensor of its dtype, on the CPU."""
    # open3d's stub makes dtype and device required; they default to the array's and the CPU
    return o3d.core.Tensor(array)  # type: ignore[call-overload]


class Raycaster:
    """First hits of rays: distance (inf for a miss), triangle id (-1 for a miss) and cosine of incidence."""

    def __init__(self, mesh: LabelledMesh, threads: int = 1) -> None:
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(_tensor(mesh.vertices.astype(np.float32)), _tensor(mesh.triangles.astype(np.uint32)))
        self._normals = mesh.normals().astype(np.float32)
        self.threads = threads

    @property
    def normals(self) -> np.ndarray:
        """Unit face normals (T, 3) float32."""
        return self._normals

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays from (N, 3) origins along (N, 3) unit directions."""
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        ans = self._scene.cast_rays(_tensor(rays), nthreads=self.threads)
        t = ans["t_hit"].numpy().astype(np.float64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        hit = prim != INVALID
        prim[~hit] = -1
        t[~hit] = np.inf
        cos = np.zeros(len(t), np.float32)
        cos[hit] = np.abs((self._normals[prim[hit]] * rays[hit, 3:]).sum(axis=1))
        return t, prim, cos

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (N,) from points to the nearest surface."""
        q = _tensor(np.ascontiguousarray(points, dtype=np.float32))
        return self._scene.compute_distance(q, nthreads=self.threads).numpy().astype(np.float64)

    def closest_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest surface points (N, 3) and their triangle ids (N,)."""
        q = _tensor(np.ascontiguousarray(points, dtype=np.float32))
        ans = self._scene.compute_closest_points(q, nthreads=self.threads)
        return ans["points"].numpy().astype(np.float64), ans["primitive_ids"].numpy().astype(np.int64)
