"""Shared fixtures: repository paths and the BROAD recordings (skipped with a clear message if absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
BROAD_DIR = REPO_ROOT.parent / "shared" / "data" / "broad"


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    if not BROAD_DIR.is_dir():
        pytest.skip(f"BROAD recordings not found at {BROAD_DIR} (expected ../shared/data/broad beside the repo)")
    return BROAD_DIR
