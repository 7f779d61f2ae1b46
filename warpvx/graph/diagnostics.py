"""Measurements of the runtime itself: executor overhead per node, and soak runs.

Both return plain dicts (benchmarks print and record them; tests run them small). They are
measurements, not assertions: timings on a shared machine vary.
"""

from __future__ import annotations

import gc
import os
import statistics
import sys
import time

import numpy as np

from ..errors import WarpvxValueError
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


def nvidia_smi_mb(gpu: str | None):
    """This process's GPU memory in MB as ``nvidia-smi`` reports it (the CUDA context, pools
    and every allocation); None without CUDA or nvidia-smi. ``gpu``'s ordinal is taken as
    nvidia-smi's index (true unless ``CUDA_VISIBLE_DEVICES`` reorders devices)."""
    if not gpu or not gpu.startswith("cuda"):
        return None
    import shutil
    import subprocess

    exe = shutil.which("nvidia-smi")
    if exe is None:
        return None
    index = gpu.split(":", 1)[1] if ":" in gpu else "0"
    try:
        res = subprocess.run([exe, "-i", index, "--query-compute-apps=pid,used_memory",
                              "--format=csv,noheader,nounits"], capture_output=True, text=True,
                             timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    pid = os.getpid()
    for line in res.stdout.splitlines():
        parts = [p.strip() for p in line.split(",")]
        if len(parts) == 2 and parts[0].isdigit() and int(parts[0]) == pid:
            try:
                return float(parts[1])
            except ValueError:
                return None
    return None


def _identity(v):
    return v


def _warp_identity(v):
    return v


#: The trivial chains :func:`executor_overhead` measures.
CHAINS = ("cpu", "gpu", "mixed")


def _chain(n_nodes: int, chain: str) -> Graph:
    g = Graph(f"overhead-{chain}-{n_nodes}")
    x = g.input("x", shape=(4,), dtype=np.float32)
    v = x
    for i in range(n_nodes):
        if chain == "mixed":
            target = "gpu" if i % 2 else "cpu"
            v = g.user(_identity, [v], warp_fn=_warp_identity, name=f"n{i}", target=target)
        elif chain == "gpu":
            v = g.user(None, [v], warp_fn=_warp_identity, name=f"n{i}", target="gpu")
        else:
            v = g.user(_identity, [v], name=f"n{i}")
    g.output("y", v)
    return g


def executor_overhead(n_nodes: int = 100, frames: int = 50, *, mixed: bool = False,
                      chain: str | None = None, gpu=None, depth: int = 4,
                      spin: float | None = None, timing: str | None = None) -> dict:
    """Per-node dispatch overhead of the executor, with trivial nodes.

    Builds a chain of ``n_nodes`` identity user nodes and runs ``frames`` frames with
    :meth:`Graph.process` (one frame at a time) and with :meth:`Graph.stream` (``depth``
    frames in flight). The overhead per node is the wall time per frame, minus the nodes'
    own time, over the number of nodes. The input is 4 float32 values on the host.

    ``chain`` (``mixed=True`` is ``chain="mixed"``):

    - ``"cpu"``: every node on one CPU worker (a task dispatch, no hand-off);
    - ``"gpu"``: every node on the GPU role: one upload at the first node, then data stays
      on the device; the GPU thread's enqueue overhead per task (timing events included);
    - ``"mixed"``: alternating CPU and GPU, so every edge crosses queues: a flag wait plus,
      on CUDA, an event, an upload (CPU -> GPU) or a download (GPU -> CPU).

    ``gpu`` is the GPU role's backend (default: CUDA when present); ``spin`` the executor's
    (:data:`warpvx.runtime.executor.SPIN_SECONDS` by default); ``timing`` its GPU timing
    (``"tasks"``, ``"bursts"``; None: its default, per task for ``process``, bursts for a
    pipelined stream: :class:`~warpvx.runtime.Executor`).

    Returns
    -------
    dict
        ``chain``, ``mixed``, ``per_node_us`` (process), ``per_node_us_stream``,
        ``frame_us``, the settings (``timing`` included), ``inline_units`` ("short/all": the executor's units
        scheduled short enough to run inline, :attr:`Executor.INLINE_MAX_MS`), and a
        ``breakdown`` (medians, us). ``"mixed"``: one
        CPU -> GPU -> CPU round: the GPU thread's time in a task (``gpu_task``), a CPU task's
        interval with its download (``cpu_task``), and the hand-offs from a CPU task's end to
        the GPU thread starting the next task (``cpu_to_gpu``) and from the GPU thread's end
        of a task to the CPU worker starting the next (``gpu_to_cpu``: wake-up, event wait).
        ``"gpu"``: the GPU thread's time in a task (``gpu_task``; the first one, with the
        upload, left out) and between two tasks (``gpu_gap``). Every chain: the frame's host
        time before its first task and after its last (``frame_head``, ``frame_tail``:
        :func:`_frame_ends`). Each ``process`` frame's timeline is read right after its
        timed call, as a caller learning from it would (on CUDA its events then go back to
        the pool; results kept unread would make later frames read them).
    """
    from ..runtime import executor as _executor

    chain = chain or ("mixed" if mixed else "cpu")
    if chain not in CHAINS:
        raise WarpvxValueError(f"chain: expected one of {CHAINS}, got {chain!r}")
    g = _chain(n_nodes, chain)
    x = np.arange(4, dtype=np.float32)
    saved = _executor.SPIN_SECONDS
    if spin is not None:
        _executor.SPIN_SECONDS = spin
    try:
        g.schedule("heft", n_cpus=1, gpu=False if chain == "cpu" else gpu)
        g.plan.executor().timing = timing
        g.process({"x": x})  # start the threads
    finally:
        _executor.SPIN_SECONDS = saved
    t_call = _time_direct(n_nodes)
    wall, runs, calls = [], [], []
    for _ in range(frames):
        t0 = time.perf_counter()
        g.process({"x": x})
        t1 = time.perf_counter()
        wall.append(t1 - t0)
        calls.append((t0, t1))
        run = g.plan.last_run[-1]
        # Its timeline read now, outside the timed call, as a caller learning from it would:
        # its CUDA events go back to the pool. Kept unread by the hundred, the pool would make
        # every later frame read an old one's events before returning (EventPool.MAX_UNREAD).
        run.timeline.get("")
        runs.append(run)
    frame_s = statistics.median(wall)
    t0 = time.perf_counter()
    for _ in g.stream(({"x": x} for _ in range(frames)), depth=depth):
        pass
    stream_s = (time.perf_counter() - t0) / frames
    plan = g.plan
    ex = plan.executor()
    spin_used = ex.spin
    # How many units were scheduled short enough to run inline (Executor.INLINE_MAX_MS).
    shorts = [ok for role in ex._roles.values() for ok in role.short]
    g.close()
    out = {
        "n_nodes": n_nodes,
        "frames": frames,
        "chain": chain,
        "mixed": chain == "mixed",
        "gpu": plan.gpu,
        "spin_us": spin_used * 1e6,
        "timing": timing,
        "frame_us": frame_s * 1e6,
        "per_node_us": max(0.0, frame_s - t_call) / n_nodes * 1e6,
        "per_node_us_stream": max(0.0, stream_s - t_call) / n_nodes * 1e6,
        "inline_units": f"{sum(shorts)}/{len(shorts)}",
    }
    if chain == "mixed":
        out["breakdown"] = _breakdown(runs, n_nodes)
    elif chain == "gpu":
        out["breakdown"] = _breakdown_gpu(runs, n_nodes)
    else:
        out["breakdown"] = {}
    out["breakdown"].update(_frame_ends(runs, calls))
    return out


def profile_overhead(n_nodes: int = 64, frames: int = 200, *, chain: str = "gpu", gpu=None,
                     top: int = 40) -> str:
    """:func:`executor_overhead` of one chain under ``cProfile``, on every thread: the
    caller's and the executor's role threads (their loop is wrapped while this runs), merged.

    Returns the ``pstats`` report (text): the ``top`` functions by own time, then by
    cumulative time (scheduling included; a short unprofiled run first loads modules and
    kernels; lock ``acquire`` is mostly idle threads waiting). Profiling slows every call several-fold: read it for where the host
    time goes, not for its amount.
    """
    import cProfile
    import io
    import pstats

    from ..runtime.roles import RoleRunner

    profiles = []
    loop = RoleRunner._role_loop

    def profiled_loop(self, proc):
        prof = cProfile.Profile()
        profiles.append(prof)
        prof.enable()
        try:
            loop(self, proc)
        finally:
            prof.disable()

    executor_overhead(n_nodes, 5, chain=chain, gpu=gpu)  # imports, JIT: not profiled
    main = cProfile.Profile()
    # From Python 3.12 cProfile runs on sys.monitoring: one profiler for the whole process,
    # which sees every thread (a second one enabled on a role thread would raise).
    if sys.version_info < (3, 12):
        RoleRunner._role_loop = profiled_loop
    try:
        main.enable()
        try:
            executor_overhead(n_nodes, frames, chain=chain, gpu=gpu)  # closes its threads
        finally:
            main.disable()
    finally:
        RoleRunner._role_loop = loop
    text = io.StringIO()
    stats = pstats.Stats(main, stream=text)
    for prof in profiles:
        stats.add(prof)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)
    return text.getvalue()


