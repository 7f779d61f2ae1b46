"""GPU micro-benchmark of the Warp separable filters and pyramids (gaussian_blur,
gaussian_pyramid, scale_pyramid) against the memory-bandwidth floor and CV-CUDA.

Usage, from the repository root on a CUDA machine::

    PYTHONPATH=. python3 benchmarks/perf/filtering.py [--sizes 1920x1080,1241x376]
        [--variants] [--quick] [--out DIR]

For each case and size it prints, per call: ``api`` (the public function with ``out=``, batches
of back-to-back calls, as ``warpvx bench`` times it), ``kernel`` (the ``kernels_warp`` function
with ``out=``, i.e. without the public validation), ``graph`` (the public call replayed from a
captured CUDA graph: device time only), the floor ``bytes read + written / bandwidth``,
graph/floor, and the first H200 figures (before this rewrite) and CV-CUDA's from
``benchmarks/results/gpu-h200-first``. ``--variants`` also times (in a graph) the kernel
shapes the implementation chooses between: output rows per thread, fused against two-pass,
resize rows per thread; and a trivial one-byte-per-thread Warp copy kernel (the launch floor).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass

import numpy as np
import warp as wp

import warpvx
from warpvx.bench import Settings, copy_bandwidth, load_photo, photo_at, time_graph, time_per_call_s
from warpvx.kernels_warp import _filtering, _launch, scale_pyramid as ksp
from warpvx.kernels_warp.gaussian_blur import gaussian_blur as k_blur
from warpvx.kernels_warp.gaussian_pyramid import gaussian_pyramid as k_pyramid
from warpvx.pyramid import gaussian_pyramid_sizes, scale_pyramid_sizes

DEVICE = "cuda:0"

#: First H200 run (benchmarks/results/gpu-h200-first/bench.log): (api per call, graph) in us,
#: and CV-CUDA per call, by (case, size).
BEFORE = {
    ("blur 5x5 s1 gray", "1920x1080"): (187.6, 187.0, 23.6),
    ("blur 7x7 s2 gray", "1920x1080"): (266.1, 265.2, 31.6),
    ("blur 5x5 s1 BGR", "1920x1080"): (553.6, 552.6, 37.5),
    ("pyramid 4 gray", "1920x1080"): (83.6, 82.0, None),
    ("pyrDown BGR", "1920x1080"): (149.3, 148.3, None),
    ("scale pyr 8 x1.2", "1920x1080"): (141.6, 46.3, 63.8),
    ("blur 5x5 s1 gray", "1241x376"): (48.3, 47.9, 9.3),
    ("blur 7x7 s2 gray", "1241x376"): (70.7, 70.2, 10.6),
    ("blur 5x5 s1 BGR", "1241x376"): (137.8, 137.1, 14.5),
    ("pyramid 4 gray", "1241x376"): (63.8, 38.4, None),
    ("pyrDown BGR", "1241x376"): (51.3, 49.9, None),
    ("scale pyr 8 x1.2", "1241x376"): (231.2, 20.5, 67.5),
}


@wp.kernel
def copy_bytes(src: wp.array2d(dtype=wp.uint8), dst: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    dst[y, x] = src[y, x]


@wp.kernel
def copy_bytes_1d(src: wp.array(dtype=wp.uint8), dst: wp.array(dtype=wp.uint8)):
    i = wp.tid()
    dst[i] = src[i]


@wp.kernel
def copy_words(src: wp.array2d(dtype=wp.uint32), dst: wp.array2d(dtype=wp.uint32)):
    y, x = wp.tid()
    dst[y, x] = src[y, x]


def run_probe(settings) -> None:
    """Diagnostics: copy kernels (2-D and 1-D launches, bytes and words) in a graph, before and
    after a second of load (clock ramp), and the registers / local memory of the compiled
    filter kernels (through CuPy, when present)."""
    import glob
    import re
    import time

    h, w = 1080, 1920
    a = wp.zeros((h, w), dtype=wp.uint8, device=DEVICE)
    b = wp.empty_like(a)
    a1, b1 = a.flatten(), b.flatten()
    aw = wp.zeros((h, w // 4), dtype=wp.uint32, device=DEVICE)
    bw = wp.empty_like(aw)
    cases = make_cases(photo_at(load_photo(), (w, h)))
    fns = {
        "copy u8 2-D": lambda: wp.launch(copy_bytes, dim=a.shape, inputs=[a], outputs=[b]),
        "copy u8 1-D": lambda: wp.launch(copy_bytes_1d, dim=a1.shape, inputs=[a1], outputs=[b1]),
        "copy u32 2-D": lambda: wp.launch(copy_words, dim=aw.shape, inputs=[aw], outputs=[bw]),
        "wp.copy 2 MB": lambda: wp.copy(b, a),
        "blur 5x5 gray": cases["blur 5x5 s1 gray"].kernel,
    }
    for phase in ("cold", "after 1 s load"):
        if phase != "cold":
            fn = _on_device(cases["blur 5x5 s1 gray"].kernel)
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < 1.0:
                for _ in range(50):
                    fn()
                _sync()
        for name, fn in fns.items():
            t = _graph(_on_device(fn), settings) * 1e6
            print(f"  probe {phase:15} {name:14} {t:7.1f} us", flush=True)
    try:
        import cupy
    except ImportError:
        print("  (no cupy: no register counts)")
        return
    for path in sorted(glob.glob(os.path.expanduser("~/.cache/warp/*/wp_*fused*/*.cubin"))
                       + glob.glob(os.path.expanduser("~/.cache/warp/*/wp___main__*/*.cubin"))
                       + glob.glob(os.path.expanduser("~/.cache/warp/*/wp_*resize*/*.cubin"))):
        src = glob.glob(os.path.join(os.path.dirname(path), "*.cu"))
        names = re.findall(r"__global__ void\s+(?:__launch_bounds__\([^)]*\)\s*)?(\w+_cuda_kernel_forward)",
                           open(src[0]).read()) if src else []
        try:
            mod = cupy.RawModule(path=path)
            for n in names:
                f = mod.get_function(n)
                print(f"  {os.path.basename(os.path.dirname(path))[:60]:60} regs {f.num_regs:3} "
                      f"local {f.local_size_bytes:5} B", flush=True)
        except Exception as e:  # diagnostics only
            print("  ", os.path.basename(path), type(e).__name__, e)


def _levels(img, sizes):
    return [wp.empty((h, w) + img.shape[2:], dtype=wp.uint8, device=DEVICE) for w, h in sizes[1:]]


def _pyramid_bytes(img, sizes):
    per_pixel = img.nbytes // (img.shape[0] * img.shape[1])
    areas = [w * h for w, h in sizes]
    return per_pixel * sum(areas[i - 1] + areas[i] for i in range(1, len(areas)))


@dataclass
class Case:
    """One timed call: the public function (``api``) and the ``kernels_warp`` one (``kernel``)
    on buffers allocated once; ``check()`` compares the outputs with OpenCV's (bit-exact)."""

    label: str
    api: object
    kernel: object
    nbytes: int
    outputs: list
    refs: list

    def check(self) -> bool:
        _sync()
        return all(np.array_equal(o.numpy(), r) for o, r in zip(self.outputs, self.refs))


