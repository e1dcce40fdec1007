"""The classical online baseline of the study: incremental region growing on normals and colour over the
voxel map ("normal + colour region growing" in METHODS.md).

Each new voxel gets a normal and a curvature from PCA over the stored points of the 5 x 5 x 5 voxels
around it (points of earlier scans included). The clustering stage then links it to each neighbouring
voxel whose normal is within `cluster.normal_angle_deg` and whose colour is within `cluster.color_distance`
(RGB in [0, 1]); linked voxels share an instance. A voxel too isolated for a normal (fewer than 3 stored
points around it) links on colour alone.

Region growing finds objects but not what they are, so classes come from plain geometric rules on the
voxel's normal, curvature and height against the sensor (nothing is learned):
- a near-horizontal surface (normal within 25° of vertical) below the sensor is floor, above it ceiling;
- a near-vertical surface (normal within 25° of horizontal) is wall;
- everything else, and any voxel with curvature above 0.08 or fewer than 3 neighbours, is clutter.
So beams, columns, doors, windows and furniture faces come out as wall/floor/ceiling/clutter.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.config import Config, Environment
from aftershock.pipeline.geometry import group_pca, norms
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import VoxelMap

NAME: Final = "region-growing"
NORMAL_RADIUS_VOXELS: Final = 2
HORIZONTAL_COS: Final = float(np.cos(np.deg2rad(25.0)))  # |n_z| above this: floor or ceiling
VERTICAL_SIN: Final = float(np.sin(np.deg2rad(25.0)))  # |n_z| below this: wall
MAX_CURVATURE: Final = 0.08


def rule_classes(normals: np.ndarray, curvature: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Class per voxel from its normal, curvature and height above the sensor (the rules in the docstring)."""
    nz = np.abs(normals[:, 2])
    flat = (curvature <= MAX_CURVATURE) & (norms(normals) > 0.5)
    out = np.full(len(nz), SemanticClass.CLUTTER, np.uint16)
    horizontal = flat & (nz >= HORIZONTAL_COS)
    out[horizontal & (heights < 0)] = SemanticClass.FLOOR
    out[horizontal & (heights >= 0)] = SemanticClass.CEILING
    out[flat & (nz <= VERTICAL_SIN)] = SemanticClass.WALL
    return out


class RegionGrowingLabeller:
    name = NAME
    embedding_dim = 0

    def __init__(self, normal_angle_deg: float, color_distance: float, voxel_size_m: float) -> None:
        self.min_cos = float(np.cos(np.deg2rad(normal_angle_deg)))
        self.max_color = float(color_distance)
        self.radius_m = (NORMAL_RADIUS_VOXELS + 0.5) * voxel_size_m

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> None:
        nb = vmap.neighbour_rows(new_rows, NORMAL_RADIUS_VOXELS)
        pos = vmap.positions[np.maximum(nb, 0)]
        centre = vmap.positions[new_rows]
        valid = (nb >= 0) & (norms(pos - centre[:, None, :]) <= self.radius_m)
        normals, curvature = group_pca(pos, valid)
        sensor_z = frame.pose[2, 3] if frame.pose is not None else 0.0
        vmap.normals[new_rows] = normals
        vmap.class_ids[new_rows] = rule_classes(normals, curvature, centre[:, 2] - sensor_z)
        vmap.scores[new_rows] = np.clip(1.0 - curvature / MAX_CURVATURE, 0.0, 1.0)

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        na, nb = vmap.normals[rows_a], vmap.normals[rows_b]
        dot = np.abs(np.einsum("ij,ij->i", na, nb))
        # A voxel too isolated for a normal joins its neighbour's region on colour alone.
        unknown = (np.abs(na).sum(axis=1) == 0) | (np.abs(nb).sum(axis=1) == 0)
        ok = (dot >= self.min_cos) | unknown
        ca = vmap.colors[rows_a].astype(np.float32) / 255.0
        cb = vmap.colors[rows_b].astype(np.float32) / 255.0
        return ok & (norms(ca - cb) < self.max_color)

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        """The rule classes stay per voxel (no instance votes)."""


def create(cfg: Config, name: str = NAME, environment: Environment = Environment.INDOOR) -> RegionGrowingLabeller:
    return RegionGrowingLabeller(cfg.cluster.normal_angle_deg, cfg.cluster.color_distance, cfg.map.voxel_size_m)
