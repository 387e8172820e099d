"""Shared fixtures: repository paths and the BROAD recordings (skipped with a clear message if absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
BROAD_DIR = Path(os.environ.get("RIG_BROAD_DIR") or REPO_ROOT.parent / "shared" / "data" / "broad")
"""BROAD folder for the tests: `RIG_BROAD_DIR` if set (any folder of BROAD-format trials), else ../shared/data/broad."""


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    """The BROAD recordings; skipped when absent, unless RIG_REQUIRE_BROAD=1 (CI), where absence fails."""
    if not any(BROAD_DIR.glob("*.mat")):
        msg = (f"BROAD recordings not found at {BROAD_DIR}: put the BROAD trials there (the 15 development trials "
               "are in ../shared/data/broad beside the repo; the dataset is https://github.com/dlaidig/broad, "
               "CC BY 4.0) or set RIG_BROAD_DIR=/path/to/folder")
        if os.environ.get("RIG_REQUIRE_BROAD") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return BROAD_DIR
