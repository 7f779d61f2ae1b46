"""Measurements of the runtime itself: executor overhead per node, and soak runs.

Both return plain dicts (benchmarks print and record them; tests run them small). They are
measurements, not assertions: timings on a shared machine vary.
"""

from __future__ import annotations

import gc
import os
import statistics
import time

import numpy as np

from .graph import Graph


def host_rss_bytes() -> int:
    """Resident set size of this process (Linux ``/proc``; else the peak from ``resource``)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def gpu_memory_bytes(gpu: str | None):
    """Device memory in use: the Warp mempool's current use on CUDA (or total minus free
    without a mempool); None for the warp-cpu role or no GPU."""
    if not gpu or not gpu.startswith("cuda"):
        return None
    from ..backend import init_warp

    wp = init_warp()
    dev = wp.get_device(gpu)
    try:
        if dev.is_mempool_supported and wp.is_mempool_enabled(dev):
            return int(wp.get_mempool_used_mem_current(dev))
    except (RuntimeError, ValueError, AttributeError):
        pass
    return int(dev.total_memory - dev.free_memory)


def _identity(v):
    return v


def _warp_identity(v):
    return v


def _chain(n_nodes: int, mixed: bool) -> Graph:
    g = Graph(f"overhead-{'mixed' if mixed else 'cpu'}-{n_nodes}")
    x = g.input("x", shape=(4,), dtype=np.float32)
    v = x
    for i in range(n_nodes):
        if mixed:
            target = "gpu" if i % 2 else "cpu"
            v = g.user(_identity, [v], warp_fn=_warp_identity, name=f"n{i}", target=target)
        else:
            v = g.user(_identity, [v], name=f"n{i}")
    g.output("y", v)
    return g


def executor_overhead(n_nodes: int = 100, frames: int = 50, *, mixed: bool = False,
                      gpu=None, depth: int = 4) -> dict:
    """Per-node dispatch overhead of the executor, with trivial nodes.

    Builds a chain of ``n_nodes`` identity user nodes on one CPU worker (``mixed``: alternating
    CPU and GPU, so every edge crosses queues: a flag wait plus, on CUDA, an event) and runs
    ``frames`` frames with :meth:`Graph.process` (one frame at a time) and with
    :meth:`Graph.stream` (``depth`` frames in flight). The overhead per node is the wall time
    per frame, minus the nodes' own time, over the number of nodes.

    Returns
    -------
    dict
        ``per_node_us`` (process), ``per_node_us_stream``, ``frame_us`` and the settings.
    """
    g = _chain(n_nodes, mixed)
    x = np.arange(4, dtype=np.float32)
    g.schedule("heft", n_cpus=1, gpu=gpu if mixed else False)
    g.process({"x": x})  # start the threads
    t_call = _time_direct(n_nodes)
    wall = []
    for _ in range(frames):
        t0 = time.perf_counter()
        g.process({"x": x})
        wall.append(time.perf_counter() - t0)
    frame_s = statistics.median(wall)
    t0 = time.perf_counter()
    for _ in g.stream(({"x": x} for _ in range(frames)), depth=depth):
        pass
    stream_s = (time.perf_counter() - t0) / frames
    plan = g.plan
    g.close()
    return {
        "n_nodes": n_nodes,
        "frames": frames,
        "mixed": mixed,
        "gpu": plan.gpu,
        "frame_us": frame_s * 1e6,
        "per_node_us": max(0.0, frame_s - t_call) / n_nodes * 1e6,
        "per_node_us_stream": max(0.0, stream_s - t_call) / n_nodes * 1e6,
    }


def _time_direct(n_nodes: int) -> float:
    x = np.arange(4, dtype=np.float32)
    t0 = time.perf_counter()
    for _ in range(20):
        v = x
        for _ in range(n_nodes):
            v = _identity(v)
    return (time.perf_counter() - t0) / 20


def soak(graph: Graph, make_inputs, n: int, *, depth: int = 2, report_every: int = 0) -> dict:
    """Run ``n`` frames through ``graph.stream`` and report memory at start and end.

    Parameters
    ----------
    graph : Graph
        Scheduled already (its current plan runs) or scheduled by the first frame.
    make_inputs : callable(i) -> inputs
        The inputs of frame ``i``.
    n : int
        Frames.
    depth : int
        Frames in flight.
    report_every : int
        Also sample memory every that many frames (0: start and end only).

    Returns
    -------
    dict
        ``frames``, ``seconds``, ``fps``, ``rss_start_mb``, ``rss_end_mb``,
        ``gpu_mem_start_mb``, ``gpu_mem_end_mb`` (None without CUDA), ``samples``
        (frame, rss MB, GPU MB) when asked.
    """
    first = make_inputs(0)
    graph.process(first)  # warm: plan, threads, JIT, first allocations
    gc.collect()
    gpu = graph.plan.gpu
    mb = 1.0 / (1 << 20)

    def gpu_mb():
        v = gpu_memory_bytes(gpu)
        return None if v is None else v * mb

    rss0, gpu0 = host_rss_bytes() * mb, gpu_mb()
    samples = []
    t0 = time.perf_counter()
    for i, _ in enumerate(graph.stream((make_inputs(i) for i in range(n)), depth=depth)):
        if report_every and (i + 1) % report_every == 0:
            samples.append((i + 1, host_rss_bytes() * mb, gpu_mb()))
    seconds = time.perf_counter() - t0
    gc.collect()
    return {
        "frames": n,
        "depth": depth,
        "seconds": seconds,
        "fps": n / seconds if seconds > 0 else float("inf"),
        "rss_start_mb": rss0,
        "rss_end_mb": host_rss_bytes() * mb,
        "gpu_mem_start_mb": gpu0,
        "gpu_mem_end_mb": gpu_mb(),
        "samples": samples,
    }


__all__ = ["executor_overhead", "soak", "host_rss_bytes", "gpu_memory_bytes"]
