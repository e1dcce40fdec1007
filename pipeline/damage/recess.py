"""Is a candidate crack recessed? Its points' depth behind the surface around it, in units of the local noise.

A crack is an opening: a scanner that resolves it sees its points lie behind the surface around them, while a
stain, a dirt streak or shade is dark but flat. Each point's depth is its offset from the plane fitted to the
*other* (non-candidate) points of the 3×3×3 block of `cell_m` voxels around it, in units of that plane's own
residual (so a column's corner, where one plane fits badly, is not a recess) and never less than the element's
noise (the robust spread of the sound points' offsets). A crack's depth contrast is the 90th percentile over
its points: the opening is a narrow core of the group, whose smoothed and grown rim lies on the surface.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.damage.measure import keep_cracks
from aftershock.pipeline.geometry import block_sums, point_moments
from aftershock.pipeline.types import Crack

DEPTH_PERCENTILE: Final = 90.0
_MAD_TO_SIGMA: Final = 1.4826
_MIN_SURFACE: Final = 10  # fewer non-candidate points in a block: its plane is fitted to all of them


def depth_z(points: np.ndarray, candidates: np.ndarray, cell_m: float) -> np.ndarray:
    """Unsigned depth (N,) of every point against the surface of the non-`candidates` points around it, in
    local noise units (see the module docstring). Inside a candidate region wider than the block, the plane
    is fitted to all points: a wide flat patch measures flat."""
    q = np.asarray(points, np.float64)
    q = q - q.mean(axis=0)
    sound = ~np.asarray(candidates, bool)
    stats = point_moments(q)
    total = block_sums(q, stats * sound[:, None], cell_m)
    few = total[:, 0] < _MIN_SURFACE
    if few.any():
        total[few] = block_sums(q, stats, cell_m)[few]
    count = total[:, :1]
    mean = total[:, 1:4] / count
    cov = total[:, 4:].reshape(-1, 3, 3) / count[:, :, None] - mean[:, :, None] * mean[:, None, :]
    evals, evecs = np.linalg.eigh(cov)
    offset = np.abs(((q - mean) * evecs[:, :, 0]).sum(axis=1))
    residual = np.sqrt(np.clip(evals[:, 0], 0.0, None))
    # the element's noise: 1.4826 x the median absolute offset of the sound points (a robust sigma)
    noise = _MAD_TO_SIGMA * float(np.median(offset[sound] if sound.any() else offset))
    return offset / np.maximum(residual, max(noise, 1e-9))


def keep_recessed(
    cracks: list[Crack], ids: np.ndarray, z: np.ndarray, min_sigmas: float
) -> tuple[list[Crack], np.ndarray]:
    """Sets each crack's `depth_contrast` (the 90th percentile of `z` over its points); with `min_sigmas` > 0
    only the cracks at least that recessed stay (`keep_cracks`)."""
    for c in cracks:  # one percentile per crack
        c.depth_contrast = float(np.percentile(z[ids == c.instance_id], DEPTH_PERCENTILE))
    return keep_cracks(cracks, ids, [min_sigmas <= 0 or c.depth_contrast >= min_sigmas for c in cracks])
