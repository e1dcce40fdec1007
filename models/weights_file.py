"""Where the shipped weights are, and reading a weights file: missing or unreadable files are user errors that
name the file and the fix."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Final

import torch

from aftershock.pipeline.errors import InputError

# Found through the package, so editable and wheel installs agree; wheels install unzipped, so this is a real
# folder (and `aftershock train ...` writes its default output there).
WEIGHTS_DIR: Final[Path] = Path(str(resources.files("aftershock.models") / "weights"))


def read_weights(path: str | Path, what: str, hint: str) -> dict[str, Any]:
    """The dict saved in `path`; InputError naming the file and `hint` (how to rebuild it) if it is missing,
    unreadable or not a dict. `what` names the weights in messages, e.g. "MCPNet"."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} weights file not found; {hint}", p)
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a damaged or foreign file
        raise InputError(f"not a readable {what} weights file ({type(exc).__name__}); {hint}", p) from None
    if not isinstance(blob, dict):
        raise InputError(f"not an aftershock {what} weights file; {hint}", p)
    for key in _STATE_KEYS & blob.keys():
        state = blob[key]
        if not isinstance(state, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
        ):
            raise InputError(f"not an aftershock {what} weights file: its {key} is not a table of tensors; {hint}", p)
        for name, tensor in state.items():  # a network of NaN labels nothing, silently
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
                raise InputError(f"{what} weights hold NaN or infinite values ({name}); {hint}", p)
    return blob


_STATE_KEYS: Final = frozenset({"state", "state_dict"})
