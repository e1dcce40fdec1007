"""MCPNet: per-point class scores and instance embeddings from multi-view context pooled out of the voxel map.

Each new point is described by its own features (position relative to the robot, colour, a colour flag)
and by M context neighbours drawn from the global voxel map (points of earlier scans included), given as
differences to the point. A shared per-neighbour MLP and a max-pool give the context vector; joined to
the point's own features it yields a unit-length embedding (instances) and class scores.

Unlike the original, nothing is pooled over the batch: every output row depends on its own input row
only, so a point's label never changes with the points it is batched with.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final

import numpy as np
import torch
from torch import nn

from aftershock.models.layers import mlp
from aftershock.models.netconfig import (
    COARSE_CONTEXT_DIM,
    COARSE_GEOMETRY_FEATURES,
    CONTEXT_DIM,
    CONTEXT_FEATURES,
    GEOMETRY_FEATURES,
    LAYOUTS,
    POINT_DIM,
    POINT_FEATURES,
    STRUCTURE_FEATURES,
    NetConfig,
)
from aftershock.models.pointnet import PointNet
from aftershock.models.weights_file import WEIGHTS_DIR, read_weights
from aftershock.pipeline.classes import NETWORK_CLASSES
from aftershock.pipeline.errors import InputError

FORMAT: Final = "aftershock-mcpnet"
FORMAT_VERSION: Final = 1


class MCPNet(nn.Module):
    """Context pooling network; `use_context=False` is the same network without the context branch. With
    `cfg.coarse_points` a second, wider context (offsets only) is pooled by a small branch of its own."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.use_context = cfg.kind == "mcpnet"
        self.use_wide = self.use_context and cfg.coarse_points > 0
        if self.use_context:
            self.context_mlp = mlp(cfg.context_dim, w, w)
        if self.use_wide:
            self.wide_mlp = mlp(COARSE_CONTEXT_DIM, cfg.coarse_width, cfg.coarse_width)
        joined = cfg.point_dim + (w if self.use_context else 0) + (cfg.coarse_width if self.use_wide else 0)
        self.point_mlp = mlp(joined, w)
        self.embed = nn.Linear(w, cfg.embed_dim)
        self.classify = mlp(w + cfg.embed_dim, w, cfg.num_classes, last_relu=False)

    def branch(self, wide: bool) -> nn.Sequential:
        return self.wide_mlp if wide else self.context_mlp

    def pool_context(self, context: torch.Tensor, mask: torch.Tensor | None, wide: bool = False) -> torch.Tensor:
        """max over neighbours of the shared MLP, absent neighbours left out (0 when a point has none).

        max(relu(h)) = relu(max(h)), so the last ReLU runs on the pooled (B, W) rather than on (B, M, W);
        and absent neighbours are replaced by a present one of the same point, which leaves the max as it is."""
        if mask is not None and not bool(mask.all()):
            first = mask.to(torch.int8).argmax(dim=1)  # a present neighbour per point (0 when none)
            fill = context[torch.arange(len(context)), first].unsqueeze(1).expand_as(context)
            context = torch.where(mask.unsqueeze(-1), context, fill)
        lin1, relu1, lin2 = self.branch(wide)[0], self.branch(wide)[1], self.branch(wide)[2]
        pooled = torch.relu(lin2(relu1(lin1(context))).amax(dim=1))
        if mask is not None:
            pooled = pooled * mask.any(dim=1, keepdim=True).to(pooled.dtype)
        return pooled

    def pool_pairs(self, pairs: torch.Tensor, owner: torch.Tensor, num_points: int, wide: bool = False) -> torch.Tensor:
        """The context vectors (B, W) of `num_points` points from (point, neighbour) pairs: `pairs` (P, Fc)
        differences to the point, `owner` (P,) the point each pair belongs to (points without a pair get 0).

        The max over draws is the max over the distinct neighbours drawn, so giving each neighbour once
        yields `pool_context` of the draws with repeats, at the cost of the distinct ones only."""
        lin1, relu1, lin2 = self.branch(wide)[0], self.branch(wide)[1], self.branch(wide)[2]
        h = lin2(relu1(lin1(pairs)))
        pooled = torch.full((num_points, h.shape[1]), -torch.inf, dtype=h.dtype)
        pooled.scatter_reduce_(0, owner.unsqueeze(1).expand_as(h), h, reduce="amax", include_self=True)
        return torch.relu(pooled)  # relu(-inf) = 0 for points without context, as in `pool_context`

    def forward(
        self,
        point: torch.Tensor,
        context: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        wide: torch.Tensor | None = None,
        wide_mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """point (B, Fp); context (B, M, Fc) differences to the point; mask (B, M) True where a neighbour exists;
        wide (B, Mw, 3) and wide_mask (B, Mw) the wider context. Returns unit embeddings (B, E), logits (B, C)."""
        pooled = None
        if self.use_context:
            assert context is not None
            pooled = self.pool_context(context, mask)
        if self.use_wide:
            assert wide is not None and pooled is not None
            pooled = torch.cat([pooled, self.pool_context(wide, wide_mask, wide=True)], dim=1)
        return self.head(point, pooled)

    def head(self, point: torch.Tensor, pooled: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """Unit embeddings (B, E) and class logits (B, C) from the point features and pooled context (B, W)."""
        x = point if pooled is None else torch.cat([pooled, point], dim=1)
        feat = self.point_mlp(x)
        emb = nn.functional.normalize(self.embed(feat), dim=1)
        logits = self.classify(torch.cat([feat, emb], dim=1))
        return emb, logits


def num_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def default_weights(kind: str = "mcpnet") -> Path:
    return WEIGHTS_DIR / f"{kind.replace('-', '_')}.pt"


REBUILD_HINT: Final = "rebuild it with `aftershock train mcpnet --force`"
FLOOR_PERCENTILE: Final = 1.0


def save_weights(path: Path, model: nn.Module, cfg: NetConfig, figures: dict[str, Any]) -> None:
    """Weights plus a header (format, version, config, feature layout, training figures)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(torch.float32).clone() for k, v in model.state_dict().items()}
    torch.save(
        {"format": FORMAT, "version": FORMAT_VERSION, "config": cfg.to_dict(), "figures": figures, "state": state},
        path,
    )


def load_header(path: str | Path) -> dict[str, Any]:
    """The raw contents of a weights file, checked for format and version; InputError naming the file if not."""
    p = Path(path)
    blob = read_weights(p, "MCPNet", REBUILD_HINT)
    if blob.get("format") != FORMAT:
        raise InputError(f"not an aftershock MCPNet weights file; {REBUILD_HINT}", p)
    if blob.get("version") != FORMAT_VERSION:
        raise InputError(f"weights format version {blob.get('version')} != {FORMAT_VERSION}; {REBUILD_HINT}", p)
    return blob


def load_model(path: str | Path, kind: str | None = None) -> tuple[nn.Module, NetConfig, dict[str, Any]]:
    """A network ready for inference from a weights file; refuses files of another kind or feature layout."""
    blob = load_header(path)
    try:
        cfg = NetConfig.from_dict(blob["config"])
    except (TypeError, KeyError, AttributeError, ValueError) as exc:
        raise InputError(f"weights header does not match this version ({exc}); {REBUILD_HINT}", path) from None
    if kind is not None and cfg.kind != kind:
        raise InputError(f"weights are for {cfg.kind!r}, expected {kind!r}; {REBUILD_HINT}", path)
    known = LAYOUTS.get(cfg.kind, ())
    wide_ok = (cfg.coarse_points > 0) == any(f in cfg.features for f in COARSE_GEOMETRY_FEATURES)
    if (
        cfg.features not in known
        or cfg.context_features != CONTEXT_FEATURES
        or cfg.point_dim != len(cfg.features)
        or not wide_ok
    ):
        raise InputError(
            f"weights use feature layout {list(cfg.features)}, this version runs "
            f"{' or '.join(str(list(k)) for k in known)}; {REBUILD_HINT}",
            path,
        )
    if cfg.num_classes != NETWORK_CLASSES:
        raise InputError(
            f"weights predict {cfg.num_classes} classes, the networks predict {NETWORK_CLASSES}; {REBUILD_HINT}", path
        )
    model: nn.Module = PointNet(cfg) if cfg.kind == "pointnet" else MCPNet(cfg)
    try:
        model.load_state_dict(blob["state"])
    except (RuntimeError, KeyError) as exc:
        raise InputError(f"weights do not fit the network ({str(exc).splitlines()[0]}); {REBUILD_HINT}", path) from None
    model.eval()
    return model, cfg, blob.get("figures", {})


def load_mcpnet(path: str | Path, kind: str = "mcpnet") -> tuple[MCPNet, NetConfig, dict[str, Any]]:
    """`load_model` for a kind of MCPNet (with context or without): the network as an MCPNet."""
    model, cfg, figures = load_model(path, kind=kind)
    if not isinstance(model, MCPNet):
        raise InputError(f"weights are for {cfg.kind!r}, not an MCPNet; {REBUILD_HINT}", path)
    return model, cfg, figures


def floor_height(world_points: np.ndarray) -> float:
    """The scan's floor: a low percentile of the whole scan's heights (robust to a few stray returns). One
    function for training and labelling, so that height above the floor means the same in both."""
    if not len(world_points):
        return 0.0
    return float(np.percentile(world_points[:, 2], FLOOR_PERCENTILE))


def point_features(positions: np.ndarray, colors: np.ndarray | None, origin: np.ndarray, floor_z: float) -> np.ndarray:
    """(N, 7) float32: x, y relative to the robot (`origin` (3,) or (N, 3)), z relative to the floor,
    colour in [-0.5, 0.5], colour flag."""
    n = len(positions)
    out = np.zeros((n, POINT_DIM), np.float32)
    out[:, 0:2] = positions[:, 0:2] - origin[..., 0:2]
    out[:, 2] = positions[:, 2] - floor_z
    if colors is not None:
        out[:, 3:6] = colors.astype(np.float32) / 255.0 - 0.5
        out[:, 6] = 1.0
    return out


def geometry_features(offsets: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(K, 5) float32 local shape from context offsets (K, M, 3) (neighbour minus point) and their mask (K, M):
    |n_z| of the least-variance direction (1 on floors, 0 on walls), planarity, linearity and sphericity from
    the sorted covariance eigenvalues, and the standard deviation of heights. Zero where fewer than three
    neighbours exist. Vectorised: one batched 3 x 3 eigen-decomposition."""
    k = len(offsets)
    out = np.zeros((k, len(GEOMETRY_FEATURES)), np.float32)
    w = mask.astype(np.float64)
    n = w.sum(axis=1)
    ok = n >= 3
    if not ok.any():
        return out
    x = offsets[ok].astype(np.float64)
    w, n = w[ok], n[ok]
    mean = (x * w[..., None]).sum(1) / n[:, None]
    d = (x - mean[:, None, :]) * w[..., None]
    cov = np.einsum("kmi,kmj->kij", d, d) / n[:, None, None]
    vals, vecs = np.linalg.eigh(cov + np.eye(3) * 1e-9)  # ascending
    l3, l2, l1 = vals[:, 0], vals[:, 1], np.maximum(vals[:, 2], 1e-12)
    out[ok, 0] = np.abs(vecs[:, 2, 0])
    out[ok, 1] = (l2 - l3) / l1
    out[ok, 2] = (l1 - l2) / l1
    out[ok, 3] = l3 / l1
    out[ok, 4] = np.sqrt(np.maximum(cov[:, 2, 2], 0.0)) / 0.1  # in voxels of 0.1 m
    return out


def wide_geometry_features(offsets: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(K, 7) float32: `geometry_features` of the wider context, then the highest and lowest neighbour relative
    to the point (metres; zero without neighbours)."""
    out = np.zeros((len(offsets), len(COARSE_GEOMETRY_FEATURES)), np.float32)
    out[:, :5] = geometry_features(offsets, mask)
    dz = offsets[..., 2]
    has = mask.any(axis=1)
    out[has, 5] = np.where(mask, dz, -np.inf).max(axis=1)[has]
    out[has, 6] = np.where(mask, dz, np.inf).min(axis=1)[has]
    return out


def point_inputs(
    cfg: NetConfig,
    base: np.ndarray,
    offsets: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    wide_offsets: np.ndarray | None = None,
    wide_mask: np.ndarray | None = None,
    structure: np.ndarray | None = None,
) -> np.ndarray:
    """The network's point features (K, len(cfg.features)) in the weights' layout, from the base features
    (K, 7) of `point_features`, the offsets (K, M, >=3) and masks of the context and the wider context, and the
    structure model's evidence (K, 4) in STRUCTURE_FEATURES order (pipeline.structure.features)."""
    cols = dict(zip(POINT_FEATURES, base.T, strict=True))
    if cfg.structure:
        assert structure is not None, "these weights read the structure model's features"
        cols.update(zip(STRUCTURE_FEATURES, np.asarray(structure, np.float32).T, strict=True))
    if any(f in cfg.features for f in GEOMETRY_FEATURES):
        assert offsets is not None and mask is not None
        cols.update(zip(GEOMETRY_FEATURES, geometry_features(offsets[..., 0:3], mask).T, strict=True))
    if any(f in cfg.features for f in COARSE_GEOMETRY_FEATURES):
        assert wide_offsets is not None and wide_mask is not None
        wide = wide_geometry_features(wide_offsets[..., 0:3], wide_mask)
        cols.update(zip(COARSE_GEOMETRY_FEATURES, wide.T, strict=True))
    return np.ascontiguousarray(np.stack([cols[f] for f in cfg.features], axis=1), dtype=np.float32)


def row_offsets(positions: np.ndarray, rows: np.ndarray, ctx_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (K, M, 3) float32 of drawn context rows (K, M, -1 where none) to map rows (K,), and their mask."""
    mask = ctx_rows >= 0
    safe = np.where(mask, ctx_rows, rows[:, None])
    return (positions[safe] - positions[rows][:, None, :]).astype(np.float32), mask


def point_inputs_of_rows(
    cfg: NetConfig,
    base: np.ndarray,
    positions: np.ndarray,
    rows: np.ndarray,
    ctx_rows: np.ndarray,
    wide_rows: np.ndarray | None,
    structure: np.ndarray | None = None,
) -> np.ndarray:
    """`point_inputs` from map rows (K,), their drawn context rows (K, M) and wider context rows (K, Mw), and the
    structure model's evidence (K, 4) where the weights read it."""
    if not cfg.geometry:
        return point_inputs(cfg, base, structure=structure)
    offsets, mask = row_offsets(positions, rows, ctx_rows)
    wide, wide_mask = row_offsets(positions, rows, wide_rows) if wide_rows is not None else (None, None)
    return point_inputs(cfg, base, offsets, mask, wide, wide_mask, structure)


def context_features(
    positions: np.ndarray,
    colors: np.ndarray | None,
    rows: np.ndarray,
    ctx_rows: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Context of map rows `rows` (K,) from neighbour rows `ctx_rows` (K, M, -1 where none):
    (K, M, 6) float32 differences to the point and a (K, M) bool mask. Colours zero when `colors` is None."""
    mask = ctx_rows >= 0
    safe = np.where(mask, ctx_rows, rows[:, None])
    ctx = np.zeros((*ctx_rows.shape, CONTEXT_DIM), np.float32)
    ctx[..., 0:3] = positions[safe] - positions[rows][:, None, :]
    if colors is not None:
        c = colors.astype(np.float32) / 255.0
        ctx[..., 3:6] = c[safe] - c[rows][:, None, :]
    return ctx, mask


_MIX1: Final = np.uint64(0xBF58476D1CE4E5B9)
_MIX2: Final = np.uint64(0x94D049BB133111EB)
_GOLDEN: Final = np.uint64(0x9E3779B97F4A7C15)


def context_draws(voxel_keys: np.ndarray, num: int) -> np.ndarray:
    """(K, num) uniform numbers in [0, 1) hashed (splitmix64) from each voxel's key: which context points a
    voxel draws depends on the voxel and the map only, never on the other voxels predicted with it."""
    k = np.asarray(voxel_keys, dtype=np.int64).astype(np.uint64)
    with np.errstate(over="ignore"):
        z = k[:, None] * np.uint64(num) + np.arange(num, dtype=np.uint64)[None, :] + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)
