"""Device time of a two-camera frame's Harris corners, before / after (issue 11 item 3).

(A faster LK was tried with this bench on the H100 and measured 0.81x: reverted; see
benchmarks/results/graph/h100-2026-11-24-s4/harris_select.md.)

The graph bench's frames (``benchmarks/graph_bench.make_frames``: two cameras, 1280x720), its
Harris settings (500
corners, quality 0.01, min distance 7), each call captured as a CUDA graph and replayed (as
the graph executor replays them), timed with CUDA events: ``--repeat`` trials of
``--replays`` replays after a warm-up, the median trial per replay.

- Harris (:class:`~warpvx.kernels_warp.harris_counted.DeviceCorners`, a graph's Counted
  path): ``before`` is the launch geometry of 26f41cc on the current code (a thread per
  candidate slot, i.e. per pixel, for the per-candidate kernels; sentinels over the whole
  capacity; a 256-lane output scan), ``after`` the current one.

Also a per-kernel breakdown of one eager call of each (``wp.timing_begin``).

Run on the GPU machine from the repository root (< 2 min on an H100)::

    PYTHONPATH=. python3 benchmarks/perf/harris_select.py --out $OUT

``--device cpu`` runs it on Warp's CPU device (no capture; host wall time; a smoke test).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import statistics
import sys
import time
import traceback

import cv2
import numpy as np
import warp as wp

SIZE = (1280, 720)
POINTS = 500
HARRIS = dict(max_corners=POINTS, quality_level=0.01, min_distance=7)
COMMAND = "PYTHONPATH=. python3 benchmarks/perf/harris_select.py --out $OUT"


@contextlib.contextmanager
def patched(obj, **values):
    """Module attributes set for the block."""
    old = {k: getattr(obj, k) for k in values}
    for k, v in values.items():
        setattr(obj, k, v)
    try:
        yield
    finally:
        for k, v in old.items():
            setattr(obj, k, v)


class Timer:
    """Device time per call of ``fn`` on its own stream: captured and replayed on CUDA,
    called (host wall time) on the CPU."""

    def __init__(self, device, repeat: int, replays: int):
        self.device, self.repeat, self.replays = device, repeat, replays

    def __call__(self, fn) -> float:
        """Median seconds per call; ``fn`` has been called once (warm) by the caller."""
        dev = self.device
        if dev.is_cpu:
            trials = []
            for _ in range(self.repeat):
                t0 = time.perf_counter()
                for _ in range(self.replays):
                    fn()
                wp.synchronize_device(dev)
                trials.append((time.perf_counter() - t0) / self.replays)
            return statistics.median(trials)
        with wp.ScopedCapture(dev) as cap:
            fn()
        graph = cap.graph
        for _ in range(3):
            wp.capture_launch(graph)
        start = wp.Event(dev, enable_timing=True)
        end = wp.Event(dev, enable_timing=True)
        trials = []
        for _ in range(self.repeat):
            wp.record_event(start)
            for _ in range(self.replays):
                wp.capture_launch(graph)
            wp.record_event(end)
            wp.synchronize_event(end)
            trials.append(wp.get_event_elapsed_time(start, end) / 1e3 / self.replays)
        return statistics.median(trials)


def kernel_breakdown(fn, device, calls: int = 5) -> dict:
    """Device microseconds per call by kernel name over ``calls`` eager calls."""
    if device.is_cpu:
        return {}
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_KERNEL_BUILTIN, synchronize=True)
    for _ in range(calls):
        fn()
    results = wp.timing_end(synchronize=True)
    per = {}
    for r in results:
        name = re.sub(r"_[0-9a-f]{8}$", "", r.name.replace("forward kernel ", ""))
        per[name] = per.get(name, 0.0) + r.elapsed * 1e3 / calls
    return dict(sorted(per.items(), key=lambda kv: -kv[1]))


def frames(device):
    """Gray frames 0 and 1 of both cameras on ``device``."""
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from graph_bench import make_frames

    out = {}
    for cam in ("L", "R"):
        pair = [cv2.cvtColor(f[f"frame{cam}"], cv2.COLOR_BGR2GRAY) for f in make_frames(SIZE, 2)]
        out[cam] = [wp.array(g, dtype=wp.uint8, device=device) for g in pair]
    return out


def harris_rows(cams, device, timer) -> list:
    """Before/after rows of the Counted (capturable) Harris path, per camera."""
    from warpvx.kernels_warp import harris_corners as hc
    from warpvx.kernels_warp.harris_counted import DeviceCorners

    rows = []
    for cam, (gray, _) in cams.items():
        results = {}
        for name in ("before", "after"):
            print(f"  Harris {cam}: {name}", flush=True)
            old = name == "before"
            geometry = dict(CANDIDATE_THREADS=1 << 40, SCAN_BLOCK=256) if old else {}
            with patched(hc, **geometry):
                det = DeviceCorners(gray.shape, device, **HARRIS)
                if old:  # sentinels over the whole capacity, whatever the sort reads
                    det.sentinels.set(small=det.ws.capacity)

                def call():
                    det.launch(gray)
                call()
                wp.synchronize_device(device)
                t = timer(call)
                kernels = kernel_breakdown(call, device)
            count, _, rounds = (int(v) for v in det.result.numpy())
            results[name] = det.points.numpy()[:count]
            rows.append(dict(kernel="Harris", camera=cam, variant=name, points=count,
                             rounds=rounds,
                             us=t * 1e6, same=np.array_equal(results["before"], results[name]),
                             kernels=kernels))
    return rows


def markdown(rows, device, args) -> str:
    lines = [f"Regenerate: `{COMMAND}`", "",
             f"# Harris corners device time per call, {SIZE[0]}x{SIZE[1]}, {device.name}", "",
             f"{'captured graph replays' if not device.is_cpu else 'host wall time'}, "
             f"median of {args.repeat} trials of {args.replays} replays; `same`: outputs "
             "bit-identical to `before`.", "",
             "| kernel | camera | variant | points | us/call | x before | same | max dp px | "
             "status changes |", "|---|---|---|---|---|---|---|---|---|"]
    base = {(r["kernel"], r["camera"]): r["us"] for r in rows if r["variant"] == "before"}
    for r in rows:
        ratio = base[(r["kernel"], r["camera"])] / r["us"]
        moved = f"{r['max_dp']:.3g} | {r['status_changes']}" if "max_dp" in r else "- | -"
        lines.append(f"| {r['kernel']} | {r['camera']} | {r['variant']} | {r['points']} | "
                     f"{r['us']:.1f} | {ratio:.2f} | {'yes' if r['same'] else 'NO'} | {moved} |")
    lines += ["", "Two-camera frame (both cameras):", "",
              "| variant | us/frame |", "|---|---|"]
    for v in ("before", "after"):
        lines.append(f"| {v} | {sum(r['us'] for r in rows if r['variant'] == v):.1f} |")
    lines += ["", "## Kernels per eager call (us, camera L)", ""]
    for r in rows:
        if r["camera"] == "L" and r["kernels"]:
            rounds = f" ({r['rounds']} selection rounds had work)" if "rounds" in r else ""
            lines.append(f"- {r['kernel']} {r['variant']}{rounds}: " + ", ".join(
                f"{k} {v:.1f}" for k, v in list(r["kernels"].items())[:12]))
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda:0", help="cuda:N or cpu")
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--replays", type=int, default=50)
    ap.add_argument("--out", default=os.environ.get("OUT", "."))
    args = ap.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    timer = Timer(device, args.repeat, args.replays)
    t0 = time.time()
    cams = frames(device)
    rows, failures = [], []
    for name, part in (("Harris", harris_rows),):
        print(name, flush=True)
        try:
            rows += part(cams, device, timer)
        except Exception:  # noqa: BLE001 - one run on the GPU machine: keep the other part
            failures.append(f"{name} failed:\n\n```\n{traceback.format_exc()}```\n")
            print(failures[-1], flush=True)
    write_results(args.out, "harris_select", markdown(rows, device, args) + "\n".join(failures),
                  rows, t0)


def write_results(out: str, name: str, text: str, rows: list, t0: float) -> None:
    """``out/name.md`` (``text``, also printed) and ``out/name.json`` (``rows``)."""
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, f"{name}.md"), "w") as f:
        f.write(text)
    with open(os.path.join(out, f"{name}.json"), "w") as f:
        json.dump(rows, f, indent=1)
    print(text)
    print(f"done in {time.time() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
