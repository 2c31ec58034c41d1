"""Shared pytest fixtures: the shared data folder, skipping with a clear reason when it is missing."""

from __future__ import annotations

from pathlib import Path

import pytest

from meshadv.data import DATA_ENV_VAR, shared_data_dir


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared data folder; the test is skipped when it is absent."""
    root = shared_data_dir()
    if root is None:
        pytest.skip(f"shared data not found (set {DATA_ENV_VAR} or provide ../shared/data)")
    return root
