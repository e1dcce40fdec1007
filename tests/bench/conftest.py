"""Benchmarks: everything in this folder is slow (`make bench*` runs it with `-m slow`), and the held-out
simulated missions that MCPNet's and the objects' benchmarks share."""

from __future__ import annotations

from pathlib import Path
from typing import Final

import pytest
from common import BENCH_SEEDS, pickle_scans

from aftershock.models.mcpnet_train import FAMILIES, HELDOUT_SCANS, HELDOUT_SEEDS, SENSOR

HERE: Final = Path(__file__).resolve().parent


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects, so the mark counts
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if HERE in item.path.parents:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="module")
def heldout_missions(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Pickled scans of every held-out mission (both families, BENCH_SEEDS), simulated once per module."""
    root = tmp_path_factory.mktemp("heldout")
    paths = []
    for family in FAMILIES:
        for seed in BENCH_SEEDS:
            assert seed in HELDOUT_SEEDS, f"seed {seed} is not held out"
            uri = f"sim://{family}?seed={seed}&sensor={SENSOR}&scans={HELDOUT_SCANS}"
            paths.append(pickle_scans(uri, root / f"{family}_{seed}.pkl"))
    return paths
