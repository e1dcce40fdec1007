"""Does a candidate crack change the surface's hue, or only its brightness?

Shade (a face lit less, light falling across an element) and most dirt scale all three colour channels
alike: they change how much light the surface returns, not its chromaticity (r, g, b over their sum). A crack
shows other material (the concrete's inside, dust, moisture; bare concrete under paint), which shifts the hue
as well. A candidate's chroma contrast is the distance, in percent of chromaticity, between the
chromaticity of its core (the half of its points furthest from the sound surface: its smoothed and grown rim
lies on that surface) and that of the sound points around it (a ring `RING_M` from the candidate), each the
chromaticity of the mean colour of the middle half of each channel's values. A channel at the sensor's ceiling
no longer scales with the light: that mean stays true while under a quarter of the points are clipped
(leaving clipped points out would bias the rest, brighter surroundings more than a darker candidate); a
candidate whose core or ring is clipped into its middle half, or has fewer than `_MIN_POINTS` points, cannot
be judged and keeps a contrast of NaN (never dropped for it).

Off by default (`cracks.min_chroma_contrast` = 0; docs/decisions.md#round-t-the-hue-test): the real elements'
stains have hues of their own (rust, damp) and slab2's cracks hardly any, so on them the test drops cracks and keeps
stains.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scipy.spatial import cKDTree

from aftershock.pipeline.damage.measure import keep_cracks
from aftershock.pipeline.types import Crack

RING_M: Final = (0.015, 0.05)  # the sound surface around a candidate: this far from its nearest point
SATURATED: Final = 255  # a channel at the 8-bit ceiling
_MIN_POINTS: Final = 5  # fewer core or ring points: no contrast (NaN)


def _by_group(values: np.ndarray, owner: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`values` (M,) sorted by owner 0..k and then by value, with each owner's start and count in that order."""
    counts = np.bincount(owner, minlength=k + 1)
    return values[np.lexsort((values, owner))], np.r_[0, np.cumsum(counts)[:-1]], counts


def _group_midmeans(values: np.ndarray, owner: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-column mean of the middle half (25th to 75th percentile) of `values` (M, C) over each owner 0..k, and
    the top of that half: two (k + 1, C) arrays, NaN where an owner has no rows."""
    mean = np.full((k + 1, values.shape[1]), np.nan)
    top = np.full_like(mean, np.nan)
    for c in range(values.shape[1]):  # one sort per channel
        v, starts, counts = _by_group(values[:, c], owner, k)
        has = counts > 0
        lo = starts[has] + counts[has] // 4
        hi = np.maximum(starts[has] + (3 * counts[has] + 3) // 4, lo + 1)  # at least one value
        cum = np.r_[0.0, np.cumsum(v)]
        mean[has, c] = (cum[hi] - cum[lo]) / (hi - lo)
        top[has, c] = v[hi - 1]
    return mean, top


def chroma_contrast(points: np.ndarray, colors: np.ndarray, ids: np.ndarray, sound: np.ndarray) -> np.ndarray:
    """Chroma contrast (K + 1,) of each crack id 1..K of `ids` (0 = no crack) in percent of chromaticity, against
    the `sound` points (not candidates of any kind) around it; entry 0 is unused (NaN). Each sound point belongs
    to the ring of the crack nearest to it."""
    ids = np.asarray(ids, np.int64)
    sound = np.asarray(sound, bool)
    k = int(ids.max(initial=0))
    out = np.full(k + 1, np.nan)
    crack = ids > 0
    if k == 0 or not sound.any():
        return out
    rgb = np.asarray(colors, np.float64)
    crack_idx, sound_idx = np.flatnonzero(crack), np.flatnonzero(sound)
    # the core: crack points at least their crack's median distance from the sound surface
    depth, _ = cKDTree(points[sound_idx]).query(points[crack_idx], k=1, workers=-1)
    crack_ids = ids[crack_idx]
    ordered, starts, counts = _by_group(depth, crack_ids, k)
    median = np.full(k + 1, np.inf)
    median[counts > 0] = ordered[(starts + (counts - 1) // 2)[counts > 0]]
    core = crack_idx[depth >= median[crack_ids]]
    # the ring: sound points RING_M from their nearest crack point
    dist, nearest = cKDTree(points[crack_idx]).query(points[sound_idx], k=1, distance_upper_bound=RING_M[1], workers=-1)
    in_ring = (dist > RING_M[0]) & np.isfinite(dist)
    ring, ring_ids = sound_idx[in_ring], crack_ids[nearest[in_ring]]
    # the middle half's mean: a channel clipped at the ceiling on under a quarter of the points leaves it true
    core_rgb, core_top = _group_midmeans(rgb[core], ids[core], k)
    ring_rgb, ring_top = _group_midmeans(rgb[ring], ring_ids, k)
    core_n = np.bincount(ids[core], minlength=k + 1)
    ring_n = np.bincount(ring_ids, minlength=k + 1)
    judged = (core_n >= _MIN_POINTS) & (ring_n >= _MIN_POINTS)
    judged &= (core_top < SATURATED).all(axis=1) & (ring_top < SATURATED).all(axis=1)
    judged[0] = False
    core_chroma = core_rgb / np.maximum(core_rgb.sum(axis=1, keepdims=True), 1.0)
    ring_chroma = ring_rgb / np.maximum(ring_rgb.sum(axis=1, keepdims=True), 1.0)
    out[judged] = 100.0 * np.linalg.norm(core_chroma[judged] - ring_chroma[judged], axis=1)
    return out


def measure_tint(
    cracks: list[Crack], points: np.ndarray, colors: np.ndarray | None, ids: np.ndarray, sound: np.ndarray
) -> None:
    """Sets each crack's `chroma_contrast` (`chroma_contrast`; NaN without colours). `ids` must still number the
    cracks as `cracks` do."""
    if colors is None:
        return
    contrast = chroma_contrast(points, colors, ids, sound)
    for c in cracks:
        c.chroma_contrast = float(contrast[c.instance_id])


def keep_tinted(cracks: list[Crack], ids: np.ndarray, min_percent: float) -> tuple[list[Crack], np.ndarray]:
    """With `min_percent` > 0 only the cracks whose hue differs at least that much from the surface around them
    (`Crack.chroma_contrast`, set by `measure_tint`) stay, and those that cannot be judged (`keep_cracks`)."""
    keep = [min_percent <= 0 or not c.chroma_contrast < min_percent for c in cracks]  # NaN stays
    return keep_cracks(cracks, ids, keep)
