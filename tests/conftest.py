"""Shared fixtures and the hypothesis profile."""

import contextlib
import os

import numpy as np
import pytest
from hypothesis import settings

# CI runs property tests derandomized (a fixed example sequence), so a green run is reproducible;
# locally hypothesis keeps exploring new examples.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture
def rng():
    """A seeded random generator (no module-level seeding)."""
    return np.random.default_rng(20240209)


@contextlib.contextmanager
def loopback_cluster(n_workers=2):
    """A real Dask cluster of worker processes on the loopback, closed on exit (idle workers use CPU).

    ":0": the scheduler's HTTP server takes a free port (None still binds 8787, and two test processes
    starting clusters at once then collide on it).
    """
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address="127.0.0.1:0")
    try:
        yield cluster
    finally:
        cluster.close()
