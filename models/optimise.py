"""One gradient step, as every training loop here takes it."""

from __future__ import annotations

import torch
from torch.optim.lr_scheduler import LRScheduler


def descend(opt: torch.optim.Optimizer, loss: torch.Tensor, sched: LRScheduler | None = None) -> None:
    """Gradients of `loss`, one optimiser step, then one of the learning-rate schedule where there is one."""
    opt.zero_grad()
    loss.backward()
    opt.step()
    if sched is not None:
        sched.step()
