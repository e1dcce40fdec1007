"""PointNet segmentation network, the online baseline: one cloud (a scan, or the scans of the last 0.1 s or
0.5 m) in, a class and a unit embedding per point out. The global feature is pooled over each cloud on its
own (padding masked out), never over the batch.
"""

from __future__ import annotations

import torch
from torch import nn

from aftershock.models.layers import mlp
from aftershock.models.netconfig import NetConfig


class PointNet(nn.Module):
    """Per-point MLP, max-pool over the cloud, the global vector joined back to every point, two heads."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.local = mlp(cfg.point_dim, 64, 64)
        self.lift = mlp(64, 128, 256)
        self.head = mlp(64 + 256, 256, 128)
        self.embed = nn.Linear(128, cfg.embed_dim)
        self.classify = nn.Linear(128 + cfg.embed_dim, cfg.num_classes)

    def forward(self, points: torch.Tensor, mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """points (B, N, Fp); mask (B, N) True on real points. Returns embeddings (B, N, E), logits (B, N, C)."""
        local = self.local(points)
        lifted = self.lift(local)  # ReLU output >= 0, so masking to 0 keeps padding out of the max
        if mask is not None:
            lifted = lifted * mask.unsqueeze(-1).to(lifted.dtype)
        glob = lifted.amax(dim=1, keepdim=True).expand(-1, points.shape[1], -1)
        feat = self.head(torch.cat([local, glob], dim=-1))
        emb = nn.functional.normalize(self.embed(feat), dim=-1)
        return emb, self.classify(torch.cat([feat, emb], dim=-1))
