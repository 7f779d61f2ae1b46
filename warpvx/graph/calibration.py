"""Calibration: measured costs of each node's implementations, of host <-> device copies and
of the executor itself.

SPEC §7: costs are measured, not guessed, and cached per machine and size, after StarPU's
history-based performance models. For a graph and a GPU role:

- each node's CPU implementation (``backend="cpu"``) and GPU implementation (the GPU role's
  Warp backend) run on the data :meth:`Graph.verify` produced at the graph's real sizes
  (two frames when the graph has delays, so temporal nodes such as LK track real motion):
  ``warmup`` calls first (they include Warp's JIT and module load), then the median of
  ``repeats`` timed calls. A GPU node is timed as the executor runs it: on a stream of its
  own made current, with CUDA events recorded before and after the call, starting from an
  idle device. Its cost is the device interval between the events — what the executor's
  timeline measures — which covers the host's enqueue time too when the host is the
  bottleneck, and the host syncs some primitives make (FAST reads its count back). The
  host-side time of the call is kept beside it (``gpu_host``);
- the transfer model: uploads and downloads of a few sizes (4 KiB to 16 MiB on CUDA), through
  the executor's own copy paths, timed once per machine and fitted as
  ``latency + bytes / bandwidth``; an edge's transfer time is the mean of both directions;
- the executor's dispatch cost (:func:`measure_dispatch`): chains of trivial tasks run through
  the real executor give its cost per CPU task, per GPU task and per hand-off between the CPU
  workers and the GPU thread, which :meth:`Graph.to_task_dag` adds to the model;
- history (:func:`learn`): what nodes cost inside running frames, where workers contend for
  cores, memory bandwidth and Python's GIL. :meth:`Graph.learn` folds a run's measured
  timelines in, and ``Graph.schedule(..., costs="history")`` schedules with them, as StarPU
  refines its models from the tasks it ran.

The cache is one JSON file, ``$WARPVX_CACHE_DIR/calibration.json`` (default
``~/.cache/warpvx/``, or ``$XDG_CACHE_HOME/warpvx/``), keyed by machine (host name and GPU
name), backend (the CPU one with OpenCV's thread count, ``cv2.setNumThreads``), and node
(primitive or user callable, constant arguments, input types and sizes; data-dependent counts
such as keypoints rounded up to a power of two). Times are in milliseconds.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import socket
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..runtime import Transfers
from .data import describe

CACHE_ENV = "WARPVX_CACHE_DIR"
CACHE_VERSION = 2  # 2: GPU nodes timed with events on the executor's path
_file_lock = threading.Lock()


def cache_dir() -> Path:
    """Where the calibration cache lives (``$WARPVX_CACHE_DIR`` or the user's cache dir)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "warpvx"


def cache_file() -> Path:
    return cache_dir() / "calibration.json"


def machine_id(gpu_backend) -> str:
    """``"<hostname>|<GPU name>"``; the GPU name is ``"warp-cpu"`` for Warp's CPU device."""
    gpu = "none"
    if gpu_backend is not None:
        if gpu_backend.is_cuda:
            from ..backend import init_warp

            gpu = init_warp().get_device(gpu_backend.device).name
        else:
            gpu = f"warp-cpu ({platform.machine()})"
    return f"{socket.gethostname()}|{gpu}"


@dataclass
class TransferModel:
    """Host <-> device copy times: ``latency + bytes * per_byte`` (ms) in each direction."""

    h2d_latency: float = 0.0
    h2d_per_byte: float = 0.0
    d2h_latency: float = 0.0
    d2h_per_byte: float = 0.0

    def upload(self, nbytes: int) -> float:
        return self.h2d_latency + nbytes * self.h2d_per_byte

    def download(self, nbytes: int) -> float:
        return self.d2h_latency + nbytes * self.d2h_per_byte

    def time(self, nbytes: int) -> float:
        """Transfer time of an edge (ms): the mean of both directions."""
        return 0.5 * (self.upload(nbytes) + self.download(nbytes))

    @property
    def bandwidth_gbps(self) -> tuple:
        """(host -> device, device -> host) bandwidths in GB/s."""
        def bw(per_byte):
            return 1e-6 / per_byte if per_byte > 0 else float("inf")

        return bw(self.h2d_per_byte), bw(self.d2h_per_byte)


@dataclass
class Calibration:
    """Measured costs of one graph on one machine (ms).

    Attributes
    ----------
    machine : str
        :func:`machine_id`.
    gpu : str or None
        The GPU role's backend name (``"cuda:0"``, ``"warp-cpu"``).
    nodes : dict
        node name -> ``{"cpu": ms or None, "gpu": ms or None, "gpu_host": ms or None}``
        (None: no implementation; ``gpu_host``: the host-side time of the GPU call).
    transfer : TransferModel
    fresh : list
        Nodes measured now (the others came from the cache).
    dispatch : dict
        :func:`measure_dispatch`'s executor costs (ms), empty when not measured.
    history : dict
        node name -> ``{"cpu": ms, "gpu": ms}`` measured inside running frames
        (:func:`learn`); a node or processing element not run yet is absent.
    keys : dict
        node name -> its cache key (kind, constants, input sizes).
    transfer_scale : float
        Measured over modelled time of the copies in running frames (:func:`learn`); the
        history costs scale the transfer model by it.
    placement : dict
        node -> ``"cpu"``/``"gpu"``: where each node ran when :func:`learn` last saw it.
    contention : dict
        ``n_cpus`` -> :func:`measure_contention`'s probe (measured on first use).
    gil : dict or None
        :func:`measure_gil` (measured on first use).
    """

    machine: str
    gpu: str | None
    nodes: dict
    transfer: TransferModel
    fresh: list = field(default_factory=list)
    dispatch: dict = field(default_factory=dict)
    history: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    transfer_scale: float = 1.0
    placement: dict = field(default_factory=dict)
    contention: dict = field(default_factory=dict)
    gil: dict | None = None

    def cost(self, node: str, pe: str, costs: str = "calibrated"):
        """``node``'s cost (ms) on ``pe`` (``"cpu"``/``"gpu"``), None without an
        implementation; ``costs="history"`` prefers what running frames measured."""
        if costs == "history":
            t = self.history.get(node, {}).get(pe)
            if t is not None:
                return t
        return self.nodes[node][pe]


# --------------------------------------------------------------------------- cache


def load_cache(path: Path | None = None) -> dict:
    path = path or cache_file()
    try:
        with open(path) as f:
            data = json.load(f)
    except (OSError, ValueError):
        return {"version": CACHE_VERSION, "machines": {}}
    if not isinstance(data, dict) or data.get("version") != CACHE_VERSION:
        return {"version": CACHE_VERSION, "machines": {}}
    data.setdefault("machines", {})
    return data


def _merge(dst: dict, src: dict):
    for k, v in src.items():
        if isinstance(v, dict) and isinstance(dst.get(k), dict):
            _merge(dst[k], v)
        else:
            dst[k] = v


def save_cache(update: dict, path: Path | None = None):
    """Merge ``update`` (same layout as the file) into the cache file atomically."""
    path = path or cache_file()
    with _file_lock:
        data = load_cache(path)
        _merge(data, update)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".calibration-", suffix=".json")
        try:
            with os.fdopen(fd, "w") as f:
                json.dump(data, f, indent=1, sort_keys=True)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise


# --------------------------------------------------------------------------- timing


def time_call(fn, *, sync=None, warmup: int = 2, repeats: int = 5) -> float:
    """Median wall time of ``fn()`` in ms after ``warmup`` untimed calls (``sync()`` after each)."""
    for _ in range(max(0, warmup)):
        fn()
        if sync is not None:
            sync()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        if sync is not None:
            sync()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def _fit(sizes, times) -> tuple:
    """Least-squares ``t = a + b * n`` with a, b >= 0."""
    n = np.asarray(sizes, np.float64)
    t = np.asarray(times, np.float64)
    A = np.stack([np.ones_like(n), n], axis=1)
    (a, b), *_ = np.linalg.lstsq(A, t, rcond=None)
    if b < 0:
        b = 0.0
        a = float(t.mean())
    if a < 0:
        a = 0.0
        b = float((n * t).sum() / (n * n).sum())
    return float(a), float(b)


def measure_transfer(gpu_backend, *, sizes=None, repeats: int = 5) -> TransferModel:
    """Time uploads and downloads of a few sizes on the GPU role's device and fit the model.

    Uploads run as the executor's GPU thread runs them (on a stream of its own made current,
    through :class:`~warpvx.runtime.Transfers`), downloads as a CPU worker's do.
    """
    from ..backend import init_warp

    wp = init_warp()
    device = gpu_backend.device
    if sizes is None:
        sizes = [1 << 12, 1 << 16, 1 << 20, 1 << 22, 1 << 24] if gpu_backend.is_cuda else \
                [1 << 12, 1 << 16, 1 << 20, 1 << 22]
    up_io, down_io = Transfers(device), Transfers(device)
    stream = wp.Stream(device) if gpu_backend.is_cuda else None
    sync = (lambda: wp.synchronize_stream(stream)) if stream is not None else None
    up, down = [], []
    with _gpu_scope(wp, device, stream):
        for n in sizes:
            host = np.random.default_rng(0).integers(0, 255, n, dtype=np.uint8)
            dev = up_io.upload(host)
            if sync is not None:
                sync()
            # Into the same buffer each time, as the executor's pooled uploads do.
            up.append(time_call(lambda: up_io.upload(host, lambda shape, dtype: dev), sync=sync,
                                warmup=1, repeats=repeats))
            down.append(time_call(lambda: down_io.download(dev), sync=None, warmup=1, repeats=repeats))
    a_up, b_up = _fit(sizes, up)
    a_dn, b_dn = _fit(sizes, down)
    return TransferModel(a_up, b_up, a_dn, b_dn)


