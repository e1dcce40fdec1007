"""Damaged regions (bands, spalled rims) on a face's orthoimages, scored against the face's own sound surface.

The real elements' masks mark damaged bands a few centimetres wide, only a little darker than the surface and
rough inside, often along a face's rim (docs/benchmarks/cracks.md): not thin lines. Each face gets per-pixel
evidence channels -- darkness against the local surround at a few scales, roughness (the local spread of the
depth residual), depth deficit (behind the fitted surface) and hue deviation from the face's median -- each turned
into robust z-scores by the face's own median and MAD (the per-element background model: most of a face is sound).
The positive z-scores are combined (sum or max), hysteresis gives regions, and a region counts when it is large
enough and its peak evidence clears the seed score; an element where no region clears a higher gate has no crack.
The normalised convolution only averages pixels on the face, so a band at the rim is compared with the interior.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from scipy import ndimage

from aftershock.pipeline.config import CrackConfig, settings_from
from aftershock.pipeline.damage.faces import Ortho, fit_faces, unroll
from aftershock.pipeline.damage.ridge import PIXEL_SPACINGS, cloud_channels, masked_smooth
from aftershock.pipeline.types import LabelledCloud

_MAD_TO_SIGMA: Final = 1.4826
CHANNELS: Final = ("dark", "rough", "deficit", "color")
_SURROUND: Final = 4.0  # the surround of a scale is this many times wider than the patch it is compared with
_DETREND_M: Final = 0.3  # the depth residual is taken against the plane's smooth trend over this
_ROUGH_M: Final = 0.01  # roughness: the spread of the depth residual over this
_COVER: Final = 0.5  # a pixel is on the face when its point cover, smoothed over 1.5 pixels, reaches this


@dataclass(frozen=True, slots=True)
class RegionSettings:
    """What the region detector looks for (chosen in tests/bench/bench_cracks_region.py, see its docstring)."""

    channels: tuple[str, ...]  # of CHANNELS
    scales_m: tuple[float, ...]  # darkness scales: a patch of this size against a surround _SURROUND times wider
    combine: str  # "sum" or "max" of the channels' positive robust z-scores
    high: float  # a region's peak evidence (90th percentile of its score) must reach this
    gate_ratio: float  # an element has cracks only if some region's peak reaches high x gate_ratio
    low_ratio: float  # regions grow over pixels above high x low_ratio
    smooth_m: float  # the combined score is averaged over this before hysteresis (damage is a region)
    open_m: float  # ... after a grey opening by a disc this wide: evidence narrower (a joint's groove, a line) goes
    min_area_m2: float  # a region covers at least this much of the face


def _robust_z(x: np.ndarray, on: np.ndarray) -> np.ndarray:
    """(x - median) / (1.4826 MAD) over the face's known pixels; 0 off them or with too few."""
    v = x[on]
    if len(v) < 50:
        return np.zeros_like(x)
    med = float(np.median(v))
    mad = _MAD_TO_SIGMA * float(np.median(np.abs(v - med)))
    if not mad > 0:
        mad = float(np.std(v)) or 1.0
    return np.where(on, (x - med) / mad, 0.0)


def evidence(ortho: Ortho, scales_m: tuple[float, ...]) -> dict[str, np.ndarray]:
    """Per channel of `CHANNELS`, the face's robust z-score image (H, W); a channel the scan lacks (no colour)
    is absent. Darkness is the maximum over scales of each scale's own z-score."""
    has = ortho.count > 0
    px = ortho.pixel_m
    out: dict[str, np.ndarray] = {}
    grey_ok = has & np.isfinite(ortho.grey)
    if grey_ok.sum() >= 50 and np.nanstd(ortho.grey[grey_ok]) > 0:
        g = np.nan_to_num(ortho.grey)
        dark = np.full(has.shape, -np.inf)
        for s in scales_m:
            sig = max(s / px, 1.0)
            d = masked_smooth(g, grey_ok, _SURROUND * sig) - masked_smooth(g, grey_ok, sig)
            dark = np.maximum(dark, _robust_z(d, grey_ok))
        out["dark"] = np.where(grey_ok, dark, 0.0)
    dep_ok = has & np.isfinite(ortho.depth)
    dep = np.nan_to_num(ortho.depth)
    sig = max(_ROUGH_M / px, 1.0)
    mean = masked_smooth(dep, dep_ok, sig)
    spread = np.sqrt(np.clip(masked_smooth(dep * dep, dep_ok, sig) - mean**2, 0.0, None))
    out["rough"] = _robust_z(spread, dep_ok)
    out["deficit"] = _robust_z(-mean, dep_ok)
    chroma_ok = has & np.isfinite(ortho.chroma).all(axis=2)
    if chroma_ok.sum() >= 50:
        face = np.median(ortho.chroma[chroma_ok], axis=0)
        dist = np.zeros(has.shape)
        for i in range(2):
            dist += (masked_smooth(np.nan_to_num(ortho.chroma[:, :, i]), chroma_ok, 1.0) - face[i]) ** 2
        out["color"] = _robust_z(np.sqrt(dist), chroma_ok)
    return out


