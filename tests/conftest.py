"""Shared fixtures: the real reference data folder and simulated projects (generated once per session)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")).resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; tests that need it skip with a reason when it is absent."""
    d = shared_data_dir()
    if not d.is_dir():
        pytest.skip(f"real reference data not found at {d} (set AEROTRI_SHARED_DATA)")
    return d


@pytest.fixture(scope="session")
def tiny_project(tmp_path_factory) -> Path:
    """A simulated ``tiny`` project (generated once per test session; treat it as read-only)."""
    from aerotri.sim import load_preset, simulate

    out = tmp_path_factory.mktemp("sim") / "tiny"
    simulate(load_preset("tiny"), out)
    return out
