"""What ``warpvx bench`` reports: one :class:`Result` per timed implementation, the
:class:`Report` with machine information, and its text table, JSON and bar chart."""

from __future__ import annotations

import json
import os
import platform
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .timing import warp_module


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
    """A whole run: machine information, settings, sizes, backends, the measured copy
    bandwidth per device (GB/s), the :class:`Result` rows, notes on what was skipped, the
    input photo (:func:`~warpvx.bench.inputs.load_photo_with_source`) and what each
    implementation name stands for (:func:`describe_impl`)."""

    machine: dict
    settings: dict
    sizes: list
    backends: list
    copy_bandwidth_gbps: dict = field(default_factory=dict)
    results: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    photo: dict = field(default_factory=dict)
    impls: dict = field(default_factory=dict)


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
        wp = warp_module()
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

# --- what the rows are ----------------------------------------------------------------------

# impl -> (short name for the chart's legend, what the table's legend says)
_ROLES = {
    "opencv": ("OpenCV", "OpenCV (cv2) on all cores: the reference"),
    "cpu": ("warpvx cpu (NumPy/OpenCV)",
            "warpvx backend 'cpu': the NumPy/OpenCV implementation (warpvx.kernels_cpu, "
            "which calls OpenCV where it can), not Warp"),
    "warp-cpu": ("warpvx warp-cpu (Warp, CPU)",
                 "warpvx backend 'warp-cpu': the Warp kernels on Warp's CPU device "
                 "(single-threaded)"),
    "cvcuda": ("CV-CUDA", "CV-CUDA on the GPU (peer library)"),
    "kornia": ("Kornia", "Kornia on PyTorch CUDA (peer library)"),
}


def describe_impl(impl: str, machine: dict, *, short: bool = False) -> str:
    """What an implementation name in the results stands for (``short``: a few words, for
    the chart's legend). ``cuda:N`` names the GPU from ``machine["gpus"]``."""
    if impl in _ROLES:
        return _ROLES[impl][0 if short else 1]
    if impl.startswith("cuda"):
        gpu = next((g["name"] for g in machine.get("gpus", []) if g["device"] == impl), "GPU")
        return (f"warpvx {impl} (Warp, GPU)" if short
                else f"warpvx backend '{impl}': the Warp kernels on {gpu}")
    return impl


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
    """The results as a fixed-width text table, then a legend: what each implementation is
    and which way the ratios read. The graph columns appear only when a run has them."""
    graph = any(r.graph_per_call_s or r.floor_s for r in report.results)
    head = ["primitive", "case", "size", "impl", "per call", "vs OpenCV"]
    head += ["graph", "floor", "graph/floor"] if graph else []
    rows = []
    for r in report.results:
        row = [
            r.primitive, r.case, r.size, r.impl,
            _fmt_time(r.per_call_s) if r.note is None or r.per_call_s else (r.note[:40]),
            "-" if r.speedup_vs_opencv is None else f"{r.speedup_vs_opencv:.2f}x",
        ]
        if graph:
            row += [_fmt_time(r.graph_per_call_s), _fmt_time(r.floor_s),
                    "-" if r.graph_over_floor is None else f"{r.graph_over_floor:.2f}"]
        rows.append(row)
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in rows]
    lines.append("")
    name_w = max(map(len, report.impls), default=0)
    lines += [f"{impl.ljust(name_w)} = {text}" for impl, text in report.impls.items()]
    lines.append("vs OpenCV = speed-up = OpenCV time / this time; > 1 is faster than OpenCV")
    if graph:
        lines.append("graph = per call replayed from a captured graph; floor = bytes moved / "
                     "measured copy bandwidth; graph/floor: 1 is the memory-bandwidth limit")
    return "\n".join(lines)


def write_json(report: Report, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = asdict(report)
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return path


def write_plot(report: Report, path: Path) -> Path | None:
    """Draw :func:`plot_figure` into ``path`` (PNG); None without matplotlib or timings."""
    fig = plot_figure(report)
    if fig is None:
        return None
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_figure(report: Report):
    """Horizontal grouped bars of log time per call: one panel per size, one group per case,
    one bar per implementation (a matplotlib Figure; None without matplotlib or timings).

    Constrained layout keeps the title clear of the first panel and the case labels (in full:
    two cases of one primitive may differ only at the end) inside the figure; every panel
    carries its time axis label; the legend sits below the panels."""
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
    fig, axes = plt.subplots(len(sizes), 1, figsize=(11, sum(heights) + 1.5), layout="constrained",
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
            ax.barh(ys, xs, height=bar_h, label=_legend_label(impl, report.machine),
                    color=colors[i % len(colors)])
        ax.set_xscale("log")
        ax.set_yticks(range(len(cases)))
        ax.set_yticklabels([f"{prim}: {case}" for prim, case in cases], fontsize=7)
        ax.invert_yaxis()
        ax.set_title(f"input {sz}", fontsize=9)
        ax.set_xlabel("time per call (us, log scale; shorter is faster)", fontsize=8)
        ax.grid(axis="x", which="both", alpha=0.3)
    try:
        fig.legend(*axes[0, 0].get_legend_handles_labels(), fontsize=7,
                   loc="outside lower center", ncols=min(3, len(impls)))
    except ValueError:  # matplotlib < 3.7 has no "outside" locations
        axes[0, 0].legend(fontsize=7, loc="lower right")
    gpus = ", ".join(g["name"] for g in report.machine.get("gpus", [])) or "no GPU"
    photo = report.photo
    source = f"\ninput: {photo['name']} photo ({photo['size']}) resized to each size" if photo else ""
    fig.suptitle(f"warpvx bench: {report.machine.get('cpu_model', '?')} "
                 f"({report.machine.get('cpu_cores')} cores), {gpus}{source}", fontsize=9)
    return fig


def _legend_label(impl: str, machine: dict) -> str:
    if impl.endswith(" graph"):
        return f"{describe_impl(impl[:-len(' graph')], machine, short=True)} in a captured graph"
    return describe_impl(impl, machine, short=True)
