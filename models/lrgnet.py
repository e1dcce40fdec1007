"""LRGNet: a learnable step of region growing.

Two point branches (the region's inliers and its neighbours), each a shared MLP F→64→64→64→128→512 (F = 18 inputs
in feature layout 3, 16 or 13 in older files; the widths are recorded in the weights header) with a
max-pooled global feature; the two global features joined (1024) go back to every point together with the
point's own 64-wide second-layer feature (1088) into a head 256→128→2: one head says which inliers to remove,
the other which neighbours to add. No normalisation layers, so a point's output depends only on itself and
the two pooled features; inference can therefore pool over a sample and then decide for every candidate.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any, Final, cast

import torch
from torch import nn
from torch.nn import functional as F

from aftershock.models.weights_file import read_weights
from aftershock.pipeline.errors import InputError

BRANCH_WIDTHS: Final = (64, 64, 64, 128, 512)
HEAD_WIDTHS: Final = (256, 128, 2)
LOCAL_LAYER: Final = 1  # the per-point feature handed to the head: output of the second layer (64 wide)
FORMAT: Final = "aftershock-lrgnet"
FORMAT_VERSION: Final = 1
REBUILD_HINT: Final = "rebuild it with `aftershock train lrgnet --force`"


class Branch(nn.Module):
    """Shared per-point MLP; returns the per-point local feature (64 wide as shipped) and the max-pooled global one."""

    def __init__(self, in_features: int, branch_widths: tuple[int, ...] = BRANCH_WIDTHS) -> None:
        super().__init__()
        widths = (in_features, *branch_widths)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(widths))

    def local(self, x: torch.Tensor) -> torch.Tensor:
        """Only the per-point local feature (the first layers), for deciding on many points."""
        for layer in self.layers[: LOCAL_LAYER + 1]:
            x = F.relu(layer(x))
        return x

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        local = x
        for i, layer in enumerate(self.layers):
            x = F.relu(layer(x))
            if i == LOCAL_LAYER:
                local = x
        return local, x.max(dim=-2).values


class Head(nn.Module):
    """[global 1024 ; local 64] → 256 → 128 → 2. The first layer is applied as W_g·g + W_l·l (the same
    product as on the joined vector) so the global part is computed once per region, not once per point."""

    def __init__(self, global_width: int, local_width: int, head_widths: tuple[int, ...] = HEAD_WIDTHS) -> None:
        super().__init__()
        widths = (global_width + local_width, *head_widths)
        self.global_width = global_width
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(widths))

    def forward(self, global_feature: torch.Tensor, local: torch.Tensor) -> torch.Tensor:
        first = cast(nn.Linear, self.layers[0])  # a ModuleList indexes as Module
        g = F.linear(global_feature, first.weight[:, : self.global_width], first.bias)  # (B, 256)
        x = F.relu(F.linear(local, first.weight[:, self.global_width :]) + g.unsqueeze(-2))
        for layer in self.layers[1:-1]:
            x = F.relu(layer(x))
        return self.layers[-1](x)


class LRGNet(nn.Module):
    """Inputs (B, I, F) inliers and (B, J, F) neighbours; outputs remove logits (B, I, 2), add logits (B, J, 2)."""

    def __init__(
        self,
        in_features: int = 16,
        branch_widths: tuple[int, ...] = BRANCH_WIDTHS,
        head_widths: tuple[int, ...] = HEAD_WIDTHS,
    ) -> None:
        super().__init__()
        self.in_features = in_features
        self.branch_widths, self.head_widths = tuple(branch_widths), tuple(head_widths)
        self.inlier_branch = Branch(in_features, self.branch_widths)
        self.neighbour_branch = Branch(in_features, self.branch_widths)
        width = 2 * self.branch_widths[-1]
        self.remove_head = Head(width, self.branch_widths[LOCAL_LAYER], self.head_widths)
        self.add_head = Head(width, self.branch_widths[LOCAL_LAYER], self.head_widths)

    def encode(self, inliers: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        """The joined global feature (B, 1024) of a region's inlier and neighbour samples."""
        _, gi = self.inlier_branch(inliers)
        _, gn = self.neighbour_branch(neighbours)
        return torch.cat([gi, gn], dim=-1)

    def remove_logits(self, global_feature: torch.Tensor, inliers: torch.Tensor) -> torch.Tensor:
        return self.remove_head(global_feature, self.inlier_branch.local(inliers))

    def add_logits(self, global_feature: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        return self.add_head(global_feature, self.neighbour_branch.local(neighbours))

    def forward(self, inliers: torch.Tensor, neighbours: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        li, gi = self.inlier_branch(inliers)
        ln, gn = self.neighbour_branch(neighbours)
        g = torch.cat([gi, gn], dim=-1)
        return self.remove_head(g, li), self.add_head(g, ln)


def num_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


def save_weights(path: Path, net: LRGNet, settings: dict[str, Any], figures: dict[str, Any]) -> None:
    """Weights with a header recording the settings they were trained for."""
    sizes = {"branch_widths": list(net.branch_widths), "head_widths": list(net.head_widths)}
    header = {"format": FORMAT, "version": FORMAT_VERSION, "settings": {**settings, **sizes}, "figures": figures}
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    torch.save({"header": header, "state_dict": state}, path)


def load_weights(path: str | Path, expected: dict[str, Any], layouts: dict[int, int]) -> tuple[LRGNet, dict[str, Any]]:
    """Load weights and check their header against the settings in use and the feature layouts this version
    reads (`layouts`: feature version -> number of features); a mismatch is an InputError that names the file and
    how to rebuild it."""
    p = Path(path)
    blob = read_weights(p, "LRGNet", REBUILD_HINT)
    header = blob.get("header")
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise InputError(f"not an LRGNet weights file; {REBUILD_HINT}", p)
    if header.get("version") != FORMAT_VERSION:
        raise InputError(f"LRGNet weights format {header.get('version')} != {FORMAT_VERSION}; {REBUILD_HINT}", p)
    settings = header.get("settings", {})
    if not isinstance(settings, dict):
        raise InputError(f"not an LRGNet weights file: its settings are a {type(settings).__name__}; {REBUILD_HINT}", p)
    layout: tuple[Any, Any] = (settings.get("feature_version"), settings.get("features"))  # as the file has them
    if layouts.get(layout[0]) != layout[1]:
        known = ", ".join(f"{v} ({n} features)" for v, n in layouts.items())
        raise InputError(
            f"LRGNet weights of feature layout {layout[0]} ({layout[1]} features), this version reads {known}; "
            f"{REBUILD_HINT}",
            p,
        )
    wrong = {k: (settings.get(k), v) for k, v in expected.items() if settings.get(k) != v}
    if wrong:
        detail = ", ".join(f"{k}={a!r} (expected {b!r})" for k, (a, b) in wrong.items())
        raise InputError(f"LRGNet weights were trained for other settings: {detail}; {REBUILD_HINT}", p)
    # the layer widths are read from the header; files written before they were recorded have the shipped ones
    widths = settings.get("branch_widths", BRANCH_WIDTHS), settings.get("head_widths", HEAD_WIDTHS)
    try:
        net = LRGNet(int(layout[1]), *(tuple(int(w) for w in ws) for ws in widths))
        net.load_state_dict(blob["state_dict"])
    except (RuntimeError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"LRGNet weights do not fit the network ({exc}); {REBUILD_HINT}", p) from None
    net.eval()
    return net, header