def _gpu_scope(wp, device, stream):
    """The GPU thread's scope: the device current and, on CUDA, ``stream`` as its stream."""
    import contextlib

    stack = contextlib.ExitStack()
    stack.enter_context(wp.ScopedDevice(device))
    if stream is not None:
        stack.enter_context(wp.ScopedStream(stream, sync_enter=False))
    return stack


def time_gpu_call(fn, gpu_backend, *, warmup: int = 2, repeats: int = 5) -> tuple:
    """``(device_ms, host_ms)``: medians of ``fn()`` run as the executor's GPU thread runs a
    node, each call from an idle device.

    On CUDA ``device_ms`` is the interval between events recorded on the current stream just
    before and just after the call (what the executor's timeline records for a GPU task), and
    ``host_ms`` the host time of the call (enqueue plus any host sync inside it). On Warp's
    CPU device both are the host time. Call it inside :func:`_gpu_scope`.
    """
    if not gpu_backend.is_cuda:
        t = time_call(fn, warmup=warmup, repeats=repeats)
        return t, t
    from ..backend import init_warp

    wp = init_warp()
    device = gpu_backend.device
    stream = wp.get_device(device).stream
    e0 = wp.Event(device, enable_timing=True)
    e1 = wp.Event(device, enable_timing=True)
    dev, host = [], []
    for i in range(max(0, warmup) + max(1, repeats)):
        wp.synchronize_device(device)
        h0 = time.perf_counter()
        stream.record_event(e0)
        fn()
        stream.record_event(e1)
        h1 = time.perf_counter()
        wp.synchronize_event(e1)
        if i >= warmup:
            dev.append(wp.get_event_elapsed_time(e0, e1, synchronize=False))
            host.append((h1 - h0) * 1e3)
    return statistics.median(dev), statistics.median(host)


def _identity(v):
    return v


