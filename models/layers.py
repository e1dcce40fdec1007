"""Building blocks shared by the networks."""

from __future__ import annotations

import itertools

from torch import nn


def mlp(*widths: int, last_relu: bool = True) -> nn.Sequential:
    """Linear layers of the given widths with a ReLU after each (after the last only when `last_relu`)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(itertools.pairwise(widths)):
        layers.append(nn.Linear(a, b))
        if last_relu or i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)
