"""Calibration: measured costs of each node's implementations and of host <-> device copies.

SPEC §7: costs are measured, not guessed, and cached per machine and size, after StarPU's
history-based performance models. For a graph and a GPU role:

- each node's CPU implementation (``backend="cpu"``) and GPU implementation (the GPU role's
  Warp backend) run on the data :meth:`Graph.verify` produced at the graph's real sizes:
  ``warmup`` calls first (they include Warp's JIT and module load), then the median of
  ``repeats`` timed calls; GPU calls are followed by a device synchronisation, so a time is
  what the call costs end to end, launch overhead included;
- the transfer model: host -> device and device -> host copies of a few sizes (4 KiB to
  16 MiB on CUDA) are timed once per machine and fitted as ``latency + bytes / bandwidth``;
  an edge's transfer time is the mean of both directions for its data's bytes.

The cache is one JSON file, ``$WARPVX_CACHE_DIR/calibration.json`` (default
``~/.cache/warpvx/``, or ``$XDG_CACHE_HOME/warpvx/``), keyed by machine (host name and GPU
name), backend (the CPU one with OpenCV's thread count, ``cv2.setNumThreads``), and node
(primitive or user callable, constant arguments, input types and sizes; data-dependent counts
such as keypoints rounded up to a power of two). Times are in milliseconds.
"""

from __future__ import annotations

import json
import os
import platform
import socket
import statistics
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..sched.executor import Transfers
from .data import describe

CACHE_ENV = "WARPVX_CACHE_DIR"
CACHE_VERSION = 1
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
        node name -> ``{"cpu": ms or None, "gpu": ms or None}`` (None: no implementation).
    transfer : TransferModel
    fresh : list
        Nodes measured now (the others came from the cache).
    """

    machine: str
    gpu: str | None
    nodes: dict
    transfer: TransferModel
    fresh: list = field(default_factory=list)


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
    """Time uploads and downloads of a few sizes on the GPU role's device and fit the model."""
    from ..backend import init_warp

    wp = init_warp()
    device = gpu_backend.device
    if sizes is None:
        sizes = [1 << 12, 1 << 16, 1 << 20, 1 << 22, 1 << 24] if gpu_backend.is_cuda else \
                [1 << 12, 1 << 16, 1 << 20, 1 << 22]
    io = Transfers(device)
    sync = (lambda: wp.synchronize_device(device)) if gpu_backend.is_cuda else None
    up, down = [], []
    with wp.ScopedDevice(device):
        for n in sizes:
            host = np.random.default_rng(0).integers(0, 255, n, dtype=np.uint8)
            dev = io.upload(host)
            up.append(time_call(lambda: io.upload(host), sync=sync, warmup=1, repeats=repeats))
            down.append(time_call(lambda: io.download(dev), sync=None, warmup=1, repeats=repeats))
    a_up, b_up = _fit(sizes, up)
    a_dn, b_dn = _fit(sizes, down)
    return TransferModel(a_up, b_up, a_dn, b_dn)


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
    """The sample values of ``node``'s inputs (delay inputs read the delay's initial value)."""
    from .data import DelayRef

    out = []
    for ref in node.inputs.values():
        if isinstance(ref, DelayRef):
            out.append(ref.delay.initial if ref.data.sample is None else ref.data.sample)
        else:
            out.append(ref.sample)
    return out


def calibrate(graph, gpu_backend, *, recalibrate: bool = False, warmup: int = 2,
              repeats: int = 5, path: Path | None = None) -> Calibration:
    """Measure (or load from the cache) every node's costs and the transfer model.

    ``graph`` must be verified (its data objects carry samples at the real sizes).
    ``gpu_backend`` is the GPU role's :class:`~warpvx.backend.Backend` or None (CPU only).
    """
    from ..backend import init_warp, resolve_backend

    machine = machine_id(gpu_backend)
    cache = load_cache(path)
    mcache = cache["machines"].get(machine, {})
    gpu_name = gpu_backend.name if gpu_backend is not None else None
    node_cache = mcache.get("nodes", {})
    cpu_key = cpu_backend_key()
    update_nodes = {cpu_key: {}}
    if gpu_name:
        update_nodes[gpu_name] = {}
    cpu_backend = resolve_backend("cpu")
    nodes, fresh = {}, []

    transfer = None
    if gpu_name:
        cached = mcache.get("transfer", {}).get(gpu_name)
        if cached and not recalibrate:
            transfer = TransferModel(**cached)
        else:
            transfer = measure_transfer(gpu_backend, repeats=repeats)
    else:
        transfer = TransferModel()

    wp = init_warp() if gpu_name else None
    for node in graph.nodes.values():
        key = _node_key(node)
        times = {"cpu": None, "gpu": None}
        values = None
        for pe in ("cpu", "gpu"):
            if pe not in node.implementations or (pe == "gpu" and gpu_backend is None):
                continue
            bname = cpu_key if pe == "cpu" else gpu_name
            hit = node_cache.get(bname, {}).get(key)
            if hit is not None and not recalibrate:
                times[pe] = float(hit)
                continue
            if values is None:
                values = input_values(graph, node)
            if pe == "cpu":
                fn = node.callable("cpu", cpu_backend)
                t = time_call(lambda: fn(*values), warmup=warmup, repeats=repeats)
            else:
                device = gpu_backend.device
                fn = node.callable("gpu", gpu_backend)
                with wp.ScopedDevice(device):
                    dvals = Transfers(device).upload(list(values))
                    sync = (lambda: wp.synchronize_device(device)) if gpu_backend.is_cuda else None
                    t = time_call(lambda: fn(*dvals), sync=sync, warmup=warmup, repeats=repeats)
            times[pe] = t
            update_nodes[bname][key] = t
            if node.name not in fresh:
                fresh.append(node.name)
        nodes[node.name] = times

    update = {"machines": {machine: {"nodes": update_nodes}}}
    if gpu_name:
        update["machines"][machine]["transfer"] = {gpu_name: transfer.__dict__.copy()}
    save_cache(update, path)
    return Calibration(machine, gpu_name, nodes, transfer, fresh)


__all__ = [
    "CACHE_ENV",
    "Calibration",
    "TransferModel",
    "cache_dir",
    "cache_file",
    "calibrate",
    "load_cache",
    "machine_id",
    "measure_transfer",
    "save_cache",
    "time_call",
]
