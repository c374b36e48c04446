"""Shared fixtures (shared helpers are in support.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from support import SPD_DIR


@pytest.fixture
def spd_dir() -> Path:
    """The directory of the reference SPD files (tests/data/spd, unpacked)."""
    return SPD_DIR
