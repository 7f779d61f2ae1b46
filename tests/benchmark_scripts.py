"""The benchmark scripts under ``benchmarks/`` as modules, for the tests of their functions."""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_bench(name: str):
    """``benchmarks/<name>.py`` imported afresh (its module-level state, e.g. graph_bench's
    detector scratch images, new: what a test that times the executor sees)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.lru_cache(maxsize=None)
def bench_module(name: str):
    """:func:`load_bench` once per test session: a script's caches (graph_bench's reads and
    serial tasks per graph and size, found by running the graph) serve every test."""
    return load_bench(name)
