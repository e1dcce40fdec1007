"""PointNet applied online, the study's baselines: the network sees one cloud per scan and labels the voxels
the scan opened. Three ways to form that cloud (the labeller's name picks one):

- `pointnet`: the voxels the current scan hit, alone;
- `pointnet-temporal`: with those of the scans of the last 0.1 s (temporal expansion);
- `pointnet-spatial`: with those of the recent scans taken within 0.5 m of here (spatial expansion).

Instances come from the same clustering as MCPNet's: PointNet has an embedding head trained with the same
triplet loss, and neighbouring voxels link when their embeddings' cosine similarity exceeds β.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Final

import numpy as np
import torch

from aftershock.models.mcpnet import default_weights, floor_height, load_model, point_features
from aftershock.pipeline.config import Config, Environment
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import VoxelMap

MODES: Final[dict[str, str]] = {"pointnet": "single", "pointnet-temporal": "temporal", "pointnet-spatial": "spatial"}
TEMPORAL_WINDOW_S: Final = 0.1
SPATIAL_WINDOW_M: Final = 0.5
HISTORY: Final = 200  # scans remembered for the expansions


class PointNetLabeller:
    """The `Labeller` of `pipeline.label` backed by the PointNet baseline."""

    def __init__(self, link_beta: float, name: str = "pointnet", weights: str | Path | None = None) -> None:
        if name not in MODES:
            raise ValueError(f"unknown PointNet mode {name!r}")
        self.name = name
        self.mode = MODES[name]
        self.model, self.net, _ = load_model(Path(weights or default_weights("pointnet")), kind="pointnet")
        # Batches of a few dozen voxels: a second intra-op thread only waits (10-20x slower on a busy machine).
        torch.set_num_threads(1)
        self.embedding_dim = self.net.embed_dim
        self.beta = link_beta  # embeddings this similar link two voxels
        self.history: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=HISTORY)

    def cloud_rows(self, rows: np.ndarray, stamp_s: float, origin: np.ndarray) -> np.ndarray:
        """The rows PointNet sees for the current scan (its own rows first, then the expansion's)."""
        if self.mode == "single" or not self.history:
            return rows
        if self.mode == "temporal":
            extra = [r for t, _, r in self.history if t >= stamp_s - TEMPORAL_WINDOW_S - 1e-6]
        else:
            extra = [r for _, o, r in self.history if np.hypot(*(o[:2] - origin[:2])) <= SPATIAL_WINDOW_M]
        if not extra:
            return rows
        others = np.setdiff1d(np.concatenate(extra), rows)
        return np.r_[rows, others]

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> None:
        origin = frame.pose[:3, 3] if frame.pose is not None else np.zeros(3)
        world = frame.world_points if frame.world_points is not None else np.zeros((0, 3))
        if frame.map_rows is not None:
            rows = np.unique(frame.map_rows.rows).astype(np.int64)
        else:
            rows = vmap.lookup_points(world)
            rows = np.unique(rows[rows >= 0]).astype(np.int64)
        cloud = self.cloud_rows(rows, frame.scan.stamp_s, origin)
        colors = vmap.colors[cloud] if frame.scan.colors is not None else None
        feats = point_features(vmap.positions[cloud], colors, origin, floor_height(world))
        with torch.inference_mode():
            emb, logits = self.model(torch.from_numpy(feats)[None])
            prob = torch.softmax(logits[0], dim=1)
            best, cls = prob.max(dim=1)
        where = np.searchsorted(rows, new_rows)  # new rows are among the scan's own rows, the first of `cloud`
        vmap.class_ids[new_rows] = cls.numpy()[where].astype(np.uint16)
        vmap.scores[new_rows] = best.numpy()[where]
        vmap.embeddings[new_rows] = emb[0].numpy()[where]
        self.history.append((frame.scan.stamp_s, origin.copy(), rows))

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        ea, eb = vmap.embeddings[rows_a], vmap.embeddings[rows_b]
        return np.einsum("ij,ij->i", ea, eb) > self.beta

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        """PointNet keeps each voxel's own class (no instance votes)."""


def create(cfg: Config, name: str = "pointnet", environment: Environment = Environment.INDOOR) -> PointNetLabeller:
    return PointNetLabeller(cfg.cluster.link_beta(environment), name if name in MODES else "pointnet")