def make_cases(photo: np.ndarray) -> dict:
    """The benchmark cases at ``photo``'s size, by label."""
    import cv2

    gray = np.ascontiguousarray(cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY))
    backend = "warp-cpu" if DEVICE == "cpu" else DEVICE
    cases = []
    for label, img, k, s in (("blur 5x5 s1 gray", gray, 5, 1.0), ("blur 7x7 s2 gray", gray, 7, 2.0),
                             ("blur 5x5 s1 BGR", photo, 5, 1.0), ("blur 15x15 s3 gray", gray, 15, 3.0)):
        src = wp.array(img, dtype=wp.uint8, device=DEVICE)
        out = wp.empty_like(src)
        cases.append(Case(label,
                          lambda src=src, out=out, k=k, s=s: warpvx.gaussian_blur(src, k, s, out=out, backend=backend),
                          lambda src=src, out=out, k=k, s=s: k_blur(src, (k, k), (s, s), "reflect101", out=out),
                          2 * img.nbytes, [out],
                          [cv2.GaussianBlur(img, (k, k), s, borderType=cv2.BORDER_REFLECT_101)]))
    for label, img, levels in (("pyramid 4 gray", gray, 4), ("pyrDown BGR", photo, 2)):
        sizes = gaussian_pyramid_sizes(img.shape[1], img.shape[0], levels)
        src = wp.array(img, dtype=wp.uint8, device=DEVICE)
        out = [src] + _levels(img, sizes)
        refs = [img]
        for _ in sizes[1:]:
            refs.append(cv2.pyrDown(refs[-1]))
        cases.append(Case(label,
                          lambda src=src, out=out, n=levels: warpvx.gaussian_pyramid(src, n, out=out, backend=backend),
                          lambda src=src, out=out, n=levels: k_pyramid(src, n, out=out),
                          _pyramid_bytes(img, sizes), out[1:], refs[1:]))
    sizes = scale_pyramid_sizes(gray.shape[1], gray.shape[0], 8, 1.2)
    src = wp.array(gray, dtype=wp.uint8, device=DEVICE)
    out = [src] + _levels(gray, sizes)
    refs = [gray]
    for size in sizes[1:]:
        refs.append(cv2.resize(refs[-1], size, interpolation=cv2.INTER_LINEAR))
    cases.append(Case("scale pyr 8 x1.2",
                      lambda: warpvx.scale_pyramid(src, 8, 1.2, out=out, backend=backend),
                      lambda: ksp.scale_pyramid(src, 8, 1.2, out=out),
                      _pyramid_bytes(gray, sizes), out[1:], refs[1:]))
    return {c.label: c for c in cases}


