"""ORB-SLAM2 extraction on Warp, stage by stage: the host-quadtree path (before) against the
one-graph path (after), beside ``cv2.ORB_create(2000).detectAndCompute`` in the same run.

Usage (repo root, a Warp device): ``python benchmarks/perf/orb.py [--device cuda]
[--sizes 1920x1080 1241x376] [--repeat 30] [--no-check]``. Prints, per size:

- end to end per call: OpenCV (all cores), before (``orb_host_quadtree``: per-level launches,
  the quadtree on the host), after (the public ``warpvx.orb``, device in and out), and the
  after graph alone (``capture_launch``, GPU time per frame back to back);
- host syncs per call (``.numpy()`` reads and explicit synchronizations, counted);
- per-stage times: before, each stage run eagerly between device syncs (Python launch
  overhead included, as the path pays it); after, each stage captured alone into a CUDA
  graph (GPU time), plus the host's part of a call (enqueue, the one read-back, output copies);
- pipelined throughput: the slowest stage, and measured with 4 plans on 4 streams in flight.

``--check`` (default on) first asserts that the after path returns exactly what the before
path returns (every keypoint field and descriptor byte) on real photos at each size.
Timings: medians of batches after warm-up (JIT and graph capture excluded).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import cv2
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

import warp as wp  # noqa: E402

wp.config.quiet = True

import warpvx  # noqa: E402
from warpvx.bench import Settings, time_graph, time_per_call_s  # noqa: E402
from warpvx import _orb_spec as ref  # noqa: E402
from warpvx.kernels_warp import orb as kw  # noqa: E402

FIELDS = ("x", "y", "response", "size", "angle", "octave")
N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH = 2000, 1.2, 8, 20, 7


def photo(name: str, size: tuple) -> np.ndarray:
    """A real photo (scikit-image, else the bundled astronaut) resized to (w, h), gray."""
    try:
        from skimage import data

        img = getattr(data, name)()
    except Exception:  # noqa: BLE001 - scikit-image missing: the bundled copy
        path = os.path.join(os.path.dirname(warpvx.__file__), "data", "astronaut_448.png")
        img = cv2.cvtColor(cv2.imread(path), cv2.COLOR_BGR2RGB)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(cv2.resize(img, size, interpolation=cv2.INTER_AREA))


def median_ms(fn, device, repeat: int, inner: int = 1) -> float:
    """Median over ``repeat`` batches of ``inner`` calls (device synced around each batch),
    after one warm-up call, in ms (:func:`warpvx.bench.time_per_call_s`)."""
    return 1e3 * time_per_call_s(fn, lambda: wp.synchronize_device(device),
                                 settings=Settings(repeat=repeat, warmup=1), calls=inner)[0]


def host_result(kps, desc):
    return {f: getattr(kps, f).numpy() for f in FIELDS}, desc.numpy()


class SyncCounter:
    """Counts device-to-host reads (``wp.array.numpy``) and explicit synchronizations."""

    def __init__(self):
        self.count = 0
        self._saved = {}

    def __enter__(self):
        counter = self
        orig_numpy = wp.array.numpy

        def numpy(self_):
            if self_.device.is_cuda:
                counter.count += 1
            return orig_numpy(self_)

        self._saved["numpy"] = (wp.array, "numpy", orig_numpy)
        wp.array.numpy = numpy
        for name in ("synchronize", "synchronize_device", "synchronize_stream"):
            orig = getattr(wp, name)

            def wrapped(*a, _orig=orig, **k):
                counter.count += 1
                return _orig(*a, **k)

            self._saved[name] = (wp, name, orig)
            setattr(wp, name, wrapped)
        return self

    def __exit__(self, *exc):
        for owner, name, orig in self._saved.values():
            setattr(owner, name, orig)


def check(device, sizes) -> bool:
    ok = True
    for size in sizes:
        counts = []
        for name in ("astronaut", "coffee", "camera", "brick", "text"):
            img = photo(name, size)
            src = wp.array(img, dtype=wp.uint8, device=device)
            a, da = host_result(*warpvx.orb(src, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH))
            b, db = host_result(*kw.orb_host_quadtree(src, N_FEATURES, SCALE, LEVELS, INI_TH,
                                                      MIN_TH))
            same = (a["x"].shape == b["x"].shape and all(np.array_equal(a[f], b[f]) for f in FIELDS)
                    and np.array_equal(da, db))
            ok &= same
            counts.append(f"{name} {len(a['x'])}{'' if same else ' DIFFERENT'}")
        print(f"  {size[0]}x{size[1]}: " + ", ".join(counts))
    print(f"  photos: {'all identical' if ok else 'DIFFERENCES'}")
    return ok


def synthetic(rng, h: int, w: int) -> np.ndarray:
    """Noise, sparse dots, a textured patch on a flat background, or rectangles."""
    kind = int(rng.integers(0, 4))
    if kind == 0:
        return rng.integers(0, 256, (h, w)).astype(np.uint8)
    img = np.full((h, w), 128, np.uint8)
    if kind == 1:
        for _ in range(int(rng.integers(1, 300))):
            cv2.circle(img, (int(rng.integers(0, w)), int(rng.integers(0, h))),
                       int(rng.integers(1, 4)), int(rng.integers(0, 256)), -1)
    elif kind == 2:
        y0, x0 = int(rng.integers(0, h // 2)), int(rng.integers(0, w // 2))
        ph, pw = int(rng.integers(5, h // 2)), int(rng.integers(5, w // 2))
        img[y0:y0 + ph, x0:x0 + pw] = rng.integers(0, 256, (ph, pw))
    else:
        for _ in range(int(rng.integers(1, 60))):
            x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
            cv2.rectangle(img, (x0, y0), (x0 + int(rng.integers(2, 80)),
                                          y0 + int(rng.integers(2, 80))),
                          int(rng.integers(0, 256)), -1)
    return img


def check_random(device, cases: int, seed: int = 0) -> bool:
    """After against before on synthetic images, odd sizes and random parameters."""
    from warpvx.pyramid import scale_pyramid_sizes

    rng = np.random.default_rng(seed)
    bad = 0
    for _ in range(cases):
        h, w = int(rng.integers(70, 700)), int(rng.integers(70, 900))
        sf = float(rng.choice([1.2, 1.1, 1.5]))
        nl = int(rng.integers(1, 9))
        while nl > 1 and min(scale_pyramid_sizes(w, h, nl, sf)[-1]) < ref.MIN_LEVEL_SIZE:
            nl -= 1
        nf = int(rng.choice([2000, 50, 7, 500, 10000]))
        ini, mn = int(rng.choice([20, 12, 30])), int(rng.choice([7, 5, 25]))
        src = wp.array(synthetic(rng, h, w), dtype=wp.uint8, device=device)
        a, da = host_result(*warpvx.orb(src, nf, sf, nl, ini, mn))
        b, db = host_result(*kw.orb_host_quadtree(src, nf, sf, nl, ini, mn))
        same = (a["x"].shape == b["x"].shape and all(np.array_equal(a[f], b[f]) for f in FIELDS)
                and np.array_equal(da, db))
        if not same:
            bad += 1
            print(f"  DIFFERENT: {w}x{h} scale {sf} levels {nl} features {nf} th {ini}/{mn}")
    print(f"  random synthetic cases: {cases - bad} of {cases} identical")
    return bad == 0


def before_stages(src, repeat):
    """The host-quadtree path's stages, each eager between syncs (ms)."""
    device = src.device
    wanted = ref.features_per_level(N_FEATURES, SCALE, LEVELS)
    state = {}

    def pyramid():
        state["pyr"] = kw.build_pyramid(src, SCALE, LEVELS)

    def detect():
        state["cand"] = kw.detect_and_select(state["pyr"], INI_TH, MIN_TH)

    def quadtree():
        state["chosen"] = kw.distribute(*state["cand"], state["pyr"], wanted)

    def orient():
        chosen = state["chosen"]
        counts = np.bincount(chosen[:, 3], minlength=LEVELS).tolist()
        first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
        n = chosen.shape[0]
        kps = wp.array(chosen, dtype=wp.int32, device=device)
        angle = wp.empty(n, dtype=wp.float32, device=device)
        kw.compute_orientation(state["pyr"], kps, first, counts, angle)
        state.update(kps=kps, angle=angle, first=first, counts=counts)

    def blur():
        state["blur"] = kw.blur_levels(state["pyr"])

    def describe():
        desc = wp.empty((state["kps"].shape[0], 32), dtype=wp.uint8, device=device)
        kw.compute_descriptors(state["blur"], state["kps"], state["angle"], state["first"],
                               state["counts"], desc)

    def scale():
        kw.scale_back(state["kps"], state["angle"], SCALE, LEVELS)

    stages = [("pyramid (7 resizes)", pyramid), ("FAST+NMS+cells (24 launches)", detect),
              ("quadtree: sync, download, host", quadtree),
              ("upload + orientation", orient), ("blur (8 launches)", blur),
              ("descriptors", describe), ("scale back", scale)]
    for _, fn in stages:  # warm up in order
        fn()
    settings = Settings(repeat=repeat, warmup=0)
    sync = lambda: wp.synchronize_device(device)  # noqa: E731
    return [(name, 1e3 * time_per_call_s(fn, sync, settings=settings, calls=1)[0]) for name, fn in stages]


