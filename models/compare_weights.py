"""Rebuilt weights against the shipped ones, file by file: tensor for tensor, or how far apart.

`python -m aftershock.models.compare_weights SHIPPED_DIR REBUILT_DIR` (what `make train` ends with) prints one line
per weights file found in both folders. Equal tensors mean the recipe reproduces the file exactly; otherwise the
largest difference and its size against the weights' own scale say whether it is rounding or another network
(the benches' validation figures decide whether another network is as good).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Final

import torch

from aftershock.models.weights_file import read_weights
from aftershock.pipeline.errors import InputError

# Where each weights format keeps its tensors: MCPNet/PointNet "state", LRGNet "state_dict", CrackEmbed "state".
STATE_KEYS: Final = ("state_dict", "state")


def tensors(path: Path) -> dict[str, torch.Tensor]:
    """The named tensors of a weights file of any of the project's formats."""
    blob = read_weights(path, "aftershock", "rebuild it with `make train`")
    for key in STATE_KEYS:
        if isinstance(blob.get(key), dict):
            return {name: t for name, t in blob[key].items() if isinstance(t, torch.Tensor)}
    raise InputError("no tensors found: not an aftershock weights file", path)


def compare(shipped: Path, rebuilt: Path) -> str:
    """One line: `same` (every tensor equal), or the largest absolute difference relative to the largest weight."""
    a, b = tensors(shipped), tensors(rebuilt)
    if a.keys() != b.keys() or any(a[k].shape != b[k].shape for k in a):
        return "another layout (names or shapes differ)"
    if all(torch.equal(a[k], b[k]) for k in a):
        return f"same, tensor for tensor ({sum(t.numel() for t in a.values()):,} values)"
    diffs = [(a[k].float() - b[k].float()).abs().max().item() for k in a if a[k].numel()]
    scale = max((t.float().abs().max().item() for t in a.values() if t.numel()), default=0.0)
    changed = sum(not torch.equal(a[k], b[k]) for k in a)
    largest = max(diffs, default=0.0)
    return f"differs: {changed} of {len(a)} tensors, largest difference {largest:.3g} (largest weight {scale:.3g})"


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m aftershock.models.compare_weights SHIPPED_DIR REBUILT_DIR", file=sys.stderr)
        return 2
    shipped_dir, rebuilt_dir = (Path(p) for p in argv)
    rebuilt = sorted(rebuilt_dir.glob("*.pt"))
    if not rebuilt:
        print(f"{rebuilt_dir}: no weights files to compare", file=sys.stderr)
        return 2
    status = 0
    for path in rebuilt:
        ref = shipped_dir / path.name
        try:
            print(f"{path.name}: " + (compare(ref, path) if ref.is_file() else "no shipped file of that name"))
        except InputError as exc:  # one line naming the file, and the other files still compared
            print(f"{path.name}: {exc}", file=sys.stderr)
            status = 2
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
