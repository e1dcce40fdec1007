"""Per-point features for crack detection, one registry entry per feature set of the study plus our own.

Colours enter every feature in one range, [-0.5, 0.5] (the original fed its embedding 0..255 colours where
its network was trained on [-0.5, 0.5] — a defect not repeated here). Neighbourhoods are the 3×3×3 block of
voxels around each point, computed for all points at once (`pipeline.geometry.block_pca`).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Final

import numpy as np

from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.geometry import block_pca, block_sums
from aftershock.pipeline.types import LabelledCloud

_MAD_TO_SIGMA: Final = 1.4826


class FeatureSet(StrEnum):
    """The feature sets compared in the study (`rgb` … `crackembed`), `shade` (one-sided darkness) and both
    of ours together."""

    RGB = "rgb"
    INTENSITY = "intensity"
    NORMAL = "normal"
    CURVATURE = "curvature"
    FPFH = "fpfh"
    CRACKEMBED = "crackembed"
    SHADE = "shade"
    SHADE_CRACKEMBED = "shade+crackembed"


def unit_colors(cloud: LabelledCloud) -> np.ndarray:
    """Colours as float32 in [-0.5, 0.5]; a cloud without colour is an input error for colour features."""
    if cloud.colors is None:
        raise InputError("the cloud has no colour, which this crack feature needs (try --features curvature)")
    return np.asarray(cloud.colors, np.float32) / 255.0 - 0.5


def robust_z(x: np.ndarray) -> np.ndarray:
    """(x - median) / (1.4826 · MAD) per column: a scale that ignores the crack points themselves."""
    x = np.asarray(x, np.float64)
    med = np.median(x, axis=0)
    mad = np.median(np.abs(x - med), axis=0) * _MAD_TO_SIGMA
    return ((x - med) / np.where(mad > 0, mad, 1.0)).astype(np.float32)


def _intensity(cloud: LabelledCloud) -> np.ndarray:
    if cloud.intensity is None:
        raise InputError("the cloud has no intensity field, which --features intensity needs")
    return robust_z(cloud.intensity).reshape(-1, 1)


def _rgb(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    return unit_colors(cloud)


def _normal(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    normals, _, _ = block_pca(cloud.points, cfg.normal_cell_m)
    return np.abs(normals).astype(np.float32)  # sign-agnostic, as in the study


def _curvature(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    _, curvature, _ = block_pca(cloud.points, cfg.normal_cell_m)
    return curvature.astype(np.float32).reshape(-1, 1)


def _fpfh(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.normal_cell_m, max_nn=30))
    # open3d's stub leaves out the default of `indices` (every point)
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(  # type: ignore[call-arg]
        pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.fpfh_radius_m, max_nn=100)
    )
    return np.asarray(fpfh.data, np.float32).T.copy()


def _crackembed(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    from aftershock.models.crackembed import embed

    return embed(cloud, cfg)


def local_contrast(points: np.ndarray, values: np.ndarray, cell_m: float) -> np.ndarray:
    """`values` (N, K) minus their mean over the 3×3×3 block of `cell_m` voxels around each point (0 = the
    element's median instead): a high-pass that leaves out shade varying over more than a few cells."""
    v = np.asarray(values, np.float64).reshape(len(points), -1)
    if cell_m <= 0:
        return v - np.median(v, axis=0)
    sums = block_sums(points, np.c_[v, np.ones(len(v))], cell_m)
    return v - sums[:, :-1] / sums[:, -1:]


def _shade(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    """One-sided darkness against the surface around each point (`cfg.shade_cell_m`; 0 = the element's own
    typical surface): how far the grey level and the darkest channel fall below the local mean, in robust
    standard deviations (brighter than usual counts as 0). Cracks and spalls are shadowed cavities and exposed
    aggregate; a bright stain is not a crack, and neither is the shade that falls across a whole element."""
    rgb = unit_colors(cloud)
    contrast = local_contrast(cloud.points, np.stack([rgb.mean(axis=1), rgb.min(axis=1)], axis=1), cfg.shade_cell_m)
    return np.clip(-robust_z(contrast), 0.0, None)


def _shade_crackembed(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    return np.concatenate([_shade(cloud, cfg), _crackembed(cloud, cfg)], axis=1)


_FEATURES: Final[dict[FeatureSet, Callable[[LabelledCloud, CrackConfig], np.ndarray]]] = {
    FeatureSet.RGB: _rgb,
    FeatureSet.INTENSITY: lambda cloud, cfg: _intensity(cloud),
    FeatureSet.NORMAL: _normal,
    FeatureSet.CURVATURE: _curvature,
    FeatureSet.FPFH: _fpfh,
    FeatureSet.CRACKEMBED: _crackembed,
    FeatureSet.SHADE: _shade,
    FeatureSet.SHADE_CRACKEMBED: _shade_crackembed,
}


def parse_features(name: str) -> FeatureSet:
    try:
        return FeatureSet(name)
    except ValueError:
        raise InputError(
            f"unknown feature set {name!r}; choose from {', '.join(f.value for f in FeatureSet)}"
        ) from None


def compute_features(cloud: LabelledCloud, features: FeatureSet | str, cfg: CrackConfig) -> np.ndarray:
    """(N, D) float32 features of every point of `cloud`."""
    kind = parse_features(features) if isinstance(features, str) else features
    out = _FEATURES[kind](cloud, cfg)
    return np.nan_to_num(np.asarray(out, np.float32).reshape(len(cloud), -1))
