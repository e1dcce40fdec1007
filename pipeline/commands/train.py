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
    module = importlib.import_module(f"aftershock.models.{model.value}_train")
    figures = module.train(out=out, seed=seed, epochs=epochs, force=force)
    if as_json:
        print(json.dumps(figures, indent=2))
    else:
        for key, value in figures.items():
            print(f"{key}: {value}")