MAIN_CASES = ("blur 5x5 s1 gray", "blur 7x7 s2 gray", "blur 5x5 s1 BGR", "pyramid 4 gray", "pyrDown BGR",
              "scale pyr 8 x1.2")


def _us(v):
    return "-" if v is None else f"{v:.1f}"


def _sync():
    if DEVICE != "cpu":
        wp.synchronize_device(DEVICE)


def _on_device(fn):
    def call():
        with wp.ScopedDevice(DEVICE):
            fn()
    return call


def _graph(fn, settings):
    """Per-call seconds replayed from a CUDA graph (plain batches on the CPU device)."""
    if DEVICE == "cpu":
        return time_per_call_s(fn, _sync, settings=settings)[0]
    return time_graph(fn, DEVICE, settings=settings)


def run_main(sizes, settings, bandwidth, rows):
    print(f"\n{'case':18} {'size':10} {'api':>8} {'kernel':>8} {'graph':>8} {'floor':>7} {'g/floor':>7} "
          f"{'before api/graph':>17} {'cvcuda':>7} exact   (us per call)")
    for size in sizes:
        tag = f"{size[0]}x{size[1]}"
        cases = make_cases(photo_at(load_photo(), size))
        for label in MAIN_CASES:
            case = cases[label]
            t_api = time_per_call_s(case.api, _sync, settings=settings,
                                    min_calls=settings.gpu_min_calls)[0]
            t_kernel = time_per_call_s(_on_device(case.kernel), _sync, settings=settings,
                                       min_calls=settings.gpu_min_calls)[0]
            t_graph = _graph(case.api, settings)
            exact = case.check()
            floor = case.nbytes / bandwidth
            before = BEFORE.get((label, tag), (None, None, None))
            rows.append(dict(case=label, size=tag, api_us=t_api * 1e6, kernel_us=t_kernel * 1e6,
                             graph_us=t_graph * 1e6, floor_us=floor * 1e6, exact=exact,
                             before_api_us=before[0], before_graph_us=before[1], cvcuda_us=before[2]))
            print(f"{label:18} {tag:10} {t_api * 1e6:8.1f} {t_kernel * 1e6:8.1f} {t_graph * 1e6:8.1f} "
                  f"{floor * 1e6:7.2f} {t_graph / floor:7.1f} {_us(before[0]):>8}/{_us(before[1]):>8} "
                  f"{_us(before[2]):>7} {exact}", flush=True)


