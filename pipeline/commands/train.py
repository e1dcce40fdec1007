"""`aftershock train MODEL`: reproduce the shipped weights from simulator data on a CPU, seeded."""

from __future__ import annotations

import importlib
import json
from enum import StrEnum
from pathlib import Path

import typer


class Model(StrEnum):
    MCPNET = "mcpnet"
    LRGNET = "lrgnet"
    CRACKEMBED = "crackembed"


def train(
    model: Model = typer.Argument(..., help="Which network to train."),
    out: Path | None = typer.Option(None, help="Weights file to write (default: the shipped one)."),
    seed: int = typer.Option(0, help="Seed for data generation and training."),
    epochs: int | None = typer.Option(None, help="Override the number of epochs (default: as shipped)."),
    force: bool = typer.Option(False, help="Overwrite an existing weights file."),
    as_json: bool = typer.Option(False, "--json", help="Print the training figures as JSON."),
) -> None:
    """Train a network from simulated missions and write its weights."""
    from aftershock.pipeline.errors import InputError

    if epochs is not None and epochs < 1:
        raise InputError(f"--epochs {epochs}: training takes at least one epoch")
    if not 0 <= seed <= 2**32 - 1:
        raise InputError(f"--seed {seed}: a seed is between 0 and {2**32 - 1} (numpy and torch take 32-bit seeds)")
    module = importlib.import_module(f"aftershock.models.{model.value}_train")
    figures = module.train(out=out, seed=seed, epochs=epochs, force=force)
    if as_json:
        print(json.dumps(figures, indent=2))
    else:
        for key, value in figures.items():
            print(f"{key}: {value}")
