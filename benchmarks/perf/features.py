"""Per-stage profile of the feature primitives on a Warp device, against OpenCV on all cores.

Cases are the registry's own bench cases (``warpvx.bench.cases.<primitive>``: FAST, Harris
response, goodFeaturesToTrack, pyramidal LK, Hamming matching) on the benchmark photo. For every case and variant the script prints:

- the per-call time through the public function (median of batches between two device
  synchronisations, warm-up and JIT excluded), OpenCV's time on all cores beside it and the
  ratio;
- the host syncs one call makes (``wp.synchronize*`` and device ``.numpy()`` calls) and the
  kernel launches it makes (``wp.launch`` and replays of recorded ``wp.Launch`` objects);
- the GPU time of its Warp kernels (CUDA events around one call, ``wp.timing_begin``), the
  largest kernels named; CUB sorts and scans launched natively are not in that sum;
- ``graph``: the per-call time replayed from a captured CUDA graph, for calls without a
  host sync (Harris response, LK).

``--before DIR`` also times a baseline: DIR holds a package ``oldk`` with copies of the
previous ``warpvx/kernels_warp`` modules (``oldk/kernels_warp/<name>.py``); the public
functions are pointed at them for the "before" rows, and their results are compared with the
current ones (``same``).

Run on the GPU machine from the repository root::

    PYTHONPATH=. python3 benchmarks/perf/features.py --before build/perf_before
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from dataclasses import replace

import numpy as np

from warpvx.bench import Settings, time_graph, time_per_call_s

PRIMS = ("fast_corners", "harris_response", "harris_corners", "optical_flow_pyr_lk",
         "match_hamming")


# --- counting ----------------------------------------------------------------------------------


class Counter:
    """Counts host syncs and kernel launches while ``active``."""

    def __init__(self, wp):
        self.wp = wp
        self.active = False
        self.syncs = 0
        self.launches = 0
        self.old = 0  # launches of baseline (oldk) kernels
        ctx = wp._src.context
        orig = {
            "synchronize": wp.synchronize, "synchronize_device": wp.synchronize_device,
            "synchronize_stream": wp.synchronize_stream, "launch": wp.launch,
            "numpy": wp.array.numpy, "replay": ctx.Launch.launch,
        }
        counter = self

        def sync_wrap(f):
            def g(*a, **k):
                if counter.active:
                    counter.syncs += 1
                return f(*a, **k)
            return g

        def note(kernel):
            counter.launches += 1
            if getattr(getattr(kernel, "module", None), "name", "").startswith("oldk"):
                counter.old += 1

        def launch_wrap(*a, **k):
            if counter.active and not k.get("record_cmd"):
                note(a[0] if a else k.get("kernel"))
            return orig["launch"](*a, **k)

        def op_wrap(f):
            def g(*a, **k):
                if counter.active:
                    counter.launches += 1
                return f(*a, **k)
            return g

        def numpy_wrap(self_, *a, **k):
            if counter.active and not self_.device.is_cpu:
                counter.syncs += 1
            return orig["numpy"](self_, *a, **k)

        def replay_wrap(self_, *a, **k):
            if counter.active:
                note(self_.kernel)
            return orig["replay"](self_, *a, **k)

        for name in ("synchronize", "synchronize_device", "synchronize_stream"):
            setattr(wp, name, sync_wrap(orig[name]))
        # wp.launch_tiled calls the module-level launch, hence both.
        wp.launch = ctx.launch = launch_wrap
        # Memsets and copies are device operations too.
        wp.array.zero_ = op_wrap(wp.array.zero_)
        wp.array.fill_ = op_wrap(wp.array.fill_)
        wp.copy = op_wrap(wp.copy)
        wp.array.numpy = numpy_wrap
        ctx.Launch.launch = replay_wrap

    @contextlib.contextmanager
    def count(self):
        self.syncs = self.launches = self.old = 0
        self.active = True
        try:
            yield self
        finally:
            self.active = False


# --- timing ------------------------------------------------------------------------------------


#: Batches of at least 20 ms (20 to 2000 calls) after 3 warm-up calls, median of 5; CUDA graphs
#: of 10 calls replayed in batches of at least 5.
TIMING = Settings(repeat=5, warmup=3, min_batch_s=0.02, max_calls=2000, gpu_min_calls=50, graph_calls=10)


def per_call(fn, sync, *, min_calls=20, repeat=5):
    """Median per-call seconds over ``repeat`` batches between two syncs
    (:func:`warpvx.bench.time_per_call_s`)."""
    return time_per_call_s(fn, sync, settings=replace(TIMING, repeat=repeat), min_calls=min_calls)[0]


def kernel_profile(wp, fn, device):
    """(total GPU us of Warp kernels/memsets/copies in one call, [(name, us)] largest first)."""
    fn()
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    fn()
    results = wp.timing_end()
    agg: dict = {}
    for r in results:
        name = r.name.split("(")[0].replace("forward_kernel", "").replace("_cuda_kernel", "")
        name = name.removeprefix("memcpy ").strip()[-28:]
        agg[name] = agg.get(name, 0.0) + r.elapsed * 1e3
    total = sum(agg.values())
    return total, sorted(agg.items(), key=lambda kv: -kv[1])


# --- results -----------------------------------------------------------------------------------


def _host(x):
    """Nested results (arrays, tuples, Keypoints) as host NumPy arrays."""
    from warpvx.keypoints import FIELDS, Keypoints

    if isinstance(x, Keypoints):
        return [_host(getattr(x, f)) for f in FIELDS]
    if isinstance(x, (list, tuple)):
        return [_host(v) for v in x]
    if isinstance(x, np.ndarray):
        return x
    if hasattr(x, "numpy"):
        return x.numpy()
    return x


def _same(a, b) -> str:
    a, b = _host(a), _host(b)
    if isinstance(a, list):
        if not isinstance(b, list) or len(a) != len(b):
            return "no"
        verdicts = [_same(x, y) for x, y in zip(a, b)]
        for v in ("no", "close"):
            if v in verdicts:
                return v
        return "yes"
    if not isinstance(a, np.ndarray):
        return "yes" if a == b else "no"
    if a.shape != b.shape:
        return "no"
    if np.array_equal(a, b):
        return "yes"
    if a.dtype.kind == "f" and np.allclose(a, b, rtol=1e-4, atol=1e-6 * max(1e-30, np.abs(b).max())):
        return "close"
    return "no"


@contextlib.contextmanager
def baseline(prim: str):
    """Point the registry's Warp implementation of ``prim`` at ``oldk.kernels_warp``."""
    import warpvx.flow as flow
    from warpvx.registry import REGISTRY

    entry = REGISTRY[prim]
    saved = entry.impls["warp"]
    loaded = getattr(entry, "_loaded", {})  # the registry may cache loaded implementations
    loaded.clear()
    entry.impls["warp"] = f"oldk.kernels_warp.{prim}:{prim}"
    saved_check = flow._check_points
    if prim == "optical_flow_pyr_lk":
        from warpvx.check import check_array

        def old_check_points(p, name, n=None):  # the previous flow.py: reads device points back
            check_array(p, name, dtypes=(np.float32,), finite=True)
            return saved_check(p, name, n)

        flow._check_points = old_check_points
    try:
        yield
    finally:
        entry.impls["warp"] = saved
        loaded.clear()
        flow._check_points = saved_check


