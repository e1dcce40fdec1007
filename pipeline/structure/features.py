"""Evidence from the structure model that transfers between buildings, per voxel, for a network to read
(issue #28: height above the story's floor plane, not a height percentile; distance to the nearest wall plane;
inside a column's footprint; under a slab). A network whose weights name them (models.netconfig
STRUCTURE_FEATURES) reads them; `FEATURES` names the columns in order.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.models.netconfig import STRUCTURE_FEATURES
from aftershock.pipeline.structure.elements import Kind
from aftershock.pipeline.structure.model import StructureModel

FEATURES: Final[tuple[str, ...]] = STRUCTURE_FEATURES
FAR_M: Final = 10.0  # distances are clipped here (and given where no floor or wall is known)
NOTHING_KNOWN: Final[tuple[float, ...]] = (FAR_M, FAR_M, 0.0, 0.0)  # the features where no element is known


def structure_features(model: StructureModel, positions: np.ndarray, sensor_z: float) -> np.ndarray:
    """(N, 4) float32 of `FEATURES` for points in the levelled map frame, seen from a sensor at `sensor_z`."""
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    n = len(pos)
    out = np.zeros((n, len(FEATURES)), np.float32)
    floors = [s for s in model.slabs if s.kind is Kind.FLOOR]
    ceilings = [s for s in model.slabs if s.kind is Kind.CEILING]
    # height above the highest floor plane under each point that lies below the sensor (its story's floor)
    height = np.full(n, FAR_M)
    for s in floors:  # one iteration per floor slab
        zf = s.height_at(pos[:, :2])
        above = pos[:, 2] - zf
        ok = (zf < sensor_z) & (above > -0.5)
        height = np.where(ok & (above < height), above, height)
    out[:, 0] = np.clip(height, -FAR_M, FAR_M)
    # distance to the nearest confirmed wall plane
    dist = np.full(n, FAR_M)
    for pid in model.wall_of_piece:  # one iteration per wall piece
        p = model.pieces[pid]
        d = np.abs(pos[:, :2] @ p.normal + p.offset)
        along = pos[:, :2] @ np.array([-p.normal[1], p.normal[0]])
        beside = np.clip(np.maximum(p.u[0] - along, along - p.u[1]), 0.0, None)
        dist = np.minimum(dist, np.hypot(d, beside))
    out[:, 1] = np.clip(dist, 0.0, FAR_M)
    inside = np.zeros(n, bool)
    for e in model.columns.values():  # one iteration per column
        inside |= np.all((pos[:, :2] >= e.lo[:2]) & (pos[:, :2] <= e.hi[:2]), axis=1)
    out[:, 2] = inside
    under = np.zeros(n, bool)
    for s in ceilings:  # one iteration per ceiling slab
        within = np.all((pos[:, :2] >= s.lo[:2]) & (pos[:, :2] <= s.hi[:2]), axis=1)
        under |= within & (s.height_at(pos[:, :2]) > pos[:, 2])
    out[:, 3] = under
    return out
