"""On-demand, class-agnostic re-segmentation of a labelled map (or any cloud) by LRGNet region growing.

result = refine_cloud(cloud, Config().lrgnet, record_object=3)
result.instance_ids      # (N,) uint32 object id of every point, 1.. in growth order
result.steps             # object 3's growth: (inlier indices, neighbour indices) into the cloud, per step
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import torch

from aftershock.models.lrgnet import LRGNet, load_weights
from aftershock.models.weights_file import WEIGHTS_DIR
from aftershock.pipeline.config import LRGNET_MODE_DEFAULTS, LRGNetConfig
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.geometry import attach_small_segments
from aftershock.pipeline.refine.features import NUM_FEATURES, PLANE_FEATURES, VoxelCloud, voxelise
from aftershock.pipeline.refine.grow import Grower, ModeSettings, Search
from aftershock.pipeline.refine.merge import merge_coplanar, split_creases
from aftershock.pipeline.types import LabelledCloud

DEFAULT_WEIGHTS: Final = WEIGHTS_DIR / "lrgnet.pt"
FEATURE_VERSION: Final = 2  # bump when the meaning of the features changes (2: planarity, linearity, verticality)
# Feature layouts that weights may have been trained for (version -> features). Each is a prefix of the current
# one, so older weights read the first columns: version 1 is the 13 features before the local shape.
# Version 3 adds the per-step plane features (`features.plane_features`) after the 16: the shipped lrgnet.pt since
# round P2 (`lrgnet_train.PLANE`; docs/decisions.md#round-p2-lrgnet-plane-features-full-size); files of version 2
# run without them.
PLANE_VERSION: Final = 3
LAYOUTS: Final = {1: 13, FEATURE_VERSION: NUM_FEATURES, PLANE_VERSION: NUM_FEATURES + PLANE_FEATURES}


@dataclass(slots=True)
class RefineResult:
    instance_ids: np.ndarray  # (N,) uint32 for every point of the input cloud
    steps: list[tuple[np.ndarray, np.ndarray]] | None  # one object's growth, point indices into the cloud
    steps_per_object: list[int] = field(default_factory=list)
    segments: int = 0
    voxels: int = 0
    seconds: float = 0.0
    color: bool = True  # the cloud had colour, so it was grown with that mode's settings
    settings: dict[str, float] = field(default_factory=dict)  # the mode-dependent settings it was grown with


def weight_settings(cfg: LRGNetConfig, plane: bool = False) -> dict[str, Any]:
    """What weights trained now for `cfg` record: the feature layout (with `plane`, layout 3) and the voxel
    settings."""
    version = PLANE_VERSION if plane else FEATURE_VERSION
    return {"features": LAYOUTS[version], "feature_version": version, **voxel_settings(cfg)}


def voxel_settings(cfg: LRGNetConfig) -> dict[str, Any]:
    """What a weights file must have been trained for to be used with `cfg` (besides a layout in LAYOUTS)."""
    return {"voxel_size_m": cfg.voxel_size_m, "delta_m": cfg.delta_m}


def load_network(cfg: LRGNetConfig, path: str | Path | None = None) -> LRGNet:
    net, _ = load_weights(path or cfg.weights or DEFAULT_WEIGHTS, voxel_settings(cfg), LAYOUTS)
    return net


def to_points(vc: VoxelCloud, voxels: np.ndarray) -> np.ndarray:
    """Indices of the raw points that fall in the given voxels."""
    mask = np.zeros(len(vc), bool)
    mask[voxels] = True
    return np.flatnonzero(mask[vc.voxel_of_point])


def refine_cloud(
    cloud: LabelledCloud,
    cfg: LRGNetConfig,
    record_object: int | None = None,
    net: LRGNet | None = None,
) -> RefineResult:
    """Re-segment `cloud` into objects by learnt region growing; `record_object` (an output id) keeps that
    object's growth, step by step, for the debugging timeline."""
    if len(cloud) == 0:
        raise InputError("the cloud has no points")
    try:
        Search(cfg.search)
    except ValueError:
        raise InputError(f"unknown search {cfg.search!r} (greedy, restart or beam)") from None
    net = net or load_network(cfg)
    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    vc = voxelise(cloud, cfg.voxel_size_m, cfg.delta_m)
    cfg = cfg.for_color(vc.color)  # growth and consolidation settings of the cloud's mode, as the Grower's
    vc.features = vc.features[:, : net.in_features]  # weights of an older layout read its first columns
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # thousands of small products: extra threads only add overhead (measured 20x slower)
    try:
        seg = Grower(vc, net, cfg).segment(record_object)
    finally:
        torch.set_num_threads(threads)
    labels = seg.labels
    mode = ModeSettings.of(cfg, vc.color)
    if mode.crease_angle_deg > 0:
        labels = split_creases(vc, labels, mode.crease_angle_deg, mode.crease_min_voxels)
    if mode.merge_angle_deg > 0:
        labels = merge_coplanar(vc, labels, mode.merge_angle_deg, mode.merge_offset_m)
    labels = attach_small_segments(vc.points, labels, cfg.min_segment_points)
    steps = None
    if seg.history is not None:
        steps = [(to_points(vc, inl), to_points(vc, nb)) for inl, nb in seg.history]
    return RefineResult(
        instance_ids=labels[vc.voxel_of_point].astype(np.uint32),
        steps=steps,
        steps_per_object=seg.steps_per_object,
        segments=len(np.unique(labels)),
        voxels=len(vc),
        seconds=time.perf_counter() - t0,
        color=vc.color,
        settings=cfg.model_dump(include=set(LRGNET_MODE_DEFAULTS[vc.color])),
    )


def baseline_cloud(cloud: LabelledCloud, name: str, cfg: LRGNetConfig, vc: VoxelCloud | None = None) -> RefineResult:
    """One of the classical baselines (`pipeline.refine.baselines`) on the same voxels as LRGNet."""
    from aftershock.pipeline.refine.baselines import run_baseline

    t0 = time.perf_counter()
    vc = vc or voxelise(cloud, cfg.voxel_size_m, cfg.delta_m)
    labels = run_baseline(name, cloud, vc, cfg)
    return RefineResult(
        instance_ids=labels[vc.voxel_of_point].astype(np.uint32),
        steps=None,
        segments=len(np.unique(labels)),
        voxels=len(vc),
        seconds=time.perf_counter() - t0,
        color=vc.color,
    )


def scores(true_ids: np.ndarray, pred_ids: np.ndarray) -> dict[str, float]:
    """NMI, AMI, ARI over points; precision, recall and mean IoU at IoU 0.5 with one-to-one matching."""
    from aftershock.pipeline.metrics import cluster_scores, instance_scores

    c = cluster_scores(true_ids, pred_ids)
    i = instance_scores(true_ids, pred_ids)
    return {
        "nmi": c.nmi,
        "ami": c.ami,
        "ari": c.ari,
        "precision": i.precision,
        "recall": i.recall,
        "mean_iou": i.mean_iou,
        "true_instances": i.true_instances,
        "predicted_instances": i.predicted_instances,
    }