# --- main --------------------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--before", default=None, help="directory holding the oldk baseline package")
    ap.add_argument("--only", nargs="*", default=list(PRIMS))
    ap.add_argument("--small", action="store_true", help="small images (a local smoke run)")
    ap.add_argument("--lk-lanes", nargs="*", type=int, default=[],
                    help="also time LK with these lanes per point")
    args = ap.parse_args(argv)

    import cv2

    cv2.setNumThreads(os.cpu_count() or 1)
    from warpvx.backend import init_warp

    wp = init_warp()
    if args.before:
        sys.path.insert(0, os.path.abspath(args.before))
    from warpvx import bench
    from warpvx.registry import REGISTRY, _load

    counter = Counter(wp)
    device = str(wp.get_device(args.device))
    backend = "cuda" if device.startswith("cuda") else "warp-cpu"
    is_cuda = device.startswith("cuda")
    sync = (lambda: wp.synchronize_device(device))
    photo = bench.load_photo()
    sizes = {p: [(1920, 1080)] for p in PRIMS}
    sizes["harris_corners"] = [(1920, 1080), (1241, 376)]
    if args.small:
        sizes = {p: [(320, 240)] for p in PRIMS}
    print(f"device {wp.get_device(device).name}, {os.cpu_count()} CPU cores, OpenCV {cv2.__version__} "
          f"threads {cv2.getNumThreads()}, warp {wp.__version__}")
    hdr = (f"{'primitive':<20}{'case':<34}{'size':<10}{'variant':<13}{'us/call':>9}{'cv us':>9}"
           f"{'x cv':>7}{'sync':>5}{'lnch':>5}{'gpu us':>8}{'graph':>8}  same  kernels (gpu us)")
    print(hdr)
    for prim in args.only:
        bench_fn = _load(REGISTRY[prim].bench)
        for size in sizes[prim]:
            for case in bench_fn(bench.photo_at(photo, size)):
                t_cv = per_call(case.opencv(), lambda: None, min_calls=3, repeat=3)
                variants = [("after", contextlib.nullcontext)]
                if args.before:
                    variants.insert(0, ("before", lambda p=prim: baseline(p)))
                lanes_mod = importlib.import_module("warpvx.kernels_warp.optical_flow_pyr_lk")
                if prim == "optical_flow_pyr_lk":
                    variants += [(f"after,{n}ln", lambda n=n: _lanes(lanes_mod, n))
                                 for n in args.lk_lanes]
                ref = None
                for label, ctx in variants:
                    with ctx():
                        with wp.ScopedDevice(device):
                            fn = case.prepare(backend)
                            result = fn()
                            sync()
                            same = "-" if label == "before" or ref is None else _same(result, ref)
                            if label == "before" or ref is None:
                                ref = result
                            t = per_call(fn, sync)
                            with counter.count():
                                fn()
                            syncs, launches = counter.syncs, counter.launches
                            if (label == "before") != (counter.old > 0):
                                print(f"  WARNING: {label} ran {counter.old} baseline kernels")
                            gpu, kernels = (kernel_profile(wp, fn, device) if is_cuda
                                            else (float("nan"), []))
                            graph = float("nan")
                            if is_cuda and syncs == 0:
                                try:
                                    graph = time_graph(fn, device, settings=TIMING) * 1e6
                                except Exception as exc:  # noqa: BLE001 - report, go on
                                    graph = float("nan")
                                    print(f"  (graph capture failed: {exc!r:.80})")
                    ks = ", ".join(f"{n} {v:.1f}" for n, v in kernels[:4])
                    print(f"{prim:<20}{case.label[:33]:<34}{size[0]}x{size[1]:<5}{label:<13}"
                          f"{t * 1e6:9.1f}{t_cv * 1e6:9.1f}{t_cv / t:7.2f}{syncs:5d}{launches:5d}"
                          f"{gpu:8.1f}{graph:8.1f}  {same:<5} {ks}", flush=True)
    return 0


@contextlib.contextmanager
def _lanes(mod, n):
    saved = mod.BLOCK_DIM
    mod.BLOCK_DIM = n
    try:
        yield
    finally:
        mod.BLOCK_DIM = saved


if __name__ == "__main__":
    sys.exit(main())
