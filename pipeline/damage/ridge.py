"""Cracks as thin dark ridges on a face's orthoimages, scored against the face's own background.

At each scale the image is smoothed by normalised convolution (holes and the face's edges do not pull it), the
Hessian gives the direction across a line, and the line's contrast is how much darker (or deeper) the centre is
than *both* sides at twice the scale, which must be alike: an edge of a stain, of shade or of the face is a step,
and a blob (a pit, a spot) is dark in every direction, so its Hessian is not line-like. Each contrast is divided
by the robust spread of the same contrast over the face (a crack differs from its surroundings more than the
surface varies), the maximum over scales and the mean over channels is the pixel's score, and hysteresis (seeds
above `high`, grown over pixels above `low`) gives candidate regions, kept when long and elongated.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from scipy import ndimage

from aftershock.pipeline.config import CrackConfig, settings_from
from aftershock.pipeline.damage.faces import Ortho
from aftershock.pipeline.types import LabelledCloud

_MAD_TO_SIGMA: Final = 1.4826
# the median nearest-neighbour distance of a scan underestimates its pitch (jitter brings neighbours closer): an
# image at that pitch is half empty; a quarter more fills most pixels once
PIXEL_SPACINGS: Final = 1.25
_COVER: Final = 0.5  # a pixel is on the face when its point cover, smoothed over 1.5 pixels, reaches this


@dataclass(frozen=True, slots=True)
class RidgeSettings:
    """What the ridge detector looks for (chosen in `make bench-cracks`, see its docstring)."""

    scales_m: tuple[float, ...]  # Gaussian scales, metres (each at least one pixel)
    channels: tuple[str, ...]  # "grey", "depth", "intensity"
    high: float  # seed score (robust sigmas): calibrated on simulated intact elements
    low_ratio: float  # grown over pixels above high x low_ratio
    min_length_m: float  # a crack region is at least this long ...
    min_elongation: float  # ... and this many times longer than wide
    max_line_ratio: float  # |smaller| / larger Hessian eigenvalue: above it the spot is a blob, not a line
    max_chroma: float = 0.0  # a region whose hue lies this far (% chromaticity) from the face's is paint (0: off)
    straight_width_m: float = 0.0  # a thin straight strip along a face axis no wider than this is a joint (0: off)
    member_z: float = 0.0  # a region's pixels darker than the surface around by this many robust sigmas are crack
    rim: bool = False  # at the face's rim, where one side is off the face, compare with the other side alone


def masked_smooth(image: np.ndarray, has: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised convolution: the Gaussian mean over the known pixels only (holes and rims do not pull it)."""
    num = ndimage.gaussian_filter(np.where(has, image, 0.0), sigma, mode="constant")
    den = ndimage.gaussian_filter(has.astype(np.float64), sigma, mode="constant")
    return num / np.maximum(den, 1e-12)


def _robust_z(x: np.ndarray, on: np.ndarray) -> np.ndarray:
    v = x[on]
    if len(v) < 10:
        return np.zeros_like(x)
    med = float(np.median(v))
    mad = _MAD_TO_SIGMA * float(np.median(np.abs(v - med)))
    return np.where(on, (x - med) / max(mad, 1e-12), 0.0)