def _frame_ends(runs, calls) -> dict:
    """Medians (us) of a frame's host time outside its tasks, on the host clock (a GPU task's
    call, not its device interval): from ``process`` being called to the first task's start
    (``frame_head``: inputs, submit, a thread's wake-up) and from the last task's end to
    ``process`` returning (``frame_tail``: the device finishing, the wait, outputs, the
    frame's result and recycling)."""
    head, tail = [], []
    for r, (c0, c1) in zip(runs, calls):
        spans = [r.host.get(k) or (t.start, t.finish) for k, t in r.timeline.items()]
        head.append(r.t0 + min(a for a, _ in spans) / 1e3 - c0)
        tail.append(c1 - r.t0 - max(b for _, b in spans) / 1e3)
    return {"frame_head": statistics.median(head) * 1e6, "frame_tail": statistics.median(tail) * 1e6}


def _breakdown(runs, n_nodes: int) -> dict:
    """Medians (us) of the parts of the alternating chain's rounds (see executor_overhead)."""
    parts = {"gpu_task": [], "cpu_task": [], "cpu_to_gpu": [], "gpu_to_cpu": []}
    for r in runs:
        for i in range(1, n_nodes):
            prev, cur = f"n{i - 1}", f"n{i}"
            if cur in r.host:  # a GPU task after a CPU one
                h0, h1 = r.host[cur]
                parts["gpu_task"].append(h1 - h0)
                parts["cpu_to_gpu"].append(h0 - r.timeline[prev].finish)
            elif prev in r.host:  # a CPU task after a GPU one
                t = r.timeline[cur]
                parts["cpu_task"].append(t.finish - t.start)
                parts["gpu_to_cpu"].append(t.start - r.host[prev][1])
    return {k: statistics.median(v) * 1e3 if v else None for k, v in parts.items()}


