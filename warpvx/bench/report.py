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
    bandwidth per device (GB/s), the :class:`Result` rows and notes on what was skipped."""

    machine: dict
    settings: dict
    sizes: list
    backends: list
    copy_bandwidth_gbps: dict = field(default_factory=dict)
    results: list = field(default_factory=list)
    notes: list = field(default_factory=list)


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