def line_contrast(
    image: np.ndarray, has: np.ndarray, sigma_px: float, max_line_ratio: float, rim: bool = False
) -> np.ndarray:
    """Contrast (H, W) of a dark line at scale `sigma_px`: the smaller of the two sides' smoothed values less
    the centre's, across the Hessian's direction; 0 where a side falls off the face or the spot is not line-like.
    """
    s = masked_smooth(image, has, sigma_px)
    # on the face: points within a couple of pixels (a side that falls into a hole or off the face is no side)
    cover = ndimage.gaussian_filter(has.astype(np.float64), 1.5, mode="constant") >= _COVER
    syy, syx = np.gradient(np.gradient(s, axis=0), axis=(0, 1))
    sxx = np.gradient(np.gradient(s, axis=1), axis=1)
    half_tr = 0.5 * (syy + sxx)
    root = np.sqrt(0.25 * (syy - sxx) ** 2 + syx**2)
    big, small = half_tr + root, half_tr - root  # eigenvalues; a dark valley curves up across it: big > 0
    # eigenvector of `big`: (syx, big - syy) in (row, col), or along a row when the Hessian is diagonal
    er, ec = syx, big - syy
    flat = np.hypot(er, ec) < 1e-12
    er = np.where(flat, np.where(syy >= sxx, 1.0, 0.0), er)
    ec = np.where(flat, np.where(syy >= sxx, 0.0, 1.0), ec)
    norm = np.hypot(er, ec)
    er, ec = er / norm, ec / norm
    d = 2.0 * sigma_px
    rr, cc = np.indices(s.shape, dtype=np.float64)
    sides = []
    for sign in (1.0, -1.0):
        coords = np.stack([rr + sign * d * er, cc + sign * d * ec])
        value = ndimage.map_coordinates(s, coords, order=1, mode="nearest")
        # the side and the surface beyond it are on the face: at the face's rim one side is an extrapolation
        beyond = np.stack([rr + sign * 1.5 * d * er, cc + sign * 1.5 * d * ec])
        inside = np.ones(s.shape, bool)
        for at in (coords, beyond):
            inside &= ndimage.map_coordinates(cover.astype(np.float64), at, order=0, mode="constant", cval=0.0) > 0
        sides.append(np.where(inside, value, np.nan))
    contrast = np.fmin(sides[0], sides[1]) - s
    # both sides alike: a line is deeper than its sides differ; a step (an edge of shade or of a stain, a wedge of
    # shadow against the face's rim) is not
    contrast = np.where(np.abs(sides[0] - sides[1]) <= 2.0 * contrast, contrast, np.nan)
    if rim:  # at the face's rim (a column's spalled corner) only one side is there: it alone is the reference
        one = np.isfinite(sides[0]) != np.isfinite(sides[1])
        contrast = np.where(one, np.fmax(sides[0], sides[1]) - s, contrast)
    linear = (big > 0) & (np.abs(small) <= max_line_ratio * big)
    ok = cover & np.isfinite(contrast) & linear
    return np.where(ok, np.nan_to_num(contrast), 0.0)


def channel_image(ortho: Ortho, channel: str) -> np.ndarray:
    """The image a channel looks for dark lines on: grey and intensity as they are, depth negated (behind the
    surface = dark)."""
    if channel == "grey":
        return ortho.grey
    if channel == "intensity":
        return ortho.intensity
    if channel == "depth":
        return -ortho.depth
    raise ValueError(f"unknown ridge channel {channel!r}")


def ridge_score(ortho: Ortho, settings: RidgeSettings) -> np.ndarray:
    """Per-pixel score (H, W): over the channels, the mean of the maximum over scales of the line contrast in
    robust sigmas of the face's own contrasts at that scale."""
    has = ortho.count > 0
    total = np.zeros(has.shape)
    used = 0
    for channel in settings.channels:
        image = channel_image(ortho, channel)
        known = has & np.isfinite(image)
        if known.sum() < 50:
            continue
        best = np.zeros(has.shape)
        for scale in settings.scales_m:
            sigma = max(scale / ortho.pixel_m, 1.0)
            c = line_contrast(np.nan_to_num(image), known, sigma, settings.max_line_ratio, settings.rim)
            best = np.maximum(best, _robust_z(c, known & (c != 0)) * (c > 0))
        total += best
        used += 1
    return total / max(used, 1)


def paint(ortho: Ortho, max_chroma: float) -> np.ndarray:
    """Pixels (H, W) whose hue (chromaticity, lightly smoothed) lies more than `max_chroma` percent from the
    face's median: a coat or mark of a colour of its own. Shade, dirt and cracks change how much light comes
    back far more than its hue (damage/tint), so no crack pixel is taken for paint on bare concrete."""
    has = np.isfinite(ortho.chroma).all(axis=2)
    face = np.median(ortho.chroma[has], axis=0)
    dist = np.zeros(has.shape)
    for i in range(2):
        dist += (masked_smooth(np.nan_to_num(ortho.chroma[:, :, i]), has, 1.0) - face[i]) ** 2
    return 100.0 * np.sqrt(dist) > max_chroma


