"""Shared test fixtures: the backends under test and real images.

Backends come from ``WARPVX_TEST_BACKENDS`` (comma separated, e.g. ``cpu,warp-cpu,cuda``);
by default ``cpu`` and ``warp-cpu``, plus ``cuda`` when a GPU is present. Tests take the
``backend`` fixture and so run once per backend.
"""

from __future__ import annotations

import os

import pytest


def _backends():
    env = os.environ.get("WARPVX_TEST_BACKENDS")
    if env:
        return [b.strip() for b in env.split(",") if b.strip()]
    import warpvx

    names = ["cpu", "warp-cpu"]
    if warpvx.cuda_available():
        names.append("cuda")
    return names


BACKENDS = _backends()


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Each backend under test in turn."""
    return request.param


@pytest.fixture(params=[b for b in BACKENDS if b != "cpu"] or ["warp-cpu"])
def warp_backend(request):
    """Each Warp backend under test (warp-cpu, cuda)."""
    return request.param


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory):
    """Graphs calibrate into a private cache (never the user's ~/.cache)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("WARPVX_CACHE_DIR", str(tmp_path_factory.mktemp("calibration")))
    yield
    mp.undo()
