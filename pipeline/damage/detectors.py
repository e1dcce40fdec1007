"""Unsupervised crack detectors: a registry of anomaly detectors and clustering baselines over point features.

Every detector gives each point a crack score and a threshold (score > threshold = crack), so that all of them
can be smoothed over space the same way: cracks are spatially coherent, isolated dark specks are not.
Anomaly detectors are fitted on a seeded sample of at most `fit_points` points and applied to all points
(one-class SVM and robust covariance are quadratic or worse in the number of points). `valley_threshold`
reads the contamination from the scores themselves; `grow` is hysteresis held close to a crack.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Final

import numpy as np

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.geometry import block_sums

# K of the clustering baselines per feature set, as in the study (2 to 5 clusters).
CLUSTERS_PER_FEATURE: Final[dict[str, int]] = {
    "rgb": 3,
    "intensity": 3,
    "normal": 3,
    "curvature": 2,
    "fpfh": 2,
    "crackembed": 5,
    "shade": 2,
    "shade+crackembed": 5,
}


class Detector(StrEnum):
    ISOLATION_FOREST = "isolation-forest"
    ROBUST_COVARIANCE = "robust-covariance"
    ONE_CLASS_SVM = "one-class-svm"
    LOCAL_OUTLIER_FACTOR = "lof"
    KMEANS = "kmeans"
    GMM = "gmm"
    MEAN_SHIFT = "mean-shift"
    RIDGE = "ridge"  # not a point-feature detector: thin ridges on the faces' orthoimages (damage/ridge.py)
    REGION = "region"  # not a point-feature detector: damaged regions on the faces' orthoimages (damage/region.py)


@dataclass(frozen=True, slots=True)
class Detection:
    """Per-point crack score (higher = more crack-like) and the threshold above which a point is crack."""

    score: np.ndarray
    threshold: float

    @property
    def mask(self) -> np.ndarray:
        return self.score > self.threshold


# Detectors with a continuous anomaly score (the clustering baselines give 0/1 memberships).
ANOMALY_DETECTORS: Final = frozenset(
    {Detector.ISOLATION_FOREST, Detector.ROBUST_COVARIANCE, Detector.ONE_CLASS_SVM, Detector.LOCAL_OUTLIER_FACTOR}
)


def parse_detector(name: str) -> Detector:
    try:
        return Detector(name)
    except ValueError:
        raise InputError(f"unknown detector {name!r}; choose from {', '.join(d.value for d in Detector)}") from None


def _sample(x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return x if len(x) <= n else x[rng.choice(len(x), size=n, replace=False)]


def _isolation_forest(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    from sklearn.ensemble import IsolationForest

    forest = IsolationForest(n_estimators=100, random_state=seed).fit(fit)
    return Detection(-forest.decision_function(x), 0.0)  # crack = negative decision function


def _robust_covariance(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    from sklearn.covariance import EllipticEnvelope

    env = EllipticEnvelope(contamination=0.1, random_state=seed).fit(fit)
    return Detection(-env.decision_function(x), 0.0)


def _one_class_svm(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    from sklearn.svm import OneClassSVM

    svm = OneClassSVM(gamma="scale", nu=0.1).fit(fit[: min(len(fit), 5000)])
    return Detection(-svm.decision_function(x), 0.0)


def _lof(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    """LOF over all points (not a sample: a point scored against a sample that holds it would be its own
    nearest neighbour). Five neighbours, as in the study."""
    from sklearn.neighbors import LocalOutlierFactor

    lof = LocalOutlierFactor(n_neighbors=5).fit(x)
    return Detection(-lof.negative_outlier_factor_, -lof.offset_)


def _smallest_cluster(labels: np.ndarray, k: int) -> Detection:
    counts = np.bincount(labels, minlength=k)
    counts[counts == 0] = np.iinfo(np.int64).max
    return Detection((labels == int(np.argmin(counts))).astype(np.float64), 0.5)


def _kmeans(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    from sklearn.cluster import KMeans

    model = KMeans(n_clusters=k, n_init=3, random_state=seed).fit(fit)
    return _smallest_cluster(model.predict(x), k)


def _gmm(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    from sklearn.mixture import GaussianMixture

    model = GaussianMixture(n_components=k, covariance_type="full", random_state=seed, reg_covar=1e-4).fit(fit)
    return _smallest_cluster(model.predict(x), k)


def _mean_shift(x: np.ndarray, fit: np.ndarray, seed: int, k: int) -> Detection:
    """Mean-shift modes on the sample; points far from every mode (the study's `cluster_all=False` orphans)
    and points of the smallest mode are crack."""
    from sklearn.cluster import MeanShift, estimate_bandwidth

    small = fit[: min(len(fit), 5000)]
    bandwidth = estimate_bandwidth(small, quantile=0.2, random_state=seed) or 1.0
    model = MeanShift(bandwidth=bandwidth, bin_seeding=True, cluster_all=False, min_bin_freq=5).fit(small)
    centres = model.cluster_centers_
    dist = np.linalg.norm(x[:, None, :] - centres[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    orphan = dist.min(axis=1) > bandwidth
    counts = np.bincount(nearest[~orphan], minlength=len(centres))
    if len(centres) > 1:
        orphan |= nearest == int(np.argmin(counts))
    return Detection(orphan.astype(np.float64), 0.5)


_DETECTORS: Final[dict[Detector, Callable[[np.ndarray, np.ndarray, int, int], Detection]]] = {
    Detector.ISOLATION_FOREST: _isolation_forest,
    Detector.ROBUST_COVARIANCE: _robust_covariance,
    Detector.ONE_CLASS_SVM: _one_class_svm,
    Detector.LOCAL_OUTLIER_FACTOR: _lof,
    Detector.KMEANS: _kmeans,
    Detector.GMM: _gmm,
    Detector.MEAN_SHIFT: _mean_shift,
}


def detect(
    features: np.ndarray,
    detector: Detector | str,
    *,
    seed: int = 0,
    fit_points: int = 20000,
    clusters: int = 2,
) -> Detection:
    """Run one detector over (N, D) features. Features are standardised first (robust covariance, SVM and
    k-means are not scale-free); the isolation forest does not need it but does not mind."""
    kind = parse_detector(detector) if isinstance(detector, str) else detector
    if kind not in _DETECTORS:
        raise InputError(f"detector {kind.value!r} does not work on point features")
    x = np.asarray(features, np.float64)
    std = x.std(axis=0)
    x = (x - x.mean(axis=0)) / np.where(std > 0, std, 1.0)
    rng = np.random.default_rng(seed)
    fit = _sample(x, fit_points, rng)
    return _DETECTORS[kind](x, fit, seed, clusters)


def smooth(points: np.ndarray, detection: Detection, cell_m: float, keep_raw: bool = False) -> Detection:
    """The mean score over the 3×3×3 block of `cell_m` voxels around each point (0 = no smoothing).
    Smoothing joins the speckled detections of a wide damaged zone but averages a crack a few millimetres
    wide away; with `keep_raw` a point's score is the larger of its own and the smoothed one, so both stay."""
    if cell_m <= 0:
        return detection
    sums = block_sums(points, np.stack([detection.score, np.ones(len(points))], axis=1), cell_m)
    score = sums[:, 0] / sums[:, 1]
    if keep_raw:
        score = np.maximum(score, detection.score)
    return Detection(score, detection.threshold)


def valley_threshold(
    score: np.ndarray, floor: float, rise: float = 2.0, min_share: float = 0.03, bins: int = 200
) -> float:
    """The contamination read from the scores themselves: when the histogram of the scores (1st to 999th
    per-mille, lightly smoothed) falls from its main mode to a valley and rises again to a second mode at least
    `rise` times as dense as the valley, holding at least `min_share` of the scores beyond the valley, the
    deepest such valley is the threshold; otherwise `floor` (the detector's own threshold). Never below `floor`.
    Cracks that stand apart from sound concrete form such a mode; where they blend into it (wide damaged zones)
    there is none and the detector's threshold stays; a few stray points far out are not a mode."""
    from scipy.ndimage import gaussian_filter1d

    s = np.asarray(score, np.float64)
    lo, hi = np.quantile(s, [0.001, 0.999])
    if not hi > lo:
        return float(floor)
    hist, edges = np.histogram(s, bins, (lo, hi))
    h = gaussian_filter1d(hist.astype(np.float64), 3.0)
    centres = (edges[:-1] + edges[1:]) / 2
    mode = int(np.argmax(h))
    after = np.r_[np.maximum.accumulate(h[::-1])[::-1][1:], 0.0]  # the densest bin beyond each bin
    i = np.arange(1, bins - 1)
    beyond = (np.cumsum(hist[::-1])[::-1] - hist + np.sum(s > hi)) / len(s)  # share of the scores above each bin
    local_min = (h[i] <= h[i - 1]) & (h[i] <= h[i + 1])
    valley = i[(i > mode) & local_min & (after[i] >= rise * h[i]) & (beyond[i] >= min_share)]
    if len(valley) == 0:
        return float(floor)
    return float(max(centres[valley[np.argmin(h[valley])]], floor))


def grow(points: np.ndarray, mask: np.ndarray, score: np.ndarray, threshold: float, reach_m: float) -> np.ndarray:
    """`mask` plus the points within `reach_m` of it whose `score` is above `threshold` (a lower one than the
    detection's): hysteresis held close to the crack. A crack's weaker points — the thin ends and sides of a
    crack that the support rule trims, the crushed rim of a wide one — join it; weak points elsewhere do not."""
    mask = np.asarray(mask, bool)
    if reach_m <= 0 or not mask.any():
        return mask.copy()
    from scipy.spatial import cKDTree

    cand = np.flatnonzero(~mask & (score > threshold))
    out = mask.copy()
    if len(cand):
        dist, _ = cKDTree(points[mask]).query(points[cand], k=1, distance_upper_bound=reach_m, workers=-1)
        out[cand[np.isfinite(dist)]] = True
    return out


def robust_sigma(x: np.ndarray) -> float:
    """1.4826 × the median absolute deviation: the spread of the bulk of the scores (sound concrete)."""
    x = np.asarray(x, np.float64)
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def null_threshold(score: np.ndarray, sigmas: float) -> float:
    """The score a point of sound concrete rarely reaches: the scores' median plus `sigmas` robust standard
    deviations. The bulk of an element's points is sound surface whether it is cracked or not, so the median
    and the spread describe the sound surface; `sigmas` is calibrated on simulated intact elements so that
    about as few of their points pass as the target allows (`make bench-cracks`)."""
    s = np.asarray(score, np.float64)
    return float(np.median(s) + sigmas * robust_sigma(s))


def mixture_threshold(score: np.ndarray, null: float, min_weight: float, min_separation: float, seed: int = 0) -> float:
    """A two-component Gaussian mixture of the scores: when its upper component holds at least `min_weight`
    of them and lies at least `min_separation` standard deviations of the lower one above it (a population of
    crack points, not a tail of sound ones), the threshold is where a score becomes more likely the upper
    component's; otherwise there is no crack population and the threshold is `null`. Never below `null`."""
    from sklearn.mixture import GaussianMixture

    s = np.asarray(score, np.float64)
    rng = np.random.default_rng(seed)
    sample = s if len(s) <= 20000 else s[rng.choice(len(s), 20000, replace=False)]
    if len(sample) < 20 or not np.ptp(sample) > 0:
        return float(null)
    gmm = GaussianMixture(2, random_state=seed, reg_covar=1e-6).fit(sample.reshape(-1, 1))
    mean, sd, weight = gmm.means_[:, 0], np.sqrt(gmm.covariances_.reshape(-1)), gmm.weights_
    lo, hi = int(np.argmin(mean)), int(np.argmax(mean))
    if weight[hi] < min_weight or (mean[hi] - mean[lo]) / sd[lo] < min_separation:
        return float(null)
    grid = np.linspace(mean[lo], mean[hi], 512).reshape(-1, 1)
    upper = gmm.predict_proba(grid)[:, hi] >= 0.5
    cross = float(grid[np.argmax(upper), 0]) if upper.any() else float(mean[hi])
    return max(cross, float(null))


def edge_points(points: np.ndarray, cell_m: float, offset: float = 0.4) -> np.ndarray:
    """Points on the edge of the scanned surface (the border of an element cut out of a scan, a hole where
    something stood in front): the centroid of the 3×3×3 block of `cell_m` voxels around them lies more than
    `offset` cells away from its centre within the surface (the offset along the surface normal, as at a column's
    corner, does not count). Their neighbourhood is one-sided, so their features look unusual though the
    surface is sound."""
    pts = np.asarray(points, np.float64)
    if cell_m <= 0 or len(pts) < 4:
        return np.zeros(len(pts), bool)
    from aftershock.pipeline.geometry import block_pca

    q = pts - pts.mean(axis=0)
    sums = block_sums(q, np.c_[q, np.ones(len(q))], cell_m)
    centre = (np.floor(q / cell_m) + 0.5) * cell_m  # the block is centred on the point's voxel
    shift = sums[:, :3] / sums[:, 3:] - centre
    normals, _, _ = block_pca(pts, cell_m)
    along = shift - (shift * normals).sum(axis=1, keepdims=True) * normals
    return np.linalg.norm(along, axis=1) > offset * cell_m
