"""Calls a graph run makes per node and per frame: native Warp calls (each ctypes call into
Warp's library: CUDA events, stream waits and syncs, copies, context and stream switches)
and Python function calls, counted rather than timed.

Used by ``overhead_bench.py`` in its own process and in the A/B's fresh processes, which import
warpvx from another tree: it touches only Warp's native library object and
``warpvx.runtime.native_copy``'s cache of its entry points, which every tree has. On Warp's CPU
device most CUDA calls are never made; run on CUDA for the GPU role's real counts.
"""

from __future__ import annotations

import cProfile
import pstats
import re
from collections import Counter
from pathlib import Path


def _core():
    """Warp's native library object and the names of its functions Warp's Python calls."""
    from warpvx.backend import init_warp

    init_warp()
    try:
        from warp._src import context as ctx
    except ImportError:  # older Warp layout
        from warp import context as ctx
    names = set(re.findall(r"core\.(wp_\w+)", Path(ctx.__file__).read_text()))
    return ctx.runtime.core, names


class NativeCounter:
    """``with NativeCounter() as c:`` counts every call into Warp's native library by name
    (``c.counts``) until exit: the library's functions are swapped for counting wrappers, and
    ``native_copy``'s cached entry points looked up again (inside and after). What caches an
    entry point itself (an executor's event recorder, made when it starts) counts only if
    made inside."""

    def __init__(self):
        self.counts = Counter()
        self._saved = {}

    def __enter__(self):
        core, names = _core()
        counts = self.counts
        for name in sorted(names):
            fn = getattr(core, name, None)
            if fn is None:
                continue
            self._saved[name] = fn
            setattr(core, name, _counting(name, fn, counts))
        _forget_native_copy_cache()
        return self

    def __exit__(self, *exc):
        core, _ = _core()
        for name, fn in self._saved.items():
            setattr(core, name, fn)
        self._saved.clear()
        _forget_native_copy_cache()


def _counting(name, fn, counts):
    def call(*args):
        counts[name] += 1
        return fn(*args)

    return call


def _forget_native_copy_cache():
    from warpvx.runtime import native_copy

    native_copy._NATIVE = False


def frame_calls(make_graph, feed, frames: int = 20, warm: int = 10) -> dict:
    """Calls per frame of ``Graph.process(feed)`` on a graph ``make_graph()`` returns
    (scheduled; made, warmed and closed inside the counters): ``{"python": n, "native":
    {name: n}}``, per frame. Python calls: cProfile's count on this thread (where
    ``process`` runs a frame alone)."""
    with NativeCounter() as native:
        g = make_graph()
        try:
            for _ in range(warm):
                g.process(feed)
            native.counts.clear()
            prof = cProfile.Profile()
            prof.enable()
            for _ in range(frames):
                g.process(feed)
            prof.disable()
            counts = dict(native.counts)
        finally:
            g.close()
    python = sum(v[1] for v in pstats.Stats(prof).stats.values())
    return {"python": python / frames, "native": {k: v / frames for k, v in counts.items()}}


def per_node_and_frame(short: dict, long_: dict, n_short: int, n_long: int) -> dict:
    """Split :func:`frame_calls` of a chain of ``n_short`` and of ``n_long`` nodes into calls per
    node (what one more node adds) and per frame (the rest: a frame's fixed calls):
    ``{"python": (per node, per frame), "native": (per node, per frame), "by_name": {name:
    (per node, per frame)}}``."""
    def split(a, b):
        node = (b - a) / (n_long - n_short)
        return round(node, 2), round(a - n_short * node, 2)

    names = sorted(set(short["native"]) | set(long_["native"]))
    by_name = {k: split(short["native"].get(k, 0.0), long_["native"].get(k, 0.0)) for k in names}
    return {"python": split(short["python"], long_["python"]),
            "native": split(sum(short["native"].values()), sum(long_["native"].values())),
            "by_name": by_name}


def chain_calls(make_chain, chain: str, n_nodes: int, gpu, frames: int = 20) -> dict:
    """:func:`per_node_and_frame` of an identity chain (``make_chain(n, chain)``:
    ``warpvx.graph.diagnostics._chain`` of the tree under test) of ``n_nodes // 2`` and
    ``n_nodes`` nodes (even lengths: the alternating chain's rounds), scheduled as
    ``executor_overhead`` schedules them, fed 4 float32 values; ``n_nodes`` >= 4."""
    import numpy as np

    feed = {"x": np.arange(4, dtype=np.float32)}
    lengths = (n_nodes // 4 * 2, n_nodes // 2 * 2)

    def maker(n):
        def make():
            g = make_chain(n, chain)
            g.schedule("heft", n_cpus=1, gpu=False if chain == "cpu" else gpu)
            return g

        return make

    short, long_ = (frame_calls(maker(n), feed, frames) for n in lengths)
    return per_node_and_frame(short, long_, *lengths)