def measure_dispatch(gpu_backend, transfer: TransferModel | None = None, *, n_nodes: int = 24,
                     frames: int = 25) -> dict:
    """The executor's own costs (ms), measured through it with chains of identity tasks.

    Three chains of ``n_nodes`` tasks run ``frames`` frames one at a time: all on one CPU
    worker, all on the GPU thread, and alternating (every edge crosses between a CPU worker
    and the GPU thread, a thread hand-off plus a host/device copy of 16 bytes).

    Returns
    -------
    dict
        ``cpu_node``, ``gpu_node``: a task's cost on each kind of processor (the frame's
        makespan over the tasks); ``cpu_gap``, ``gpu_gap``: the part of it outside the
        tasks' measured intervals (between tasks); ``handoff``: the extra cost of an edge
        between a CPU worker and the GPU thread, beyond the transfer model's time for its
        bytes; ``start``: from a frame's submission to its first task's start. Without a
        GPU role the GPU entries are 0.
    """
    from ..runtime import HOST, Executor, ExecTask, InputRef, Program
    from ..sched.schedule import Schedule, ScheduledTask

    device = gpu_backend.device if gpu_backend is not None else None
    x = np.zeros(4, np.float32)

    def run(kinds):
        tasks, prev, placed = {}, "x", {}
        for i, kind in enumerate(kinds):
            name = f"t{i}"
            tasks[name] = ExecTask(name, (InputRef(prev),), (name,), cpu=_identity, gpu=_identity)
            placed[name] = ScheduledTask(name, "cpu0" if kind == "cpu" else "gpu", i, i + 1)
            prev = name
        procs = ["cpu0", "gpu"] if device else ["cpu0"]
        ex = Executor(Schedule(placed, procs), Program(tasks, ("x",), {"y": prev}),
                      gpu_device=device, name="dispatch")
        spans, gaps, starts = [], [], []
        try:
            for f in range(frames + 3):
                ex.reanchor()
                r = ex.wait(ex.submit(f, {"x": (x, HOST)}))
                if f < 3:
                    continue  # threads, streams and pools warm up
                busy = sum(t.finish - t.start for t in r.timeline.values())
                first = min(t.start for t in r.timeline.values())
                spans.append(r.makespan - first)
                gaps.append(r.makespan - first - busy)
                starts.append(first)
        finally:
            ex.close()
        return statistics.median(spans), statistics.median(gaps), statistics.median(starts)

    n = max(2, int(n_nodes))
    span, gap, start = run(["cpu"] * n)
    out = {"cpu_node": span / n, "cpu_gap": max(0.0, gap) / n, "start": start,
           "gpu_node": 0.0, "gpu_gap": 0.0, "handoff": 0.0}
    if device:
        span, gap, _ = run(["gpu"] * n)
        out["gpu_node"], out["gpu_gap"] = span / n, max(0.0, gap) / n
        span, _, _ = run(["cpu", "gpu"] * (n // 2))
        m = 2 * (n // 2)
        crossing = (span - (m // 2) * (out["cpu_node"] + out["gpu_node"])) / (m - 1)
        tiny = transfer.time(x.nbytes) if transfer is not None else 0.0
        out["handoff"] = max(0.0, crossing - tiny)
    return out


#: :func:`measure_contention`'s CPU mix: nodes whose CPU time is at most this many times
#: their GPU time (a scheduler would not put a slower one on a CPU worker).
PROBE_SPREAD = 4.0
#: :func:`measure_contention` times each pair in this many rounds of alone then loaded.
PROBE_ROUNDS = 3
#: ... and times its *heavy* CPU nodes (this many ms or more alone) beside each other.
HEAVY_MS = 2.0


def _looping(call, scope):
    """A thread body calling ``call()`` (inside ``scope()``, if any) until ``stop`` is set;
    it sets ``started`` after its first call."""
    def body(stop, started):
        with scope() if scope is not None else contextlib.nullcontext():
            try:
                call()
            finally:  # a failing call must not leave the timer waiting for it
                started.release()
            while not stop.is_set():
                call()
    return body


def _time_beside(call, scope, bodies, *, repeats: int, mean: bool = False) -> float:
    """Median ms of ``call()`` (inside ``scope()``) while a thread runs each of ``bodies``
    (:func:`_looping`) beside it; ``mean``: the mean over ``repeats`` back-to-back calls
    instead (a thread holding the GIL takes it in turns of the switch interval: calls
    shorter than a turn are either untouched or wait a whole turn, and only the mean
    counts both)."""
    stop, started = threading.Event(), threading.Semaphore(0)
    threads = [threading.Thread(target=b, args=(stop, started), daemon=True) for b in bodies]
    for th in threads:
        th.start()
    try:
        for _ in threads:  # a loaded machine can start a thread late: time only side by side
            started.acquire()
        with scope() if scope is not None else contextlib.nullcontext():
            if not mean:
                return time_call(call, warmup=1, repeats=repeats)
            call()
            t0 = time.perf_counter()
            for _ in range(repeats):
                call()
            return (time.perf_counter() - t0) * 1e3 / repeats
    finally:
        stop.set()
        for th in threads:
            th.join()


def _node_calls(graph, names, kind, gpu_backend):
    """``(name -> call of that node on kind, the GPU thread's scope or None, sync or None)``:
    a CPU node called on its inputs; a GPU node's host call on uploaded inputs, and on
    CUDA a stream sync to call after a batch of them (the queue stays short, as in a
    frame)."""
    from ..backend import init_warp, resolve_backend

    if kind == "cpu":
        cpu = resolve_backend("cpu")
        calls = {}
        for n in names:
            fn, values = graph.nodes[n].callable("cpu", cpu), input_values(graph, graph.nodes[n])
            calls[n] = (lambda fn=fn, values=values: fn(*values))
        return calls, None, None
    wp = init_warp()
    stream = wp.Stream(gpu_backend.device) if gpu_backend.is_cuda else None
    calls = {}
    for n in names:
        node = graph.nodes[n]
        with wp.ScopedDevice(gpu_backend.device):
            dvals = Transfers(gpu_backend.device).upload(list(input_values(graph, node)))
        fn = node.callable("gpu", gpu_backend)
        calls[n] = (lambda fn=fn, dvals=dvals: fn(*dvals))
    return (calls, lambda: _gpu_scope(wp, gpu_backend.device, stream),
            None if stream is None else (lambda: wp.synchronize_stream(stream)))


def _in_turn(calls, sync=None):
    """One call making each of ``calls`` in turn, then ``sync()`` if given."""
    def call():
        for c in calls:
            c()
        if sync is not None:
            sync()
    return call


def measure_contention(graph, calibration, gpu_backend, n_cpus: int, *, repeats: int = 9) -> dict:
    """How much the graph's own nodes slow each other down when run together (ms).

    A *CPU mix* (every node a scheduler might put on a CPU worker: no GPU implementation,
    or a CPU time within :data:`PROBE_SPREAD` times its GPU time, called in turn) is timed
    alone, then while the other ``n_cpus - 1`` CPU workers loop the same mix, then while
    one thread loops the *GPU mix* (every node with a GPU implementation, its host calls in
    turn, as the GPU host thread makes them); the GPU mix alone and while ``n_cpus``
    threads loop the CPU mix. Mixes, not one heavy node: contention is mostly for the GIL,
    so what matters is how much Python a typical task runs (a long OpenCV call that
    releases the GIL hides it). A placement that keeps the workers idle (all on the GPU)
    does not reveal contention, and one kind of busy neighbour does not tell the other's
    cost; this probe does. Each pair is timed in :data:`PROBE_ROUNDS` rounds, alone and
    loaded in turn, ``repeats`` calls in all of each; its slowdown is the median of the
    rounds' loaded over alone times (so a drift of the machine between blocks is not read
    as contention), applied to the median alone time of its victim kind. Long OpenCV
    calls release the GIL but still share the cores' caches and memory bandwidth, which the
    mixes dilute: the *heavy* mix (the CPU mix's nodes of :data:`HEAVY_MS` or more) is also
    timed beside one worker looping it, as ``("cpu", "heavy")`` (one busy CPU worker), so
    two heavy nodes placed side by side are predicted to slow each other as measured.

    Returns
    -------
    dict
        ``(victim kind, loader kind)`` -> ``(mix, alone_ms, loaded_ms, busy_cpus,
        busy_gpus)``, for ``("cpu", "cpu")``, ``("cpu", "gpu")``, ``("gpu", "cpu")`` and
        ``("cpu", "heavy")`` (``mix``: its nodes, comma-separated); a pair is absent when a
        mix has no node (or ``n_cpus`` is 1 for ``("cpu", "cpu")``/``("cpu", "heavy")``).
    """
    mixes = _probe_mixes(calibration, gpu_backend)
    calls = {}
    for kind, names in mixes.items():
        if names:
            per_node, scope, sync = _node_calls(graph, names, "gpu" if kind == "gpu" else "cpu",
                                                gpu_backend)
            calls[kind] = (_in_turn([per_node[n] for n in names], sync), scope)

    ratios, alone = {}, {}
    # (victim mix, loader mix) -> loaders; the heavy mix beside one worker looping it is
    # reported as ("cpu", "heavy"): a CPU victim, one busy CPU worker.
    loads = {("cpu", "cpu"): n_cpus - 1, ("cpu", "gpu"): 1, ("gpu", "cpu"): n_cpus,
             ("heavy", "heavy"): min(1, n_cpus - 1)}
    per_round = max(1, -(-repeats // PROBE_ROUNDS))
    for (kind, loader), n in loads.items():
        if kind not in calls or loader not in calls or n < 1:
            continue
        call, scope = calls[kind]
        # Means, not medians: a mix shorter than a GIL turn is either untouched or waits
        # a whole turn, and the median would keep the untouched calls only. Alone and
        # loaded in turn (A B B A ...), each loaded time over the alone time next to it:
        # the machine drifts (frames of one placement differ by up to 1.7x between blocks
        # on the H100) and a drift between an alone and a loaded block reads as contention.
        sides = ([], [_looping(*calls[loader])] * n)
        pairs = []
        for r in range(PROBE_ROUNDS):
            order = (0, 1) if r % 2 == 0 else (1, 0)
            timed = {i: _time_beside(call, scope, sides[i], repeats=per_round, mean=True)
                     for i in order}
            pairs.append((timed[0], timed[1]))
        alone.setdefault(kind, []).extend(a for a, _ in pairs)
        ratios[(kind, loader)] = (statistics.median(b / a for a, b in pairs), n)
    out = {}
    for (kind, loader), (ratio, n) in ratios.items():
        a = statistics.median(alone[kind])
        cpus = n if loader in ("cpu", "heavy") else 0
        out[("cpu", "heavy") if kind == "heavy" else (kind, loader)] = (
            ",".join(mixes[kind]), a, a * ratio, cpus, n - cpus)
    return out


def _probe_mixes(calibration, gpu_backend) -> dict:
    """``"cpu"``/``"heavy"``/``"gpu"`` -> the nodes of :func:`measure_contention`'s mixes,
    sorted (``heavy``: the CPU mix's nodes of :data:`HEAVY_MS` or more, if two or more)."""
    def plausible_on_cpu(t):
        return t.get("cpu") and (not t.get("gpu") or t["cpu"] <= PROBE_SPREAD * t["gpu"])

    cpu = sorted(n for n, t in calibration.nodes.items() if plausible_on_cpu(t))
    heavy = [n for n in cpu if calibration.nodes[n]["cpu"] >= HEAVY_MS]
    return {"cpu": cpu, "heavy": heavy if len(heavy) >= 2 else [],
            "gpu": sorted(n for n, t in calibration.nodes.items() if t.get("gpu"))
            if gpu_backend is not None else []}


#: :func:`measure_gil` times each call over at least this many GIL switch intervals...
GIL_TURNS = 10
#: ... alone and beside its neighbour in turn, this many times (the median ratio counts).
GIL_PAIRS = 3


def _spin_python(n: int = 20_000):
    """Pure Python for a while: holds the GIL but for the interpreter's forced switches."""
    x = 0
    for i in range(n):
        x += i
    return x


def measure_gil(graph, calibration, gpu_backend, *, repeats: int = 5) -> dict:
    """Each node's share in the contention for Python's GIL, on each processing element.

    ``sensitivity``: how much slower the node's call runs beside one thread running pure
    Python (``loaded / alone - 1``); ``pressure``: how much slower a pure-Python loop runs
    beside a thread looping the node's call. A node that is mostly Python has both near
    1 (two such threads take turns); an OpenCV call that releases the GIL for its whole
    duration has pressure near 0 (sensitivity can stay above 0: it waits for the GIL to
    return). The contention model weighs each busy neighbour by its pressure and each
    victim by its sensitivity (:mod:`warpvx.graph.model`), so that three workers running
    OpenCV filters do not count as three workers running Python.

    Returns
    -------
    dict
        node -> ``{pe: (sensitivity, pressure)}`` for each of ``"cpu"``/``"gpu"`` it
        can run on (the GPU: its host call), each clipped to ``[0, 1]``.
    """
    def mean_ms(call, scope, bodies, n):
        return _time_beside(call, scope, bodies, repeats=n, mean=True)

    def share(call, scope, beside, n):
        """Median over GIL_PAIRS of (loaded / alone - 1), alone and loaded in turn: a burst
        of other processes' work falls on one pair, not on the share."""
        ratios = [mean_ms(call, scope, [beside], n) / max(mean_ms(call, scope, [], n), 1e-9)
                  for _ in range(GIL_PAIRS)]
        return float(min(1.0, max(0.0, statistics.median(ratios) - 1.0)))

    # Enough of the Python loop to span several switch intervals.
    spins = max(repeats, math.ceil(GIL_TURNS * sys.getswitchinterval() * 1e3
                                   / mean_ms(_spin_python, None, [], 3)))
    out = {}
    for kind in ("cpu", "gpu"):
        names = sorted(n for n, t in calibration.nodes.items() if t.get(kind))
        if not names or (kind == "gpu" and gpu_backend is None):
            continue
        per_node, scope, sync = _node_calls(graph, names, kind, gpu_backend)
        for n in names:
            call = _in_turn([per_node[n]], sync)
            alone = mean_ms(call, scope, [], repeats)
            n_calls = max(repeats, math.ceil(GIL_TURNS * sys.getswitchinterval() * 1e3 / max(alone, 1e-3)))
            sens = share(call, scope, _looping(_spin_python, None), n_calls)
            press = share(_spin_python, None, _looping(call, scope), spins)
            out.setdefault(n, {})[kind] = (sens, press)
    return out


def cpu_backend_key() -> str:
    """The CPU backend's cache key: OpenCV's thread count changes CPU costs."""
    import cv2

    return f"cpu/cv2-threads={cv2.getNumThreads()}"


def _node_key(node) -> str:
    sizes = ",".join(f"{port}={_sample_text(ref)}" for port, ref in node.inputs.items())
    return f"{node.cache_key()}|{sizes}"


def _sample_text(ref) -> str:
    from .data import DelayRef

    data = ref.data if isinstance(ref, DelayRef) else ref
    return footprint(data.sample)


def footprint(value) -> str:
    """Size key of a value: exact for images, counts rounded up to a power of two for
    data-dependent sizes (keypoints, point lists), so the cache survives small changes."""
    from ..keypoints import Keypoints

    def pow2(n):
        return 1 << max(0, int(n) - 1).bit_length()

    if isinstance(value, Keypoints):
        return f"kp[~{pow2(len(value))}]"
    if isinstance(value, np.ndarray) and value.dtype != np.uint8 and (
            value.ndim == 1 or (value.ndim == 2 and value.shape[1] <= 4)):
        rest = "x".join(str(s) for s in value.shape[1:])
        return f"{value.dtype}[~{pow2(value.shape[0])}{'x' + rest if rest else ''}]"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(footprint(v) for v in value) + "]"
    return describe(value)


def input_values(graph, node) -> list:
    """The sample values of ``node``'s inputs, as in verification's last frame: a delay slot
    reads the frame before (else the delay's initial value)."""
    from .data import DelayRef

    out = []
    for ref in node.inputs.values():
        if isinstance(ref, DelayRef):
            prev = ref.delay.sample_previous
            out.append(ref.delay.initial if prev is None else prev)
        else:
            out.append(ref.sample)
    return out


def calibrate(graph, gpu_backend, *, recalibrate: bool = False, warmup: int = 2,
              repeats: int = 5, path: Path | None = None) -> Calibration:
    """Measure (or load from the cache) every node's costs, the transfer model and the
    executor's dispatch costs.

    ``graph`` must be verified (its data objects carry samples at the real sizes).
    ``gpu_backend`` is the GPU role's :class:`~warpvx.backend.Backend` or None (CPU only).
    """
    from ..backend import init_warp, resolve_backend

    machine = machine_id(gpu_backend)
    cache = load_cache(path)
    mcache = cache["machines"].get(machine, {})
    gpu_name = gpu_backend.name if gpu_backend is not None else None
    node_cache = mcache.get("nodes", {})
    host_cache = mcache.get("gpu_host", {}).get(gpu_name, {}) if gpu_name else {}
    cpu_key = cpu_backend_key()
    update_nodes = {cpu_key: {}}
    update_host = {}
    if gpu_name:
        update_nodes[gpu_name] = {}
    cpu_backend = resolve_backend("cpu")
    nodes, fresh, keys = {}, [], {}

    transfer, fresh_transfer = None, False
    if gpu_name:
        cached = mcache.get("transfer", {}).get(gpu_name)
        if cached and not recalibrate:
            transfer = TransferModel(**cached)
        else:
            transfer = measure_transfer(gpu_backend, repeats=repeats)
            fresh_transfer = True
    else:
        transfer = TransferModel()

    wp = init_warp() if gpu_name else None
    stream = None
    for node in graph.nodes.values():
        key = keys[node.name] = _node_key(node)
        times = {"cpu": None, "gpu": None, "gpu_host": None}
        values = None
        for pe in ("cpu", "gpu"):
            if pe not in node.implementations or (pe == "gpu" and gpu_backend is None):
                continue
            bname = cpu_key if pe == "cpu" else gpu_name
            hit = node_cache.get(bname, {}).get(key)
            if hit is not None and not recalibrate:
                times[pe] = float(hit)
                if pe == "gpu":
                    times["gpu_host"] = host_cache.get(key)
                continue
            if values is None:
                values = input_values(graph, node)
            if pe == "cpu":
                fn = node.callable("cpu", cpu_backend)
                t = time_call(lambda: fn(*values), warmup=warmup, repeats=repeats)
            else:
                device = gpu_backend.device
                fn = node.callable("gpu", gpu_backend)
                if stream is None and gpu_backend.is_cuda:
                    stream = wp.Stream(device)
                with wp.ScopedDevice(device):
                    dvals = Transfers(device).upload(list(values))
                    wp.synchronize_device(device)
                with _gpu_scope(wp, device, stream):
                    t, host = time_gpu_call(lambda: fn(*dvals), gpu_backend, warmup=warmup,
                                            repeats=repeats)
                times["gpu_host"] = update_host[key] = host
            times[pe] = t
            update_nodes[bname][key] = t
            if node.name not in fresh:
                fresh.append(node.name)
        nodes[node.name] = times

    dkey = gpu_name or "none"
    dispatch = mcache.get("executor", {}).get(dkey)
    fresh_dispatch = not dispatch or recalibrate
    if fresh_dispatch:
        dispatch = measure_dispatch(gpu_backend, transfer)

    history = {}
    hcache = mcache.get("history", {})
    for node in graph.nodes.values():
        for pe, bname in (("cpu", cpu_key), ("gpu", gpu_name)):
            t = hcache.get(bname or "-", {}).get(keys[node.name]) if bname else None
            if t is not None and not recalibrate:
                history.setdefault(node.name, {})[pe] = float(t)
                x = hcache.get(bname + "|copies", {}).get(keys[node.name])
                history[node.name][f"{pe}_copies"] = float(x) if x is not None else 0.0

    scale = mcache.get("transfer_scale", {}).get(gpu_name) if gpu_name and not recalibrate else None

    mupdate = {"nodes": update_nodes, "executor": {dkey: dispatch}}
    if gpu_name:
        mupdate["transfer"] = {gpu_name: transfer.__dict__.copy()}
        mupdate["gpu_host"] = {gpu_name: update_host}
    if fresh or fresh_transfer or fresh_dispatch:  # (all from the cache: nothing to write, ~40 ms saved)
        save_cache({"machines": {machine: mupdate}}, path)
    return Calibration(machine, gpu_name, nodes, transfer, fresh, dict(dispatch), history, keys,
                       1.0 if scale is None else float(scale))


def learn(calibration: Calibration, runs, placement: dict, *, skip: int = 1,
          path: Path | None = None) -> dict:
    """Fold measured frames into ``calibration.history`` (and the cache); returns what changed.

    Parameters
    ----------
    calibration : Calibration
        Of the graph and GPU role that ran.
    runs : list of FrameResult
        Frames run with ``placement`` (a plan's ``last_run``), the first ``skip`` left out.
        A CPU node's cost is the median of its measured interval minus the transfers inside
        it; the transfers' median is kept apart (``"<pe>_copies"``): the executor makes a
        task's copies on the task's own processor (a GPU task's uploads on the GPU thread, a
        CPU task's downloads on its worker), so history costs charge them to the node. A GPU node occupies the GPU role as long as
        the longer of its device interval and its host call (without transfers): when the
        host thread runs ahead the interval is the device's time, when the host is the
        bottleneck (Python, host syncs, GIL) the host time is the cost.
        The ratio of the copies' measured time to the transfer model's becomes
        ``calibration.transfer_scale`` (copies in a running frame compete for memory
        bandwidth and the GIL).
    placement : dict
        node -> processor (``"cpu<i>"``/``"gpu"``) of the plan that ran (its one-frame
        schedule). Each frame's time is learnt for the kind of processor its timeline says
        ran the node, which differs from this under a K-frame plan.

    Returns
    -------
    dict
        node -> ``{pe: ms}`` learnt now.
    """
    runs = list(runs)[skip:] or list(runs)
    learnt = {}
    cpu_key = cpu_backend_key()
    update = {}
    for node, proc in placement.items():
        # Each frame's time goes to the kind of processor that ran it there: a K-frame plan
        # may place a node on a CPU worker in one frame and on the GPU in the next.
        by_kind = {}
        for r in runs:
            task = r.timeline.get(node)
            if task is None:
                continue
            pe = "gpu" if task.processor.startswith("gpu") else "cpu"
            t = r.compute_ms(node)
            if pe == "gpu" and node in r.host:
                h0, h1 = r.host[node]
                t = max(t, h1 - h0 - r.transfers.get(node, 0.0))
            samples, copies = by_kind.setdefault(pe, ([], []))
            samples.append(t)
            copies.append(r.transfers.get(node, 0.0))
        if by_kind:
            calibration.placement[node] = "gpu" if proc.startswith("gpu") else "cpu"
        for pe, (samples, copies) in by_kind.items():
            t, x = statistics.median(samples), statistics.median(copies)
            entry = calibration.history.setdefault(node, {})
            entry[pe], entry[f"{pe}_copies"] = t, x
            learnt.setdefault(node, {})[pe] = t
            bname = cpu_key if pe == "cpu" else calibration.gpu
            key = calibration.keys.get(node)
            if bname and key:
                update.setdefault(bname, {})[key] = t
                update.setdefault(bname + "|copies", {})[key] = x
    scale = _transfer_scale(calibration.transfer, runs)
    if scale is not None:
        calibration.transfer_scale = scale
    mupdate = {"history": update}
    if scale is not None and calibration.gpu:
        mupdate["transfer_scale"] = {calibration.gpu: scale}
    if update or scale is not None:
        save_cache({"machines": {calibration.machine: mupdate}}, path)
    return learnt


def _transfer_scale(model: TransferModel, runs):
    """Median over frames of (measured copy time) / (the model's time for those bytes)."""
    ratios = []
    for r in runs:
        measured = modelled = 0.0
        for task, nbytes in r.copied.items():
            if task not in r.transfers or task not in r.timeline:
                continue
            gpu = r.timeline[task].processor.startswith("gpu")
            modelled += model.upload(nbytes) if gpu else model.download(nbytes)
            measured += r.transfers[task]
        if modelled > 0:
            ratios.append(measured / modelled)
    return statistics.median(ratios) if ratios else None


__all__ = [
    "CACHE_ENV",
    "Calibration",
    "TransferModel",
    "cache_dir",
    "cache_file",
    "calibrate",
    "learn",
    "load_cache",
    "machine_id",
    "measure_contention",
    "measure_gil",
    "measure_dispatch",
    "measure_transfer",
    "save_cache",
    "time_call",
    "time_gpu_call",
]
