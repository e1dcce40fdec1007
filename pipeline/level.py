"""Which way is up: the world frame levelled from the first scan's walls and floors.

KISS-ICP's world frame is the first scan's sensor frame. A LiDAR mounted with a pitch or roll (most legged
robots, many handheld rigs, the real Ouster log in `../shared/data`) then gives a world whose z axis is not
vertical, and everything that reads heights — MCPNet's height above the floor, the floor estimate, story
drift — reads them wrong: with a pitched mount labelling collapses and the floor is never labelled floor
(docs/methods.md#levelling-the-map-which-way-is-up).

Up is found from flat patches of one scan (cells of 0.5 m on two staggered grids): floors and ceilings have
normals along it, walls across it. Candidates are the floor-like normals and the lines where two patches meet
(two walls meet along up); the one most patches agree with (within 3°) wins, then a least-squares fit to the
patches that agree (most floor-normal and least wall-normal energy) refines it. Only candidates within 45° of
the sensor's z are tried, which also picks up out of a building's three square axes. A scan that cannot tell
is reported and left as it is: no structure, walls facing one way with hardly any floor (a turn about their
normal goes unseen), or two directions that fit alike.

Settings chosen on the first scans of simulated validation missions, pitched, and on real scans turned by
random angles (docs/decisions.md#levelling-and-the-attitude-hold).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy.spatial.transform import Rotation

from aftershock.pipeline.geometry import label_pca, voxel_index

CELL_M: Final = 0.5  # planar patches: the scan's points grouped into cells of this size
MIN_CELL_POINTS: Final = 12
MAX_CURVATURE: Final = 0.02  # smallest eigenvalue / sum: a patch flatter than this is a plane
MIN_SPREAD: Final = 0.1  # middle eigenvalue / sum: a patch spread less than this across is a line
AGREE_DEG: Final = 3.0  # a patch within this of up is a floor or ceiling, within this of horizontal a wall
CANDIDATE_PAIRS: Final = 2000  # pairs of patches whose meeting line is tried as up
REFINE_ROUNDS: Final = 2
MIN_FLOOR_PATCHES: Final = 5  # fewer floor (or ceiling) patches than this, and
MIN_CROSS_SHARE: Final = 0.15  # ... walls facing one way (the weaker horizontal direction under this share): unsure
MAX_TILT_DEG: Final = 45.0  # further from the sensor's z than this and the estimate is not believed
MIN_PATCHES: Final = 20
MIN_GAP: Final = 0.05  # the winning direction's share of patch weight must lead the next by this much


@dataclass(frozen=True, slots=True)
class UpEstimate:
    up: np.ndarray  # (3,) unit vector, in the scan's frame
    tilt_deg: float  # angle between up and the scan's z axis
    floor_patches: int
    wall_patches: int


def planar_patches(points: np.ndarray, cell_m: float = CELL_M) -> np.ndarray:
    """Unit normals (P, 3) of the flat cells of a point cloud (sign-agnostic), from two grids staggered by half
    a cell, so that a surface cut by one grid's cell boundary is whole in the other."""
    pts = np.asarray(points, np.float64)
    out = []
    for offset in (0.0, 0.5 * cell_m):
        _, normals, shares, count = label_pca(pts, voxel_index(pts + offset, cell_m))
        # flat, and spread both ways: a cell crossed by one scan line is a line, and its "normal" is any
        # direction across it (such cells tilted the estimate by a degree on a level scan)
        flat = (count >= MIN_CELL_POINTS) & (shares[:, 0] < MAX_CURVATURE) & (shares[:, 1] > MIN_SPREAD)
        out.append(normals[flat])
    return np.concatenate(out)


def estimate_up(points: np.ndarray) -> UpEstimate | None:
    """Up in the frame of `points` (one scan, sensor frame), or None when the scan cannot tell."""
    finite = np.isfinite(points).all(axis=1)
    normals = planar_patches(points[finite], CELL_M) if finite.sum() >= MIN_CELL_POINTS else np.zeros((0, 3))
    if len(normals) < MIN_PATCHES:
        return None
    up = _consensus_up(normals)
    for _ in range(REFINE_ROUNDS):
        floors, walls = _agree(normals, up[None])[0]
        energy = normals[floors].T @ normals[floors] - normals[walls].T @ normals[walls]
        values, vectors = np.linalg.eigh(energy)  # ascending
        if values[-1] - values[-2] < MIN_GAP * max(int(floors.sum() + walls.sum()), 1):
            return None  # two directions score alike: walls facing one way and no floor, or no structure
        up = vectors[:, -1] * np.sign(vectors[2, -1] or 1.0)
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    if tilt > MAX_TILT_DEG:
        return None
    floors, walls = _agree(normals, up[None])[0]
    across = np.linalg.eigvalsh(normals[walls].T @ normals[walls])  # ascending: ~0 along up, then the two across
    if floors.sum() < MIN_FLOOR_PATCHES and across[1] < MIN_CROSS_SHARE * across[1:].sum():
        return None  # walls facing one way and hardly any floor: a turn about the walls' normal goes unseen
    return UpEstimate(up=up, tilt_deg=tilt, floor_patches=int(floors.sum()), wall_patches=int(walls.sum()))


def _agree(normals: np.ndarray, ups: np.ndarray) -> np.ndarray:
    """(C, 2, P) masks: which patches lie as a floor (normal along) or a wall (normal across) of each candidate."""
    along = np.abs(ups @ normals.T)  # (C, P)
    return np.stack([along > np.cos(np.radians(AGREE_DEG)), along < np.sin(np.radians(AGREE_DEG))], axis=1)


def _consensus_up(normals: np.ndarray) -> np.ndarray:
    """The candidate up most patches agree with: each floor-like normal, and the line where two patches meet
    (the cross product of their normals: two walls meet along up). Only candidates within MAX_TILT_DEG of the
    sensor's z are tried, which also picks up out of a building's three square axes."""
    rng = np.random.default_rng(0)  # the same scan always gives the same answer
    i, j = rng.integers(len(normals), size=(2, CANDIDATE_PAIRS))
    cands = np.concatenate([normals, np.cross(normals[i], normals[j])])
    size = np.linalg.norm(cands, axis=1)
    cands = cands[size > 0.5] / size[size > 0.5, None]  # nearly parallel pairs say nothing
    cands *= np.where(cands[:, 2] < 0, -1.0, 1.0)[:, None]
    cands = cands[cands[:, 2] >= np.cos(np.radians(MAX_TILT_DEG))]
    if not len(cands):
        return np.array([0.0, 0.0, 1.0])
    votes = _agree(normals, cands).sum(axis=(1, 2))
    return cands[int(np.argmax(votes))]


def leveling_pose(up: np.ndarray) -> np.ndarray:
    """4 x 4 rotation taking `up` to +z by the smallest turn (the heading is left as it was)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up])[0].as_matrix()
    return out
