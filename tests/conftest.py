"""Shared fixtures. Tests that need ../shared/data skip with a clear reason when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("KDFACES_SHARED_DATA", ROOT.parent / "shared" / "data"))
LLF_TAKE = SHARED_DATA / "livelinkface" / "alex_rom_3.csv"


@pytest.fixture(scope="session")
def default_rig():
    from kdfaces import load_default_rig

    return load_default_rig()


@pytest.fixture(scope="session")
def llf_take_path():
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE} (shared data is optional)")
    return LLF_TAKE
