"""The commands of `aftershock`, one module each, wired into the app in `pipeline/cli.py`; here only the
options several commands share (one definition each, so their flags and help read alike)."""

from __future__ import annotations

from typing import Any, Final

import typer

from aftershock.pipeline.label import FALLBACK_LABELLER, LABELLERS

LABELLER_HELP: Final = (
    f"One of: {', '.join(LABELLERS)}. Default mcpnet; the {FALLBACK_LABELLER} baseline if its weights are missing."
)

# Options of the commands that open a log (run, eval, batch): use as defaults, e.g. `topic: str | None = TOPIC`.
LABELLER: Final[Any] = typer.Option(None, "--labeller", help=LABELLER_HELP)
CONFIG: Final[Any] = typer.Option(None, "--config", help="TOML or JSON config file.")
OVERRIDES: Final[Any] = typer.Option(None, "--set", help="Config override section.key=value.")
TOPIC: Final[Any] = typer.Option(None, "--topic", help="Point-cloud topic (default: the only one).")
START: Final[Any] = typer.Option(None, "--start", help="Seconds from the log start to begin at.")
END: Final[Any] = typer.Option(None, "--end", help="Seconds from the log start to stop at.")
EVERY: Final[Any] = typer.Option(None, "--every", help="Use every N-th scan.")
MAX_SCANS: Final[Any] = typer.Option(None, "--max-scans", help="Stop after this many scans.")