def crack_pixels(image: np.ndarray, ortho: Ortho, regions: np.ndarray, sigma_px: float, min_z: float) -> np.ndarray:
    """The pixels of `regions` darker than the surface around them: the image at one pixel against its mean over
    `sigma_px` outside the regions, in robust sigmas of the same difference over the rest of the face. A region
    found at a coarse scale is wider than the crack; this keeps the opening."""
    has = (ortho.count > 0) & np.isfinite(image)
    inside = ndimage.binary_dilation(regions > 0, iterations=2)
    img = np.nan_to_num(image)
    background = masked_smooth(img, has & ~inside, sigma_px)
    dark = background - masked_smooth(img, has, 0.5)
    ref = dark[has & ~inside]
    med = float(np.median(ref)) if len(ref) else 0.0
    mad = _MAD_TO_SIGMA * float(np.median(np.abs(ref - med))) if len(ref) else 1.0
    z = (dark - med) / max(mad, 1e-12)
    # the opening at half the region's own depth (its 90th percentile of darkness): the full width at half
    # maximum, the usual width of a valley whatever its contrast
    k = int(regions.max(initial=0))
    on = (regions > 0) & has
    core = np.zeros(k + 1)
    if on.any():
        lab, val = regions[on], z[on]
        order = np.lexsort((val, lab))
        lab, val = lab[order], val[order]
        starts = np.searchsorted(lab, np.arange(k + 1))
        ends = np.searchsorted(lab, np.arange(k + 1), side="right")
        filled = ends > starts
        pick = starts + ((ends - starts - 1) * 0.9).astype(np.int64)
        core[filled] = val[pick[filled]]
    level = np.maximum(min_z, 0.5 * core)
    return np.where(on & (z >= level[regions]), regions, 0)


def ridge_regions(score: np.ndarray, ortho: Ortho, settings: RidgeSettings) -> np.ndarray:
    """Labels (H, W) of the kept crack regions (0 = none): hysteresis from `high` down to `high * low_ratio`,
    8-connected, then only regions at least `min_length_m` long (principal extent) and `min_elongation` times
    longer than their mean width (area over length); not a thin straight strip along one of the face's axes
    (a construction joint, a formwork mark, a painted line: cracks wander); not of a hue of their own (paint)."""
    has, pixel_m = ortho.count > 0, ortho.pixel_m
    low = score >= settings.high * settings.low_ratio
    if settings.max_chroma > 0 and np.isfinite(ortho.chroma).any():
        low &= ~paint(ortho, settings.max_chroma)
    labels, k = ndimage.label(low, structure=np.ones((3, 3)))
    if k == 0:
        return labels
    seeds = low & (score >= settings.high)
    if settings.straight_width_m > 0:  # a joint seeds nothing: what it touches is not grown from it
        seed_labels, ks = ndimage.label(seeds, structure=np.ones((3, 3)))
        _, straight = _shape(seed_labels, ks, pixel_m, settings)
        seeds &= ~straight[seed_labels]
    seeded = np.zeros(k + 1, bool)
    seeded[np.unique(labels[seeds])] = True
    seeded[0] = False
    keep = seeded & shape_keep(labels, k, pixel_m, settings)
    new = np.zeros(k + 1, np.int64)
    new[keep] = np.arange(1, int(keep.sum()) + 1)
    return new[labels] * has


def shape_keep(labels: np.ndarray, k: int, pixel_m: float, settings: RidgeSettings) -> np.ndarray:
    """Per label 0..k: long enough, elongated enough, and not a thin straight strip along a face axis (see
    `ridge_regions`); label 0 is never kept."""
    keep, straight = _shape(labels, k, pixel_m, settings)
    return keep & ~straight


def _shape(labels: np.ndarray, k: int, pixel_m: float, settings: RidgeSettings) -> tuple[np.ndarray, np.ndarray]:
    """Per label 0..k: long and elongated enough (the first), a thin straight strip along a face axis (the
    second; never with `straight_width_m` 0)."""
    r, c = np.nonzero(labels)
    lab = labels[r, c]
    n = np.bincount(lab, minlength=k + 1).astype(np.float64)
    n1 = np.maximum(n, 1)
    mr, mc = np.bincount(lab, r, k + 1) / n1, np.bincount(lab, c, k + 1) / n1
    dr, dc = r - mr[lab], c - mc[lab]
    crr = np.bincount(lab, dr * dr, k + 1) / n1
    ccc = np.bincount(lab, dc * dc, k + 1) / n1
    crc = np.bincount(lab, dr * dc, k + 1) / n1
    root = np.sqrt(0.25 * (crr - ccc) ** 2 + crc**2)
    major = 0.5 * (crr + ccc) + root
    minor = np.clip(0.5 * (crr + ccc) - root, 0.0, None)
    length = np.sqrt(12.0 * major) + 1.0  # a strip of length L spreads L^2 / 12 along it
    width = n / length
    keep = (n > 0) & (length * pixel_m >= settings.min_length_m) & (length >= settings.min_elongation * width)
    keep[0] = False
    strip = np.zeros(k + 1, bool)
    if settings.straight_width_m > 0:
        # a straight strip of width w spreads w^2 / 12 across its axis: little more (a ragged pixel edge) = no bend
        angle = np.degrees(np.arctan2(2 * crc, crr - ccc) / 2) % 90.0
        aligned = np.minimum(angle, 90.0 - angle) <= 5.0
        straight = np.sqrt(12.0 * minor) <= 1.5 * width + 2.0
        strip = aligned & straight & (width * pixel_m <= settings.straight_width_m) & (length >= 3 * width)
        strip[0] = False
    return keep, strip