def _breakdown_gpu(runs, n_nodes: int) -> dict:
    """Medians (us) of the GPU-only chain's tasks and gaps, host side (see executor_overhead)."""
    task, gap = [], []
    for r in runs:
        for i in range(1, n_nodes):
            h0, h1 = r.host[f"n{i}"]
            task.append(h1 - h0)
            gap.append(h0 - r.host[f"n{i - 1}"][1])
    return {"gpu_task": statistics.median(task) * 1e3 if task else None,
            "gpu_gap": statistics.median(gap) * 1e3 if gap else None}


def _time_direct(n_nodes: int) -> float:
    x = np.arange(4, dtype=np.float32)
    t0 = time.perf_counter()
    for _ in range(20):
        v = x
        for _ in range(n_nodes):
            v = _identity(v)
    return (time.perf_counter() - t0) / 20


def soak(graph: Graph, make_inputs, n: int, *, depth: int = 2, report_every: int = 0,
         max_seconds: float | None = None) -> dict:
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
    max_seconds : float, optional
        Stop after this long (the frames in flight finish); ``frames`` then says how many ran.

    Returns
    -------
    dict
        ``frames`` (run), ``requested``, ``seconds``, ``fps``, ``rss_start_mb``, ``rss_end_mb``,
        ``gpu_mem_start_mb``, ``gpu_mem_end_mb`` (Warp's mempool in use; None without
        CUDA), ``smi_start_mb``, ``smi_end_mb`` (nvidia-smi's figure for this process; None
        without it), ``samples`` (frame, rss MB, GPU MB, nvidia-smi MB) when asked. Start is
        after a warm-up of ``KEEP_FRAMES + 2 * depth`` frames in the same stream (plan,
        threads, JIT, pools, the plan's window of kept timelines), end after the last frame.
    """
    from .plan import KEEP_FRAMES

    # Warm-up in the same stream: plan, threads, JIT, pools, and the plan's window of kept
    # timelines filled, so that start and end compare like with like.
    warm = KEEP_FRAMES + 2 * depth
    gpu = graph.plan.gpu if graph.plan is not None else None
    mb = 1.0 / (1 << 20)

    def gpu_mb():
        v = gpu_memory_bytes(gpu)
        return None if v is None else v * mb

    samples = []
    start = {}
    t0 = time.perf_counter()
    deadline = None if max_seconds is None else t0 + max_seconds

    def inputs():
        for i in range(warm + n):
            if deadline is not None and i >= warm and time.perf_counter() > deadline:
                return
            yield make_inputs(i)

    done = 0
    for k, _ in enumerate(graph.stream(inputs(), depth=depth), 1):
        if k == warm:
            gpu = graph.plan.gpu
            gc.collect()
            start = {"rss": host_rss_bytes() * mb, "gpu": gpu_mb(), "smi": nvidia_smi_mb(gpu)}
            t0 = time.perf_counter()
            if deadline is not None:
                deadline = t0 + max_seconds
            continue
        if k < warm:
            continue
        done = k - warm
        if report_every and done % report_every == 0:
            samples.append((done, host_rss_bytes() * mb, gpu_mb(), nvidia_smi_mb(gpu)))
    seconds = time.perf_counter() - t0
    gc.collect()
    rss0, gpu0, smi0 = start.get("rss"), start.get("gpu"), start.get("smi")
    return {
        "frames": done,
        "requested": n,
        "depth": depth,
        "seconds": seconds,
        "fps": done / seconds if seconds > 0 else float("inf"),
        "rss_start_mb": rss0,
        "rss_end_mb": host_rss_bytes() * mb,
        "gpu_mem_start_mb": gpu0,
        "gpu_mem_end_mb": gpu_mb(),
        "smi_start_mb": smi0,
        "smi_end_mb": nvidia_smi_mb(gpu),
        "samples": samples,
    }


__all__ = ["CHAINS", "executor_overhead", "profile_overhead", "soak", "host_rss_bytes", "gpu_memory_bytes", "nvidia_smi_mb"]
