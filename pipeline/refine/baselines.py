"""Classical segmentations that LRGNet is compared against, on the same voxels and with the same absorption of
small segments: region growing on normal and colour thresholds, the smoothness constraint of Rabbani et al.,
FPFH-similarity clustering, and clustering of MCPNet embeddings.

Each returns one segment id per voxel (1.., by size) of a `VoxelCloud`.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Final

import numpy as np

from aftershock.pipeline.config import LRGNetConfig
from aftershock.pipeline.geometry import (
    attach_small_segments,
    graph_components,
    smoothness_region_growing,
    threshold_region_growing,
)
from aftershock.pipeline.refine.features import NORMAL, VoxelCloud
from aftershock.pipeline.types import LabelledCloud

FPFH_RADIUS_VOXELS: Final = 2.5  # FPFH over ~0.25 m at 0.1 m voxels
FPFH_MAX_NN: Final = 50
NORMAL_RADIUS_VOXELS: Final = 1.8  # touching voxels, diagonals included (√3 ≈ 1.73)


class Baseline(StrEnum):
    THRESHOLD = "threshold"
    SMOOTHNESS = "smoothness"
    FPFH = "fpfh"
    MCPNET = "mcpnet"


def _edges(vc: VoxelCloud) -> np.ndarray:
    """Pairs (E, 2) of touching voxels, each once."""
    src = np.repeat(np.arange(len(vc)), vc.adjacency.shape[1])
    dst = vc.adjacency.ravel()
    keep = dst > src
    return np.stack([src[keep], dst[keep]], axis=1)


def similarity_components(vc: VoxelCloud, vectors: np.ndarray, min_similarity: float) -> np.ndarray:
    """Connected components of touching voxels whose vectors have cosine similarity ≥ `min_similarity`."""
    v = vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-12)
    e = _edges(vc)
    ok = np.einsum("ij,ij->i", v[e[:, 0]], v[e[:, 1]]) >= min_similarity
    e = e[ok]
    return graph_components(len(vc), e) + 1


def threshold_growing(cloud: LabelledCloud, vc: VoxelCloud, cfg: LRGNetConfig) -> np.ndarray:
    colors = None if cloud.colors is None else np.clip(vc.features[:, 6:9] * 255, 0, 255)
    return threshold_region_growing(
        vc.points,
        vc.features[:, NORMAL],
        colors,
        NORMAL_RADIUS_VOXELS * cfg.voxel_size_m,
        cfg.baseline_normal_angle_deg,
        cfg.baseline_color_distance if cloud.colors is not None else None,
    )


def smoothness_growing(cloud: LabelledCloud, vc: VoxelCloud, cfg: LRGNetConfig) -> np.ndarray:
    threshold = float(np.percentile(vc.curvature, cfg.smoothness_curvature_percentile))
    return smoothness_region_growing(
        vc.points, vc.features[:, NORMAL], vc.curvature, k=cfg.smoothness_k,
        max_angle_deg=cfg.smoothness_angle_deg, curvature_threshold=threshold,
    )  # fmt: skip


def fpfh_clustering(cloud: LabelledCloud, vc: VoxelCloud, cfg: LRGNetConfig) -> np.ndarray:
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vc.points))
    pcd.normals = o3d.utility.Vector3dVector(vc.features[:, NORMAL].astype(np.float64))
    search = o3d.geometry.KDTreeSearchParamHybrid(radius=FPFH_RADIUS_VOXELS * cfg.voxel_size_m, max_nn=FPFH_MAX_NN)
    # (M, 33); open3d's stub leaves out the default of `indices` (every point)
    fpfh = np.asarray(o3d.pipelines.registration.compute_fpfh_feature(pcd, search).data).T  # type: ignore[call-arg]
    return similarity_components(vc, fpfh, cfg.fpfh_similarity)


def mcpnet_clustering(cloud: LabelledCloud, vc: VoxelCloud, cfg: LRGNetConfig) -> np.ndarray:
    """Components over MCPNet's embeddings of the voxel points (the clustering stage's rule, β indoor)."""
    from aftershock.pipeline.config import Config, Environment
    from aftershock.pipeline.labellers.mcpnet import create

    vox = cloud.select(vc.first_point)
    vox.points = vc.points
    embeddings = create(Config(), environment=Environment.INDOOR).embed_cloud(vox)
    return similarity_components(vc, np.asarray(embeddings, np.float64), cfg.mcpnet_similarity)


BASELINES: Final[dict[Baseline, Callable[[LabelledCloud, VoxelCloud, LRGNetConfig], np.ndarray]]] = {
    Baseline.THRESHOLD: threshold_growing,
    Baseline.SMOOTHNESS: smoothness_growing,
    Baseline.FPFH: fpfh_clustering,
    Baseline.MCPNET: mcpnet_clustering,
}


def available() -> list[Baseline]:
    """The baselines this checkout can run (MCPNet's embedding needs its labeller)."""
    try:
        from aftershock.pipeline.labellers.mcpnet import MCPNetLabeller
    except ImportError:
        return [b for b in Baseline if b != Baseline.MCPNET]
    return list(Baseline) if hasattr(MCPNetLabeller, "embed_cloud") else [b for b in Baseline if b != Baseline.MCPNET]


def run_baseline(name: Baseline | str, cloud: LabelledCloud, vc: VoxelCloud, cfg: LRGNetConfig) -> np.ndarray:
    """Segment ids per voxel, small segments absorbed by their nearest large neighbour."""
    labels = BASELINES[Baseline(name)](cloud, vc, cfg)
    return attach_small_segments(vc.points, labels, cfg.min_segment_points)
