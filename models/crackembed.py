"""CrackEmbed: a small point network over each point and its neighbours that maps points of one surface close
together and points of different surfaces (an intact face, a crack's inner faces, a spall) far apart.
An anomaly detector over these embeddings then finds the crack points; no crack label is used in training.

Inputs, all in fixed ranges (the original fed 0..255 colours to a network trained on [-0.5, 0.5]):
- per neighbour (K nearest within a radius of max(`neighbourhood_m`, 3 × spacing)): offset / radius (3),
  colour difference to the centre point (3, colours in [-0.5, 0.5]), inside-radius flag (1);
- the point itself: colour minus the element's median colour (3).
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
import torch
from torch import nn

from aftershock.models.weights_file import WEIGHTS_DIR, read_weights
from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import LabelledCloud

NEIGHBOURS: Final = 16
EMBED_DIM: Final = 16
WEIGHTS: Final = WEIGHTS_DIR / "crackembed.pt"
_MAGIC: Final = "crackembed-v1"
_CHUNK: Final = 32768


class CrackEmbed(nn.Module):
    """Shared MLP over neighbours (7 → 32 → 64), max-pooled, joined with the point's own colour → 64 → 16,
    L2-normalised. About 8 k parameters."""

    def __init__(self, dim: int = EMBED_DIM) -> None:
        super().__init__()
        self.local = nn.Sequential(nn.Linear(7, 32), nn.ReLU(), nn.Linear(32, 64), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(64 + 3, 64), nn.ReLU(), nn.Linear(64, dim))

    def forward(self, neighbours: torch.Tensor, own: torch.Tensor) -> torch.Tensor:
        """neighbours (B, K, 7), own (B, 3) -> unit embeddings (B, dim). Each point independently of its batch."""
        pooled = self.local(neighbours).max(dim=1).values
        return nn.functional.normalize(self.head(torch.cat([pooled, own], dim=1)), dim=1)


def point_inputs(
    points: np.ndarray, colors: np.ndarray, neighbourhood_m: float, spacing_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Network inputs of every point: (N, K, 7) neighbour features and (N, 3) own features.
    `colors` are uint8 (N, 3)."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    rgb = np.asarray(colors, np.float32) / 255.0 - 0.5
    radius = max(neighbourhood_m, 3.0 * spacing_m)
    k = min(NEIGHBOURS, len(pts))
    dist, idx = cKDTree(pts).query(pts, k=k, workers=-1)
    dist, idx = dist.reshape(len(pts), k), idx.reshape(len(pts), k)
    inside = dist <= radius
    idx = np.where(inside, idx, np.arange(len(pts))[:, None])  # outside the radius: the point itself
    offset = ((pts[idx] - pts[:, None, :]) / radius).astype(np.float32)
    dcol = rgb[idx] - rgb[:, None, :]
    nb = np.concatenate([offset, dcol, inside[..., None].astype(np.float32)], axis=2)
    if k < NEIGHBOURS:
        nb = np.concatenate([nb, np.repeat(nb[:, :1], NEIGHBOURS - k, axis=1)], axis=1)
    own = rgb - np.median(rgb, axis=0)
    return nb, own.astype(np.float32)


def save_weights(model: CrackEmbed, path: Path, meta: dict) -> None:
    torch.save({"magic": _MAGIC, "state": model.state_dict(), "meta": meta}, path)


def load_model(path: str | Path | None = None) -> CrackEmbed:
    p = Path(path) if path is not None else WEIGHTS
    blob = read_weights(p, "CrackEmbed", "rebuild it with `aftershock train crackembed --force`")
    if blob.get("magic") != _MAGIC:
        raise InputError("not a CrackEmbed weights file", p)
    model = CrackEmbed()
    model.load_state_dict(blob["state"])
    return model.eval()


def embed_points(model: CrackEmbed, points: np.ndarray, colors: np.ndarray, neighbourhood_m: float) -> np.ndarray:
    """(N, EMBED_DIM) float32 embeddings, computed in batches without gradients."""
    from aftershock.pipeline.geometry import point_spacing

    nb, own = point_inputs(points, colors, neighbourhood_m, point_spacing(points))
    out = np.empty((len(points), EMBED_DIM), np.float32)
    with torch.no_grad():
        for s in range(0, len(points), _CHUNK):
            out[s : s + _CHUNK] = model(torch.from_numpy(nb[s : s + _CHUNK]), torch.from_numpy(own[s : s + _CHUNK]))
    return out


def embed(cloud: LabelledCloud, cfg: CrackConfig) -> np.ndarray:
    """Feature-registry entry: CrackEmbed embeddings of a cloud with the configured weights."""
    if cloud.colors is None:
        raise InputError("the cloud has no colour, which CrackEmbed needs")
    return embed_points(load_model(cfg.weights), cloud.points, cloud.colors, cfg.neighbourhood_m)