def after_stages(plan, src, repeat):
    """The one-graph path's stages (GPU ms on CUDA: each captured into a graph), and the
    host's part of a call. Detection through descriptors are timed as growing prefixes of the
    program (each prefix is idempotent: detection zeroes the counters) and reported as
    differences; the pyramid and the blur alone."""
    device = plan.device
    plan.run(src)

    def timed(fns):
        def call():
            for fn in fns:
                fn()
        if device.is_cuda:
            return 1e3 * time_graph(call, device, settings=Settings(repeat=repeat, warmup=1, graph_calls=1),
                                    calls=20)
        return median_ms(call, device, repeat)

    out = [("pyramid (7 resizes)", timed([plan.stage_pyramid])),
           ("blur (8 levels)", timed([plan.stage_blur]))]
    prefix = [("FAST+NMS+cells (3 launches, all levels)", plan.stage_detect),
              ("quadtree: path sort", plan.stage_sort),
              ("quadtree: depth counts, decisions, node order", plan.stage_nodes),
              ("quadtree: final nodes + sort", plan.stage_finals),
              ("orientation + descriptors", plan.stage_describe)]
    previous = 0.0
    for k, (name, _) in enumerate(prefix):
        total = timed([fn for _, fn in prefix[:k + 1]])
        out.append((name, total - previous))
        previous = total
    # The host's part of a call: copy in + graph launch (enqueue), then read-back and copies.
    t_enqueue, t_wait, t_copy = [], [], []
    for _ in range(repeat):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        wp.copy(plan.levels[0], src)
        plan.launch()
        t1 = time.perf_counter()
        head = plan.read_head()
        t2 = time.perf_counter()
        plan.take_outputs(int(head[kw.C_FINAL]))
        t3 = time.perf_counter()
        t_enqueue.append(t1 - t0)
        t_wait.append(t2 - t1)
        t_copy.append(t3 - t2)
    host = [("host: copy in + enqueue", 1e3 * statistics.median(t_enqueue)),
            ("host: wait for count (GPU runs)", 1e3 * statistics.median(t_wait)),
            ("host: output copies", 1e3 * statistics.median(t_copy))]
    return out, host


