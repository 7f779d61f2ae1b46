"""How ``warpvx bench`` times a call: batches between device synchronisations, the median of
several batches, in seconds per call; and the same for a call replayed from a captured graph.

(Not to be confused with :func:`warpvx.graph.calibration.time_call`, which times single calls
for the graph's cost model, in milliseconds.)
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from dataclasses import dataclass


@dataclass
class Settings:
    """How hard to time: ``repeat`` batches after ``warmup`` calls, a batch lasting at least
    ``min_batch_s`` seconds and holding at least ``gpu_min_calls`` calls on a GPU."""

    repeat: int = 7
    warmup: int = 3
    min_batch_s: float = 0.05
    gpu_min_calls: int = 100
    max_calls: int = 100_000
    graph_calls: int = 10

    @classmethod
    def quick(cls, repeat=None) -> "Settings":
        return cls(repeat=repeat or 3, warmup=1, min_batch_s=0.005, gpu_min_calls=10, graph_calls=5)


def _no_sync():
    return None


def time_per_call_s(fn, sync=_no_sync, *, settings: Settings, min_calls: int = 1,
                    calls: int | None = None, issue_only: bool = False) -> tuple[float, int]:
    """Median per-call seconds of ``fn`` over ``settings.repeat`` batches, and the batch size.

    ``settings.warmup`` calls come first. A batch is ``calls`` calls when given, else as many
    as last ``settings.min_batch_s`` (at least ``min_calls``, at most ``settings.max_calls``),
    sized by one timed call. Each batch starts after ``sync()`` and ends after ``sync()``;
    with ``issue_only`` the clock stops before that closing ``sync()``, so the figure is the
    host's time to issue the calls (the device may still be busy)."""
    for _ in range(settings.warmup):
        fn()
    sync()
    samples = []
    if calls is None:
        t0 = time.perf_counter()
        fn()
        sync()
        one = time.perf_counter() - t0
        calls = max(min_calls, math.ceil(settings.min_batch_s / max(one, 1e-7)))
        calls = min(calls, settings.max_calls)
        if calls == 1 and one >= settings.min_batch_s and not issue_only:
            samples.append(one)  # a slow call: the sizing call already is a sample
    while len(samples) < settings.repeat:
        sync()
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        if issue_only:
            samples.append((time.perf_counter() - t0) / calls)
            sync()
        else:
            sync()
            samples.append((time.perf_counter() - t0) / calls)
    return statistics.median(samples), calls


def time_graph(fn, device, *, settings: Settings, calls: int | None = None) -> float:
    """Median per-call seconds of ``fn`` replayed from a captured CUDA graph of
    ``settings.graph_calls`` calls (``wp.ScopedCapture`` then ``wp.capture_launch``); the
    replays are timed by :func:`time_per_call_s` (``calls`` replays a batch when given)."""
    wp = warp_module()
    with wp.ScopedDevice(device):
        fn()
        wp.synchronize_device(device)
        with wp.ScopedCapture(device=device) as capture:
            for _ in range(settings.graph_calls):
                fn()
        graph = capture.graph

        def replay():
            wp.capture_launch(graph)

        per_launch, _ = time_per_call_s(replay, lambda: wp.synchronize_device(device),
                                        settings=settings, calls=calls,
                                        min_calls=max(1, settings.gpu_min_calls // settings.graph_calls))
    return per_launch / settings.graph_calls


def copy_bandwidth(device: str, *, nbytes: int = 256 << 20, settings: Settings) -> float:
    """Device-to-device copy bandwidth in bytes/s (bytes read plus bytes written per second)."""
    wp = warp_module()
    src = wp.zeros(nbytes, dtype=wp.uint8, device=device)
    dst = wp.empty(nbytes, dtype=wp.uint8, device=device)
    per_copy, _ = time_per_call_s(lambda: wp.copy(dst, src), lambda: wp.synchronize_device(device),
                                  settings=settings, min_calls=10)
    return 2 * nbytes / per_copy


def warp_module():
    """The ``warp`` module, initialised."""
    from ..backend import init_warp

    return init_warp()


def sync_for(backend_name: str):
    """A ``sync()`` waiting for the backend's device (a no-op for ``"cpu"``)."""
    if backend_name == "cpu":
        return _no_sync
    wp = warp_module()
    device = device_of(backend_name)
    return lambda: wp.synchronize_device(device)


def sync_peers():
    """Synchronise every CUDA context (peers run on their own streams)."""
    from ..backend import cuda_available

    if cuda_available():
        warp_module().synchronize()
        return
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        if torch.cuda.is_available():
            torch.cuda.synchronize()


def device_of(backend_name: str) -> str:
    """The Warp device alias of a backend name (``"cuda"`` -> ``"cuda:0"``)."""
    from ..backend import resolve_backend

    return resolve_backend(backend_name).device
