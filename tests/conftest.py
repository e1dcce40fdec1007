"""Shared fixtures: where the real data lives, and a scratch folder per test."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# ../shared/data beside the checkout; AFTERSHOCK_SHARED_DATA names it for a checkout elsewhere (a worktree)
SHARED_DATA = Path(os.environ.get("AFTERSHOCK_SHARED_DATA", REPO.parent / "shared" / "data"))

os.environ.setdefault("CI", "true")  # keeps the rerun CLI from asking about analytics
os.environ.setdefault("RERUN_ANALYTICS", "0")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data; CI always has it beside the clone, a bare clone may not."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside this checkout")
    return SHARED_DATA


@pytest.fixture(scope="session")
def lidar_dir(shared_data: Path) -> Path:
    return shared_data / "lidar"


@pytest.fixture(scope="session")
def crack_dir(shared_data: Path) -> Path:
    return shared_data / "crack"