def pipelined(src, device, n_plans: int, frames: int) -> float:
    """Frames/s with ``n_plans`` plans on their own streams, round robin: copy in, the graph,
    the count read back (asynchronously; the output copies, sized by it, left out)."""
    h, w = src.shape
    plans = [kw.OrbPlan(device, h, w, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH)
             for _ in range(n_plans)]
    streams = [wp.Stream(device) for _ in range(n_plans)]
    for p in plans:
        p.run(src)
        p.run(src)  # captured
        if p.captured.graph is None:
            return float("nan")
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for i in range(frames):
        p, s = plans[i % n_plans], streams[i % n_plans]
        wp.copy(p.levels[0], src, stream=s)
        wp.capture_launch(p.captured.graph, stream=s)
        wp.copy(p.head, p.counters, count=p.head.shape[0], stream=s)
    wp.synchronize_device(device)
    return frames / (time.perf_counter() - t0)


def profile_call(plan, src, calls: int = 300, top: int = 8):
    """Per-kernel GPU times of one eager run, and where the public call's host time goes."""
    import cProfile
    import pstats

    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
    plan.program()
    results = wp.timing_end()
    per = {}
    for r in results:
        per[r.name] = per.get(r.name, 0.0) + r.elapsed
    print("per kernel (one eager run, GPU ms):")
    for name, ms in sorted(per.items(), key=lambda kv: -kv[1])[:top]:
        print(f"  {name[:60]:60s} {ms:7.3f}")
    fn = lambda: warpvx.orb(src, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH)  # noqa: E731
    fn()
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(calls):
        fn()
    prof.disable()
    stats = pstats.Stats(prof)
    rows = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:top]
    print(f"host time per public call by function (tottime, us; {calls} calls):")
    for (file, line, func), (_, _, tt, ct, _) in rows:
        print(f"  {os.path.basename(file)[:22]:22s}:{line:<5d} {func[:30]:30s} "
              f"{1e6 * tt / calls:7.1f} (cum {1e6 * ct / calls:7.1f})")