def detect_ridges(
    points: np.ndarray,
    grey: np.ndarray,
    intensity: np.ndarray | None,
    chroma: np.ndarray | None,
    spacing_m: float,
    settings: RidgeSettings,
    seed: int = 0,
    highs: tuple[float, ...] | None = None,
) -> list[np.ndarray]:
    """Per point crack masks (N,) over all the element's faces, one per seed score of `highs` (default: the
    settings' own): the faces and their scores are computed once, the thresholds are cheap."""
    from aftershock.pipeline.damage.faces import fit_faces, unroll

    levels = highs if highs is not None else (settings.high,)
    masks = [np.zeros(len(points), bool) for _ in levels]
    pixel = PIXEL_SPACINGS * spacing_m
    for face in fit_faces(points, spacing_m, seed):  # a handful of faces per element
        ortho = unroll(face, points, grey, intensity, pixel, max(settings.scales_m) * 4, chroma)
        score = ridge_score(ortho, settings)
        image = channel_image(ortho, settings.channels[0])
        for mask, high in zip(masks, levels, strict=True):  # a few thresholds
            level = replace(settings, high=high)
            regions = ridge_regions(score, ortho, level)
            if settings.member_z > 0 and settings.channels[0] != "depth":
                regions = crack_pixels(image, ortho, regions, max(settings.scales_m) / pixel, settings.member_z)
                k = int(regions.max(initial=0))
                regions = np.where(shape_keep(regions, k, pixel, level)[regions], regions, 0)
            mask[face.members] = regions[ortho.rows, ortho.cols] > 0
    return masks


def settings_of(cfg: CrackConfig) -> RidgeSettings:
    return settings_from(cfg, RidgeSettings, "ridge_", max_line_ratio="ridge_line_ratio")


def cloud_channels(cloud: LabelledCloud) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Per point: log grey level, log intensity and (r, g) chromaticity, each None when the cloud lacks it (logs:
    shade scales the light returned, so on a log scale it shifts a face's level and leaves a line's contrast)."""
    grey = chroma = intensity = None
    if cloud.colors is not None:
        rgb = np.asarray(cloud.colors, np.float64) + 1.0
        grey = np.log(rgb.mean(axis=1))
        chroma = rgb[:, :2] / rgb.sum(axis=1, keepdims=True)
    if cloud.intensity is not None:
        intensity = np.log1p(np.clip(np.asarray(cloud.intensity, np.float64), 0.0, None))
    return grey, intensity, chroma


def ridge_masks(
    cloud: LabelledCloud,
    spacing_m: float,
    settings: RidgeSettings,
    seed: int = 0,
    highs: tuple[float, ...] | None = None,
) -> list[np.ndarray]:
    """Crack points of `cloud` by the ridge detector, one mask per seed score of `highs` (default: the settings'
    own); channels the cloud lacks are left out (no colour: grey and hue; none of those asked: the depth)."""
    grey, intensity, chroma = cloud_channels(cloud)
    have = {"grey": grey is not None, "intensity": intensity is not None, "depth": True}
    channels = tuple(c for c in settings.channels if have[c]) or ("depth",)
    settings = replace(settings, channels=channels)
    zeros = np.zeros(len(cloud))
    grey_or = grey if grey is not None else zeros
    return detect_ridges(cloud.points, grey_or, intensity, chroma, spacing_m, settings, seed, highs)


def ridge_mask(cloud: LabelledCloud, spacing_m: float, settings: RidgeSettings, seed: int = 0) -> np.ndarray:
    """Crack points of `cloud` by the ridge detector (`ridge_masks` at the settings' seed score)."""
    return ridge_masks(cloud, spacing_m, settings, seed)[0]
