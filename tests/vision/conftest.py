"""Fixtures of the vision tests (constants live in scenes.py)."""

from __future__ import annotations

import pytest

from cellctl.geometry.catalog import BoardSpec
from cellctl.messages import Intrinsics

from .scenes import INTR, SPEC_A, SPEC_B


@pytest.fixture
def catalog() -> dict[str, BoardSpec]:
    return {"bin_a": SPEC_A, "bin_b": SPEC_B}


@pytest.fixture
def intr() -> Intrinsics:
    return INTR