def run_size(device, size, repeat, profile=False):
    w, h = size
    img = photo("astronaut", size)
    src = wp.array(img, dtype=wp.uint8, device=device)
    det = cv2.ORB_create(N_FEATURES, SCALE, LEVELS)
    t_cv = median_ms(lambda: det.detectAndCompute(img, None), "cpu", repeat)
    t_before = median_ms(lambda: kw.orb_host_quadtree(src, N_FEATURES, SCALE, LEVELS, INI_TH,
                                                      MIN_TH), device, repeat)
    call = lambda: warpvx.orb(src, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH)  # noqa: E731
    t_after = median_ms(call, device, repeat, inner=5)
    with SyncCounter() as c_before:
        kw.orb_host_quadtree(src, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH)
    with SyncCounter() as c_after:
        call()
    plan = kw.OrbPlan(device, h, w, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH)
    plan.run(src)
    plan.run(src)
    t_graph = None
    if plan.captured.graph is not None:
        t_graph = median_ms(lambda: wp.capture_launch(plan.captured.graph), device, repeat, inner=20)
    n_kp = int(plan.read_head()[kw.C_FINAL])
    print(f"\n== {w}x{h}: {n_kp} keypoints, candidates {int(plan.read_head()[kw.C_CAND])} "
          f"(capacity {plan.cand_cap}), OpenCV threads {cv2.getNumThreads()} ==")
    print(f"{'end to end, per call':48s} {'ms':>8s} {'vs OpenCV':>10s}")
    rows = [("OpenCV ORB_create(2000).detectAndCompute", t_cv),
            ("before: host quadtree, per-level launches", t_before),
            ("after: warpvx.orb (device in/out, 1 sync)", t_after)]
    if t_graph is not None:
        rows.append(("after: the graph alone (GPU per frame)", t_graph))
    for name, t in rows:
        print(f"{name:48s} {t:8.3f} {t_cv / t:9.1f}x")
    print(f"host syncs per call: before {c_before.count}, after {c_after.count}")
    print(f"\n{'before, per stage (eager, synced)':48s} {'ms':>8s}")
    b = before_stages(src, repeat)
    for name, t in b:
        print(f"  {name:46s} {t:8.3f}")
    print(f"  {'sum':46s} {sum(t for _, t in b):8.3f}")
    a, host = after_stages(plan, src, repeat)
    label = "after, per stage (own graph: GPU)" if plan.device.is_cuda else "after, per stage"
    print(f"\n{label:48s} {'ms':>8s}")
    for name, t in a:
        print(f"  {name:46s} {t:8.3f}")
    print(f"  {'sum':46s} {sum(t for _, t in a):8.3f}")
    for name, t in host:
        print(f"  {name:46s} {t:8.3f}")
    if plan.device.is_cuda:
        slowest = max(a + host[:1] + host[2:], key=lambda r: r[1])
        print(f"\npipelined, slowest stage: {slowest[0]} {slowest[1]:.3f} ms -> "
              f"{1e3 / slowest[1]:.0f} FPS")
        if profile:
            profile_call(plan, src)
        for k in (1, 4):
            fps = pipelined(src, device, k, 400)
            print(f"pipelined, measured: {k} plan(s) on {k} stream(s), graphs back to back: "
                  f"{fps:.0f} FPS")


def cpu_backend(size, repeat):
    """The NumPy/OpenCV implementation (kernels_cpu) against cv2 on the same photo."""
    img = photo("astronaut", size)
    det = cv2.ORB_create(N_FEATURES, SCALE, LEVELS)
    t_cv = median_ms(lambda: det.detectAndCompute(img, None), "cpu", repeat)
    t_np = median_ms(lambda: warpvx.orb(img, N_FEATURES, SCALE, LEVELS, INI_TH, MIN_TH,
                                        backend="cpu"), "cpu", repeat)
    print(f"cpu backend {size[0]}x{size[1]}: {t_np:.2f} ms, OpenCV {t_cv:.2f} ms "
          f"({t_cv / t_np:.2f}x)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda" if wp.is_cuda_available() else "cpu")
    ap.add_argument("--sizes", nargs="+", default=["1920x1080", "1241x376"])
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--no-check", action="store_true")
    ap.add_argument("--random", type=int, default=0, help="also check N synthetic cases")
    ap.add_argument("--cpu", nargs="*", default=None, metavar="WxH",
                    help="also time the cpu backend (default size 640x360)")
    ap.add_argument("--profile", action="store_true",
                    help="per-kernel GPU times and a host profile of the public call (CUDA)")
    args = ap.parse_args(argv)
    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes]
    wp.init()
    dev = wp.get_device(args.device)
    print(f"device {dev} ({getattr(dev, 'name', '')}), cv2 {cv2.__version__}, "
          f"warp {wp.__version__}")
    if not args.no_check:
        print("exactness, after against before:")
        ok = check(args.device, sizes)
        if args.random:
            ok &= check_random(args.device, args.random)
        if not ok:
            print("CHECK FAILED")
    if args.cpu is not None:
        for spec in args.cpu or ["640x360"]:
            cpu_backend(tuple(int(v) for v in spec.lower().split("x")), max(5, args.repeat // 3))
    for size in sizes:
        try:
            run_size(args.device, size, args.repeat, args.profile)
        except Exception as exc:  # noqa: BLE001 - report and go on with the next size
            import traceback

            traceback.print_exc()
            print(f"{size}: failed: {exc!r}")


if __name__ == "__main__":
    main()
