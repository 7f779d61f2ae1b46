"""The benchmark harness behind ``warpvx bench``: warpvx against OpenCV (and GPU peers).

For every registered primitive with benchmark cases (``warpvx.registry.Primitive.bench``) and
every size, the harness builds the cases from a real photo (scikit-image's astronaut, or the
bundled ``warpvx/data/astronaut_448.png``) resized to that size, then times each case on every
requested backend, on OpenCV (all cores) and on the peers that import (CV-CUDA, Kornia):

- warm-up calls first, so Warp's JIT compilation and first-touch allocations are excluded;
- a batch of N calls between two device synchronisations; the per-call time is the batch time
  over N, and the reported figure is the median over ``--repeat`` batches (N is chosen so a
  batch lasts a few milliseconds; on CUDA at least 100 calls, the way per-call GPU figures are
  usually quoted);
- with ``--graph``, cases that declare ``bytes_moved`` are also captured into a CUDA graph
  (``wp.ScopedCapture``) and replayed with ``wp.capture_launch``, and compared with the
  memory-bandwidth floor ``bytes_moved / bandwidth``, the bandwidth being a device-to-device
  copy measured in the same run.

Results are printed as a table, written as JSON (with machine information) and, when
matplotlib is installed, drawn as a bar chart (log time per case and implementation).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

DEFAULT_SIZES = ((1920, 1080), (1241, 376))
DEFAULT_OUT = Path("benchmarks") / "results"
PEERS = ("cvcuda", "kornia")


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


@dataclass
class Result:
    """One timed implementation of one case."""

    primitive: str
    case: str
    size: str
    impl: str
    per_call_s: float | None = None
    calls_per_batch: int | None = None
    speedup_vs_opencv: float | None = None
    graph_per_call_s: float | None = None
    floor_s: float | None = None
    graph_over_floor: float | None = None
    bytes_moved: int | None = None
    note: str | None = None


@dataclass
class Report:
    machine: dict
    settings: dict
    sizes: list
    backends: list
    copy_bandwidth_gbps: dict = field(default_factory=dict)
    results: list = field(default_factory=list)
    notes: list = field(default_factory=list)


# --- inputs ---------------------------------------------------------------------------------


def load_photo() -> np.ndarray:
    """The benchmark photo, BGR uint8: scikit-image's astronaut, else the bundled copy."""
    import cv2

    try:
        from skimage import data

        return np.ascontiguousarray(cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2BGR))
    except ImportError:
        path = Path(__file__).resolve().parent / "data" / "astronaut_448.png"
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"bundled benchmark image missing: {path}") from None
        return img


def photo_at(photo: np.ndarray, size) -> np.ndarray:
    """``photo`` resized to (width, height), BGR uint8, C-contiguous."""
    import cv2

    w, h = size
    interp = cv2.INTER_AREA if w * h < photo.shape[0] * photo.shape[1] else cv2.INTER_CUBIC
    return np.ascontiguousarray(cv2.resize(photo, (w, h), interpolation=interp))


# --- timing ---------------------------------------------------------------------------------


def _no_sync():
    return None