#: Kernel shapes tried per (stride, channels): (rows, pixels) per thread, and the cases timed.
SHAPES = {
    (1, 1): (("blur 5x5 s1 gray", "blur 7x7 s2 gray"), ((8, 4), (16, 4), (8, 2))),
    (1, 3): (("blur 5x5 s1 BGR",), ((8, 2), (8, 1), (16, 2))),
    (2, 1): (("pyramid 4 gray",), ((8, 1), (8, 2), (16, 1))),
    (2, 3): (("pyrDown BGR",), ((8, 1), (16, 1))),
}


def _time_variant(case, settings):
    _launch.clear_recorded()  # recorded launches hold the previous kernel shape
    t = _graph(_on_device(case.kernel), settings) * 1e6
    return t, case.check()


def _sweep(name, options, set_option, labels, all_cases, settings, rows):
    """Time ``labels`` at every size under each option; print; return the exact option with
    the lowest sum of times relative to the best per (case, size)."""
    table = {}
    for option in options:
        set_option(option)
        times, exact = [], True
        for cases in all_cases.values():
            for label in labels:
                t, ok = _time_variant(cases[label], settings)
                times.append(t)
                exact &= ok
        table[option] = times if exact else None
        rows.append(dict(variant=name, option=str(option), cases=list(labels), graph_us=times, exact=exact))
        print(f"  {name:22} {str(option):10}" + " ".join(f"{t:7.1f}" for t in times) + f"  exact {exact}",
              flush=True)
    good = {o: t for o, t in table.items() if t is not None}
    best = [min(t[i] for t in good.values()) for i in range(len(next(iter(good.values()))))]
    choice = min(good, key=lambda o: sum(t / b for t, b in zip(good[o], best)))
    set_option(choice)
    return choice


def run_variants(sizes, settings, rows) -> None:
    """Time the kernel shapes in a graph at every size, check each is exact, and keep the
    fastest exact choice of every knob."""
    all_cases = {f"{w}x{h}": make_cases(photo_at(load_photo(), (w, h))) for w, h in sizes}
    print("\nvariants (graph, us per call; columns: cases x sizes " + ", ".join(all_cases) + ")")
    for tag, cases in all_cases.items():
        gray = cases["blur 5x5 s1 gray"].outputs[0]
        dst = wp.empty_like(gray)
        t = _graph(_on_device(lambda: wp.launch(copy_bytes, dim=gray.shape, inputs=[gray], outputs=[dst])),
                   settings) * 1e6
        print(f"  warp u8 copy kernel, one byte per thread, {tag}: {t:.1f}")
        rows.append(dict(variant="copy kernel", size=tag, graph_us=t))
    F = _filtering
    for key, (labels, shapes) in SHAPES.items():
        def set_shape(rp, key=key):
            F.ROWS_PER_THREAD[key], F.PIXELS_PER_THREAD[key] = rp
        _sweep(f"rows,pixels s{key[0]} c{key[1]}", shapes, set_shape, labels, all_cases, settings, rows)
    for stride in (1, 2):  # four channels follow three
        F.ROWS_PER_THREAD[(stride, 4)] = F.ROWS_PER_THREAD[(stride, 3)]
        F.PIXELS_PER_THREAD[(stride, 4)] = F.PIXELS_PER_THREAD[(stride, 3)]
    # Fused up to radius 7 against two-pass from radius 3 (7x7) on.
    _sweep("fused max radius", (7, 2), lambda r: setattr(F, "FUSED_MAX_RADIUS", r),
           ("blur 7x7 s2 gray", "blur 15x15 s3 gray"), all_cases, settings, rows)
    _sweep("resize rows", (2, 4, 8), lambda r: setattr(ksp, "RESIZE_ROWS", r),
           ("scale pyr 8 x1.2",), all_cases, settings, rows)
    _sweep("min threads", (32768, 0, 65536), lambda n: setattr(F, "MIN_THREADS", n),
           MAIN_CASES, all_cases, settings, rows)
    _launch.clear_recorded()


