"""Shared fixtures."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    """A seeded random generator (no module-level seeding)."""
    return np.random.default_rng(20240209)