def time_call(fn, sync=_no_sync, *, settings: Settings, min_calls: int = 1, calls: int | None = None,
              issue_only: bool = False) -> tuple[float, int]:
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
    replays are timed by :func:`time_call` (``calls`` replays a batch when given)."""
    wp = _warp()
    with wp.ScopedDevice(device):
        fn()
        wp.synchronize_device(device)
        with wp.ScopedCapture(device=device) as capture:
            for _ in range(settings.graph_calls):
                fn()
        graph = capture.graph

        def replay():
            wp.capture_launch(graph)

        per_launch, _ = time_call(replay, lambda: wp.synchronize_device(device), settings=settings,
                                  min_calls=max(1, settings.gpu_min_calls // settings.graph_calls),
                                  calls=calls)
    return per_launch / settings.graph_calls


def copy_bandwidth(device: str, *, nbytes: int = 256 << 20, settings: Settings) -> float:
    """Device-to-device copy bandwidth in bytes/s (bytes read plus bytes written per second)."""
    wp = _warp()
    src = wp.zeros(nbytes, dtype=wp.uint8, device=device)
    dst = wp.empty(nbytes, dtype=wp.uint8, device=device)
    per_copy, _ = time_call(lambda: wp.copy(dst, src), lambda: wp.synchronize_device(device),
                            settings=settings, min_calls=10)
    return 2 * nbytes / per_copy


def _warp():
    from .backend import init_warp

    return init_warp()


def _sync_for(backend_name: str):
    if backend_name == "cpu":
        return _no_sync
    wp = _warp()
    device = _device_of(backend_name)
    return lambda: wp.synchronize_device(device)


def _sync_peers():
    """Synchronise every CUDA context (peers run on their own streams)."""
    from .backend import cuda_available

    if cuda_available():
        _warp().synchronize()
        return
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        if torch.cuda.is_available():
            torch.cuda.synchronize()


def _device_of(backend_name: str) -> str:
    from .backend import resolve_backend

    return resolve_backend(backend_name).device


# --- the run --------------------------------------------------------------------------------


def collect_cases(primitives, sizes, photo, notes):
    """``[(size, BenchCase)]`` for the selected primitives; a missing module or bench function
    is skipped with a note."""
    from .registry import REGISTRY, _load

    cases = []
    for name in primitives:
        prim = REGISTRY[name]
        if prim.bench is None:
            continue
        try:
            bench_fn = _load(prim.bench)
        except (ImportError, AttributeError) as exc:
            notes.append(f"{name}: skipped, no bench cases yet ({prim.bench}: {exc})")
            continue
        except Exception as exc:  # noqa: BLE001 - a module that fails to import is skipped too
            notes.append(f"{name}: skipped, {prim.bench} failed to load: {exc!r}")
            continue
        for size in sizes:
            try:
                made = bench_fn(photo_at(photo, size))
            except Exception as exc:  # noqa: BLE001 - one broken case must not stop the run
                notes.append(f"{name} {size[0]}x{size[1]}: bench cases failed: {exc!r}")
                continue
            cases.extend((size, c) for c in made)
    return cases


def run(*, primitives=None, sizes=DEFAULT_SIZES, backends=None, settings: Settings | None = None,
        graph=False, peers=True, progress=True) -> Report:
    """Time every case; see the module docstring. Returns the :class:`Report`."""
    import cv2

    from .backend import available_backends, cuda_available
    from .registry import REGISTRY

    settings = settings or Settings()
    cv2.setNumThreads(os.cpu_count() or 1)
    if primitives is None:
        primitives = [n for n, p in REGISTRY.items() if p.bench is not None]
    if backends is None:
        backends = ["cpu"] + (["cuda"] if cuda_available() else [])
    notes: list[str] = []
    usable = []
    available = available_backends()
    for b in backends:
        if b in available or (b == "cuda" and any(a.startswith("cuda") for a in available)):
            usable.append(b)
        else:
            notes.append(f"backend {b!r} is not available here; skipped")
    report = Report(machine=machine_info(), settings=asdict(settings),
                    sizes=[f"{w}x{h}" for w, h in sizes], backends=usable, notes=notes)
    cuda_backends = [b for b in usable if b.startswith("cuda")]
    warp_backends = [b for b in usable if b != "cpu"]
    if graph and warp_backends:
        for b in warp_backends:
            dev = _device_of(b)
            report.copy_bandwidth_gbps[dev] = copy_bandwidth(
                dev, nbytes=(256 << 20) if dev != "cpu" else (64 << 20), settings=settings) / 1e9
    elif graph:
        notes.append("--graph: no Warp backend (cuda, warp-cpu), graph timings skipped")

    photo = load_photo()
    cases = collect_cases(primitives, sizes, photo, notes)
    peer_names = [p for p in PEERS if peers and cuda_backends]
    tasks = [(size, case, impl) for size, case in cases
             for impl in ["opencv"] + usable + peer_names]
    bar = _progress(len(tasks), progress)
    missing_peers = set()
    for size, case in cases:
        rows = {}
        for impl in ["opencv"] + usable + peer_names:
            bar.set_description(f"{case.primitive} {case.label} {impl}"[:60])
            res = Result(case.primitive, case.label, f"{size[0]}x{size[1]}", impl,
                         bytes_moved=case.bytes_moved)
            try:
                if impl == "opencv":
                    if case.opencv is None:
                        bar.update()
                        continue
                    res.per_call_s, res.calls_per_batch = time_call(case.opencv(), settings=settings)
                elif impl in PEERS:
                    if impl not in case.peers or impl in missing_peers:
                        bar.update()
                        continue
                    try:
                        fn = case.peers[impl]()
                    except ImportError as exc:
                        missing_peers.add(impl)
                        notes.append(f"peer {impl}: not importable ({exc}); skipped")
                        bar.update()
                        continue
                    res.per_call_s, res.calls_per_batch = time_call(
                        fn, _sync_peers, settings=settings, min_calls=settings.gpu_min_calls)
                else:
                    fn = case.prepare(impl)
                    is_gpu = impl.startswith("cuda")
                    res.impl = impl if impl != "cuda" else _device_of(impl)
                    res.per_call_s, res.calls_per_batch = time_call(
                        fn, _sync_for(impl), settings=settings,
                        min_calls=settings.gpu_min_calls if is_gpu else 1)
                    if graph and impl != "cpu" and case.bytes_moved:
                        dev = _device_of(impl)
                        try:
                            res.graph_per_call_s = time_graph(fn, dev, settings=settings)
                            bw = report.copy_bandwidth_gbps.get(dev)
                            if bw:
                                res.floor_s = case.bytes_moved / (bw * 1e9)
                                res.graph_over_floor = res.graph_per_call_s / res.floor_s
                        except Exception as exc:  # noqa: BLE001 - e.g. a call that cannot be captured
                            res.note = f"graph capture failed: {exc!r}"
            except Exception as exc:  # noqa: BLE001 - report and go on with the next case
                res.note = f"failed: {exc!r}"
            rows[impl] = res
            report.results.append(res)
            bar.update()
        ref = rows.get("opencv")
        if ref is not None and ref.per_call_s:
            for r in rows.values():
                if r.per_call_s:
                    r.speedup_vs_opencv = ref.per_call_s / r.per_call_s
    bar.close()
    for extra in ("torch", "cvcuda", "kornia"):
        mod = sys.modules.get(extra)
        if mod is not None:
            report.machine["versions"][extra] = getattr(mod, "__version__", "?")
    return report


def _progress(total, enabled):
    if enabled:
        try:
            from tqdm import tqdm

            return tqdm(total=total, unit="run", leave=False, file=sys.stderr)
        except ImportError:
            pass

    class _Silent:
        def update(self, n=1):
            pass

        def set_description(self, s):
            pass

        def close(self):
            pass

    return _Silent()


# --- machine information --------------------------------------------------------------------


def machine_info() -> dict:
    """CPU model and cores, GPU name, library versions."""
    import cv2

    import warpvx

    info = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_model": _cpu_model(),
        "cpu_cores": os.cpu_count(),
        "opencv_threads": cv2.getNumThreads(),
        "gpus": [],
        "versions": {"warpvx": warpvx.__version__, "numpy": np.__version__, "opencv": cv2.__version__},
    }
    try:
        wp = _warp()
        info["versions"]["warp"] = wp.config.version
        for i in range(wp.get_cuda_device_count()):
            dev = wp.get_device(f"cuda:{i}")
            info["gpus"].append({"device": f"cuda:{i}", "name": dev.name,
                                 "memory_gib": round(dev.total_memory / 2**30, 1)})
    except Exception as exc:  # noqa: BLE001 - machine info is best effort
        info["warp_error"] = repr(exc)
    return info


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


# --- output ---------------------------------------------------------------------------------


def _fmt_time(s):
    if s is None:
        return "-"
    if s < 1e-3:
        return f"{s * 1e6:.1f} us"
    if s < 1:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def format_table(report: Report) -> str:
    """The results as a fixed-width text table."""
    head = ["primitive", "case", "size", "impl", "per call", "vs OpenCV", "graph", "floor", "graph/floor"]
    rows = []
    for r in report.results:
        rows.append([
            r.primitive, r.case, r.size, r.impl,
            _fmt_time(r.per_call_s) if r.note is None or r.per_call_s else (r.note[:40]),
            "-" if r.speedup_vs_opencv is None else f"{r.speedup_vs_opencv:.2f}x",
            _fmt_time(r.graph_per_call_s), _fmt_time(r.floor_s),
            "-" if r.graph_over_floor is None else f"{r.graph_over_floor:.2f}",
        ])
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in rows]
    return "\n".join(lines)


def write_json(report: Report, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = asdict(report)
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return path


def _short(text, n=48):
    return text if len(text) <= n else text[: n - 3] + "..."


def write_plot(report: Report, path: Path) -> Path | None:
    """Horizontal grouped bars of log time per call: one panel per size, one group per case,
    one bar per implementation. None without matplotlib or timings."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    timed = [r for r in report.results if r.per_call_s]
    if not timed:
        return None
    values = {(r.primitive, r.case, r.size, r.impl): r.per_call_s for r in timed}
    values.update({(r.primitive, r.case, r.size, f"{r.impl} graph"): r.graph_per_call_s
                   for r in timed if r.graph_per_call_s})
    impls = list(dict.fromkeys(k[3] for k in values))
    sizes = list(dict.fromkeys(r.size for r in timed))
    per_size = {sz: list(dict.fromkeys((r.primitive, r.case) for r in timed if r.size == sz)) for sz in sizes}
    bar_h = 0.8 / len(impls)
    heights = [max(2.0, 0.22 * len(per_size[sz]) * max(2, len(impls))) for sz in sizes]
    fig, axes = plt.subplots(len(sizes), 1, figsize=(10, sum(heights) + 1.0),
                             gridspec_kw={"height_ratios": heights}, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, sz in zip(axes[:, 0], sizes):
        cases = per_size[sz]
        for i, impl in enumerate(impls):
            ys, xs = [], []
            for j, (prim, case) in enumerate(cases):
                v = values.get((prim, case, sz, impl))
                if v:
                    ys.append(j + (i - (len(impls) - 1) / 2) * bar_h)
                    xs.append(v * 1e6)
            ax.barh(ys, xs, height=bar_h, label=impl, color=colors[i % len(colors)])
        ax.set_xscale("log")
        ax.set_yticks(range(len(cases)))
        ax.set_yticklabels([_short(f"{prim}: {case}") for prim, case in cases], fontsize=7)
        ax.invert_yaxis()
        ax.set_title(sz, fontsize=9)
        ax.grid(axis="x", which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("time per call (us, log scale; shorter is faster)")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    gpus = ", ".join(g["name"] for g in report.machine.get("gpus", [])) or "no GPU"
    fig.suptitle(f"warpvx bench: {report.machine.get('cpu_model', '?')} "
                 f"({report.machine.get('cpu_cores')} cores), {gpus}", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# --- command line ---------------------------------------------------------------------------


def _split_list(values):
    out = []
    for v in values or []:
        out += [p for p in v.split(",") if p.strip()]
    return [p.strip() for p in out]


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        w, h = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--sizes: expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"--sizes: expected positive sizes, got {text!r}")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``warpvx bench``'s options to ``parser``."""
    parser.add_argument("--sizes", nargs="+", metavar="WxH",
                        help="image sizes (default: 1920x1080 1241x376); comma or space separated")
    parser.add_argument("--primitives", nargs="+", metavar="NAME",
                        help="registered primitives to time (default: all with bench cases)")
    parser.add_argument("--backends", nargs="+", metavar="NAME",
                        help="warpvx backends: cpu, warp-cpu (slow), cuda, cuda:N "
                             "(default: cpu, plus cuda when present)")
    parser.add_argument("--repeat", type=int, default=None, help="timed batches per measurement (median)")
    parser.add_argument("--quick", action="store_true",
                        help="fewer, shorter batches (a smoke run; timings are noisier)")
    parser.add_argument("--graph", action="store_true",
                        help="also time cases inside a captured graph (CUDA; Warp's CPU graphs for "
                             "warp-cpu) against the memory-bandwidth floor")
    parser.add_argument("--no-peers", action="store_true", help="skip CV-CUDA and Kornia")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="directory for the JSON and PNG (default: benchmarks/results/)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw the PNG chart")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main_from_args(args) -> int:
    """Run ``warpvx bench`` from parsed arguments; prints the table and the output paths."""
    from .registry import REGISTRY

    try:
        sizes = [parse_size(s) for s in _split_list(args.sizes)] or list(DEFAULT_SIZES)
    except argparse.ArgumentTypeError as exc:
        print(f"warpvx bench: {exc}", file=sys.stderr)
        return 2
    primitives = _split_list(args.primitives) or None
    if primitives:
        unknown = [p for p in primitives if p not in REGISTRY]
        if unknown:
            print(f"warpvx bench: unknown primitive(s) {unknown}; registered: {sorted(REGISTRY)}",
                  file=sys.stderr)
            return 2
    backends = _split_list(args.backends) or None
    if args.repeat is not None and args.repeat < 1:
        print("warpvx bench: --repeat must be >= 1", file=sys.stderr)
        return 2
    settings = Settings.quick(args.repeat) if args.quick else Settings(repeat=args.repeat or 7)
    report = run(primitives=primitives, sizes=sizes, backends=backends, settings=settings,
                 graph=args.graph, peers=not args.no_peers, progress=not args.no_progress)
    for note in report.notes:
        print(f"note: {note}")
    for r in report.results:
        if r.note:
            print(f"note: {r.primitive} {r.case} {r.size} {r.impl}: {r.note}")
    print(format_table(report))
    if report.copy_bandwidth_gbps:
        for dev, bw in report.copy_bandwidth_gbps.items():
            print(f"device-to-device copy bandwidth on {dev}: {bw:.0f} GB/s (read + write)")
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    json_path = write_json(report, Path(args.out) / f"bench-{stamp}.json")
    print(f"wrote {json_path}")
    if not args.no_plot:
        png = write_plot(report, Path(args.out) / f"bench-{stamp}.png")
        print(f"wrote {png}" if png else "matplotlib not installed: no plot")
    return 0


def main(argv=None) -> int:
    """``python -m warpvx.bench`` (same as ``warpvx bench``)."""
    parser = add_arguments(argparse.ArgumentParser(prog="warpvx bench", description=__doc__.split("\n\n")[0]))
    return main_from_args(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())


__all__ = [
    "DEFAULT_SIZES",
    "Report",
    "Result",
    "Settings",
    "add_arguments",
    "collect_cases",
    "copy_bandwidth",
    "format_table",
    "load_photo",
    "machine_info",
    "main",
    "main_from_args",
    "run",
    "time_call",
    "time_graph",
    "write_json",
    "write_plot",
]
