"""The commands of `aftershock`, one module each, wired into the app in `pipeline/cli.py`; here only the
help texts several commands share."""

from __future__ import annotations

from typing import Final

from aftershock.pipeline.label import FALLBACK_LABELLER, LABELLERS

LABELLER_HELP: Final = (
    f"One of: {', '.join(LABELLERS)}. Default mcpnet; the {FALLBACK_LABELLER} baseline if its weights are missing."
)