def apply_config(config: dict) -> None:
    """Set the knobs from ``{"rows": {"1,1": 8, ...}, "pixels": {...}, "fused_max_radius": 4,
    "resize_rows": 4, "min_threads": 65536}``."""
    for name, table in (("rows", _filtering.ROWS_PER_THREAD), ("pixels", _filtering.PIXELS_PER_THREAD)):
        for k, v in config.get(name, {}).items():
            table[tuple(int(x) for x in k.split(","))] = int(v)
    if "fused_max_radius" in config:
        _filtering.FUSED_MAX_RADIUS = int(config["fused_max_radius"])
    if "resize_rows" in config:
        ksp.RESIZE_ROWS = int(config["resize_rows"])
    if "min_threads" in config:
        _filtering.MIN_THREADS = int(config["min_threads"])
    _launch.clear_recorded()


def current_config() -> dict:
    return {"rows": {f"{a},{b}": v for (a, b), v in _filtering.ROWS_PER_THREAD.items()},
            "pixels": {f"{a},{b}": v for (a, b), v in _filtering.PIXELS_PER_THREAD.items()},
            "fused_max_radius": _filtering.FUSED_MAX_RADIUS, "resize_rows": ksp.RESIZE_ROWS,
            "min_threads": _filtering.MIN_THREADS}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1920x1080,1241x376")
    parser.add_argument("--variants", action="store_true",
                        help="time the kernel shapes first and run the main table with the fastest")
    parser.add_argument("--config", default=None, help="JSON of knobs (see apply_config) for the main table")
    parser.add_argument("--save-config", default=None, help="write the knobs used (JSON) to this file")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--probe", action="store_true", help="diagnostics only (see run_probe)")
    parser.add_argument("--out", default=os.environ.get("OUT"))
    parser.add_argument("--device", default="cuda:0", help="cuda:N, or cpu for a dry run (no graphs)")
    args = parser.parse_args(argv)
    global DEVICE
    DEVICE = args.device
    wp.config.quiet = True
    wp.init()
    if DEVICE != "cpu" and not wp.is_cuda_available():
        print("no CUDA device", file=sys.stderr)
        return 1
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    settings = (Settings(repeat=3, warmup=2, min_batch_s=0.01, gpu_min_calls=50, graph_calls=10) if args.quick
                else Settings(repeat=5, warmup=3, min_batch_s=0.03, gpu_min_calls=100, graph_calls=10))
    quick = Settings(repeat=3, warmup=2, min_batch_s=0.01, gpu_min_calls=20, graph_calls=10)
    bandwidth = copy_bandwidth(DEVICE, nbytes=64 << 20, settings=quick)
    print(f"{wp.get_device(DEVICE).name}; device-to-device copy {bandwidth / 1e9:.0f} GB/s (read + write)")
    rows = []
    if args.config:
        apply_config(json.loads(args.config))
    if args.probe:
        run_probe(quick)
        return 0
    if args.variants:
        run_variants(sizes, quick, rows)
    config = current_config()
    print("config:", json.dumps(config, separators=(",", ":")))
    if args.save_config:
        with open(args.save_config, "w") as f:
            json.dump(config, f)
    run_main(sizes, settings, bandwidth, rows)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "filtering.json"), "w") as f:
            json.dump(dict(bandwidth=bandwidth, config=config, rows=rows), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
