"""Fixtures shared by the bust tests (building and placement)."""
from __future__ import annotations

import pytest

from gpja.register.bust import Bust, make_bust


@pytest.fixture(scope="session")
def bust() -> Bust:
    """The default bust (~10K vertices; built once per test session, never modified)."""
    return make_bust()


@pytest.fixture(scope="session")
def small_bust() -> Bust:
    """A coarse, quickly built bust (~2.5K vertices)."""
    return make_bust(target_edge_mm=8.0, relax_iterations=5)