def combined(ev: dict[str, np.ndarray], ortho: Ortho, settings: RegionSettings) -> np.ndarray:
    """The combined score (H, W): sum or max of the asked channels' positive z-scores, smoothed over `smooth_m`
    and opened by a disc of `open_m`."""
    has = ortho.count > 0
    parts = [np.clip(ev[c], 0.0, None) for c in settings.channels if c in ev]
    if not parts:
        return np.zeros(has.shape)
    stack = np.stack(parts)
    score = stack.sum(axis=0) if settings.combine == "sum" else stack.max(axis=0)
    # on the face: points within a couple of pixels (an empty pixel inside a jittered scan is no hole)
    cover = ndimage.gaussian_filter(has.astype(np.float64), 1.5, mode="constant") >= _COVER
    score = masked_smooth(score, has, max(settings.smooth_m / ortho.pixel_m, 0.5)) if settings.smooth_m > 0 else score
    score = np.where(cover, score, 0.0)
    if settings.open_m > 0:  # a region is wide: what a disc of open_m does not fit in is a line or a groove
        r = max(round(settings.open_m / (2 * ortho.pixel_m)), 1)
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        score = ndimage.grey_opening(score, footprint=yy**2 + xx**2 <= r * r)
    return np.where(has, score, 0.0)


def regions(score: np.ndarray, ortho: Ortho, settings: RegionSettings) -> tuple[np.ndarray, float]:
    """Labels (H, W) of the regions that count (0 = none) and the face's strongest region peak (0 if none):
    hysteresis from `high` down to `high x low_ratio`, 8-connected, at least `min_area_m2`, and the region's
    90th percentile score at least `high`."""
    has = ortho.count > 0
    low = has & (score >= settings.high * settings.low_ratio)
    labels, k = ndimage.label(low, structure=np.ones((3, 3)))
    if k == 0:
        return labels, 0.0
    lab = labels[low]
    val = score[low]
    area = np.bincount(lab, minlength=k + 1) * ortho.pixel_m**2
    order = np.lexsort((val, lab))
    lab_s, val_s = lab[order], val[order]
    starts = np.searchsorted(lab_s, np.arange(k + 1))
    ends = np.searchsorted(lab_s, np.arange(k + 1), side="right")
    peak = np.zeros(k + 1)
    filled = ends > starts
    pick = starts + ((ends - starts - 1) * 0.9).astype(np.int64)
    peak[filled] = val_s[pick[filled]]
    keep = (area >= settings.min_area_m2) & (peak >= settings.high)
    keep[0] = False
    new = np.zeros(k + 1, np.int64)
    new[keep] = np.arange(1, int(keep.sum()) + 1)
    return new[labels], float(peak[keep].max(initial=0.0))


def element_faces(
    cloud: LabelledCloud, spacing_m: float, scales_m: tuple[float, ...], seed: int = 0
) -> list[tuple[Ortho, dict[str, np.ndarray]]]:
    """The element's faces, each with its orthoimages and evidence channels (computed once per element)."""
    grey, intensity, chroma = cloud_channels(cloud)
    grey_or = grey if grey is not None else np.full(len(cloud), np.nan)
    pixel = PIXEL_SPACINGS * spacing_m
    out = []
    for face in fit_faces(cloud.points, spacing_m, seed):  # a handful of faces per element
        ortho = unroll(face, cloud.points, grey_or, intensity, pixel, _DETREND_M, chroma)
        out.append((ortho, evidence(ortho, scales_m)))
    return out


def masks_of(
    faces: list[tuple[Ortho, dict[str, np.ndarray]]],
    n: int,
    settings: RegionSettings,
    highs: tuple[float, ...] | None = None,
) -> list[np.ndarray]:
    """Per point crack masks (n,), one per seed score of `highs` (default: the settings' own). An element whose
    strongest region peak stays under high x gate_ratio has none ("no crack" is an answer)."""
    levels = highs if highs is not None else (settings.high,)
    scores = [combined(ev, ortho, settings) for ortho, ev in faces]
    out = []
    for high in levels:  # a few thresholds; the scores are computed once
        level = replace(settings, high=high)
        mask = np.zeros(n, bool)
        strongest = 0.0
        for (ortho, _), score in zip(faces, scores, strict=True):
            labels, peak = regions(score, ortho, level)
            strongest = max(strongest, peak)
            mask[ortho.face.members] = labels[ortho.rows, ortho.cols] > 0
        out.append(mask if strongest >= high * settings.gate_ratio else np.zeros(n, bool))
    return out


def region_mask(cloud: LabelledCloud, spacing_m: float, settings: RegionSettings, seed: int = 0) -> np.ndarray:
    """Crack points of `cloud` by the region detector at the settings' seed score."""
    faces = element_faces(cloud, spacing_m, settings.scales_m, seed)
    return masks_of(faces, len(cloud), settings)[0]


def settings_of(cfg: CrackConfig) -> RegionSettings:
    return settings_from(cfg, RegionSettings, "region_")
