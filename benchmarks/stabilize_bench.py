"""Speed of the video stabilizer: the warpvx graph beside the imperative OpenCV model.

Usage (repository root; about 4 minutes on one H100, results into ``$OUT``):

    PYTHONPATH=. python benchmarks/stabilize_bench.py
    PYTHONPATH=. python benchmarks/stabilize_bench.py --backend warp-cpu --frames 10 --sizes 320x240

Frames: the bundled real photo (astronaut) upscaled and shaken by a random similarity per
frame (``stabilize_metrics.shaky_clip``, 30 distinct frames cycled), so no large file is needed.
Per size (default 1920x1080, 1280x720, 640x480), end to end with frames from and back to host
memory (NumPy in, NumPy out):

* ``model``: :func:`warpvx.apps.stabilize.stabilize_model`, plain OpenCV calls, with OpenCV on
  all cores (``cv2.setNumThreads``);
* ``graph``: the stabilizer graph on ``--backend`` (``cuda``: primitives and RANSAC on the GPU,
  user nodes on CPU workers), scheduled (policy best), run by ``Graph.stream`` with
  ``--depth`` frames in flight (uploads of large host arrays go through the runtime's pinned
  staging buffers); warmed up first (JIT, calibration, allocations untimed);
* ``device``: the device engine (:mod:`warpvx.apps.stabilize_device`: points, detection,
  RANSAC, the 3x3 chain and the warp on the device, one captured CUDA graph per ring slot
  replayed per frame), ``--depth`` frames in flight: each frame copied into a pinned ring
  slot (in row bands on a few threads, started before the engine waits for an older frame),
  one host->device and one device->host copy (image + its 3x3 matrices) on copy streams; the
  output read as a view of the pinned ring (no further copy); warmed up first. Times
  ``--device-frames`` frames at most (it is fast: 600 frames would be under a second), then
  splits a frame's time into the device time of its captured graph and the host time of the
  engine's calls (a table of its own);
* decode and encode (OpenCV, mp4v) of the same frames, timed apart, and the FPS of
  decode + graph as one serial loop would see it (1 / (1/decode + 1/graph)).

Each measurement stops after ``--seconds`` (the frames done so far count). Writes
``stabilize_bench.json``, ``stabilize_bench.md`` and ``gantt_<size>.png`` (the plan's
predicted over measured timelines, 3 frames) into ``--out`` (default ``$OUT``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import tempfile
import time
from importlib.resources import files

import cv2
import numpy as np

from warpvx.apps import stabilize as st
from warpvx.apps import stabilize_metrics as sm

UNIQUE_FRAMES = 30
LIVE = np.ones(1, np.uint8)


def parse_size(text):
    w, h = (int(v) for v in text.lower().split("x"))
    return w, h


def synthetic_frames(size, n=UNIQUE_FRAMES):
    """``n`` BGR uint8 frames of ``size``: the bundled photo upscaled 15% past the frame and
    shaken (+-6 px, +-1 deg, +-1% zoom per frame)."""
    photo = cv2.imread(str(files("warpvx") / "data" / "astronaut_448.png"))
    w, h = size
    side = int(1.15 * max(w, h))
    big = cv2.resize(photo, (side, side), interpolation=cv2.INTER_CUBIC)
    frames, _, _ = sm.shaky_clip(big, n, size, shift=6.0, angle=1.0, zoom=0.01, seed=0)
    return frames


def timed(iterable, n, seconds):
    """(frames consumed, wall seconds) of iterating at most ``n`` items or ``seconds``."""
    t0 = time.perf_counter()
    done = 0
    for _ in iterable:
        done += 1
        if done >= n or time.perf_counter() - t0 > seconds:
            break
    return done, time.perf_counter() - t0


def bench_model(frames, config, n, seconds):
    cv2.setNumThreads(os.cpu_count() or 1)
    gen = st.stabilize_model(itertools.islice(itertools.cycle(frames), n + 5), config)
    list(itertools.islice(gen, 5))  # warm-up: first allocations, OpenCV's thread pool
    done, s = timed(gen, n, seconds)
    gen.close()
    return done / s


def bench_graph(frames, config, backend, depth, n, seconds, gantt_path=None):
    size = frames[0].shape[1::-1]
    g = st.build_graph(size, config, backend=backend)
    t = time.perf_counter()
    plan = st.schedule(g, backend)
    schedule_s = time.perf_counter() - t
    feed = ({"frame": f, "live": LIVE} for f in itertools.cycle(frames))
    with g:
        stream = g.stream(feed, depth=depth, host=True)
        list(itertools.islice(stream, 3 * depth + 5))  # warm-up: JIT, allocations, staging
        done, s = timed(stream, n, seconds)
        stream.close()
        info = plan.summary()
        if gantt_path is not None:
            try:
                plan.gantt(gantt_path, frames=3, title=f"stabilize {size[0]}x{size[1]} {backend}")
            except ImportError:
                gantt_path = None
    return {"fps": done / s, "frames": done, "seconds": s, "schedule_s": schedule_s,
            "nodes": len(g.nodes), "placement": info["placement"],
            "predicted_makespan_ms": info["predicted_makespan_ms"],
            "measured_makespan_ms": info["measured_makespan_ms"],
            "gantt": os.path.basename(gantt_path) if gantt_path else None}


class HostClock:
    """Host milliseconds per call of some of an object's methods (instance attributes
    wrapping them), to tell host work from waiting."""

    def __init__(self, obj, names):
        self.ms = {name: [] for name in names}
        for name in names:
            setattr(obj, name, self._wrap(getattr(obj, name), self.ms[name]))

    @staticmethod
    def _wrap(fn, out):
        def timed_call(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                out.append(1e3 * (time.perf_counter() - t))
        return timed_call

    def clear(self):
        for v in self.ms.values():
            v.clear()

    def medians(self):
        return {name: float(np.median(v)) if v else None for name, v in self.ms.items()}


def device_program_ms(plan, n=200):
    """Median device milliseconds of one frame's program as the engine launches it (the
    captured graph on CUDA, events around each launch, launches queued back to back so the
    host does not pace them; Warp's CPU device: wall time of the synchronous launches)."""
    import warp as wp

    wp.synchronize_device(plan.device)
    if not plan.device.is_cuda:
        times = []
        for k in range(n):
            t = time.perf_counter()
            plan.programs[k % plan.slots]()
            times.append(1e3 * (time.perf_counter() - t))
        return float(np.median(times))
    events = []
    for k in range(n):
        a, b = wp.Event(plan.device, enable_timing=True), wp.Event(plan.device, enable_timing=True)
        plan.compute.record_event(a)
        plan.programs[k % plan.slots]()
        plan.compute.record_event(b)
        events.append((a, b))
    wp.synchronize_device(plan.device)
    return float(np.median([wp.get_event_elapsed_time(a, b) for a, b in events]))


def bench_device(frames, config, backend, depth, n, seconds):
    """FPS of the device engine on ``frames`` cycled, and where a frame's time goes: host
    milliseconds per call of ``submit`` (the frame into its pinned slot unless staged, the
    upload, the graph launch, the download), ``stage`` (starting the next frame's copy) and
    ``result`` (mostly waiting for the download), and the device milliseconds of one frame's
    program (:func:`device_program_ms`). Errors are reported, not raised, so the other rows
    still come out."""
    from warpvx.apps.stabilize_device import DevicePlan

    size = frames[0].shape[1::-1]
    try:
        t = time.perf_counter()
        plan = DevicePlan(size, config, "cpu" if backend == "warp-cpu" else backend, depth=depth)
        clock = HostClock(plan, ("submit", "stage", "result"))
        feed = ({"frame": f, "live": LIVE} for f in itertools.cycle(frames))
        stream = plan.run(feed, copy=False)
        list(itertools.islice(stream, 3 * plan.slots + 5))  # warm-up: JIT, capture, scratch
        setup_s = time.perf_counter() - t
        clock.clear()
        done, s = timed(stream, n, seconds)
        stream.close()
        host = clock.medians()
        program_ms = device_program_ms(plan)
    except Exception as exc:  # noqa: BLE001 - a failed row must not lose the others
        print(f"device engine failed at {size[0]}x{size[1]}: {exc!r}", flush=True)
        return {"fps": None, "error": repr(exc)}
    return {"fps": done / s, "frames": done, "seconds": s, "setup_s": setup_s,
            "graphs": plan.use_graph and all(g is not None for g in plan.graphs),
            "capture_error": plan.capture_error, "slots": plan.slots,
            "breakdown_ms": {"frame interval (1 / FPS)": 1e3 * s / done,
                             "device: one frame's program": program_ms,
                             "host: submit": host["submit"], "host: stage next frame": host["stage"],
                             "host: result (mostly waiting)": host["result"]}}


def profile_device(frames, config, backend, n):
    """Mean device time per frame of each stage of the device engine (``{stage: ms}``), from
    ``n`` eager frames with events between the stages (a CUDA graph replays the same
    launches with less launch overhead), plus ``re-detections per frame`` over those frames,
    the detection alone (``detect (when it runs)``), the host's copy of a frame into the
    ring (the engine's banded copy on its threads) and (CUDA) the upload and download of one frame, which the pipeline overlaps with
    the compute; {} on error."""
    import warp as wp

    from warpvx.apps.stabilize_device import DevicePlan

    try:
        plan = DevicePlan(frames[0].shape[1::-1], config, "cpu" if backend == "warp-cpu" else backend,
                          depth=1, use_graph=False)
        cuda = plan.device.is_cuda
        marks = []

        def stamp():
            if not cuda:
                return time.perf_counter()
            ev = wp.Event(plan.device, enable_timing=True)
            plan.compute.record_event(ev)
            return ev

        def elapsed_ms(a, b):
            return wp.get_event_elapsed_time(a, b) if cuda else 1e3 * (b - a)

        feed = ({"frame": f, "live": LIVE} for f in itertools.cycle(frames))
        list(itertools.islice(plan.run(feed, copy=False), 10))  # warm-up
        refills = []
        refill = plan._refill
        plan._refill = lambda gray: (refills.append(1), refill(gray))
        plan.mark = lambda stage: marks.append((stage, stamp()))
        list(itertools.islice(plan.run(feed, copy=False), n))
        plan.mark = None
        gray = plan.pyramids[0][0]
        detect = []
        for _ in range(max(3, n // 10)):
            a = stamp()
            plan.corners.launch(gray)
            detect.append((a, stamp()))
        copies = []  # (host->device, device->host) of one frame, CUDA only
        host_copy = []  # a frame into a pinned (CUDA) / device (CPU) ring slot, host time
        for k in range(max(3, n // 10)):
            t = time.perf_counter()
            plan.copier.wait(plan.copier.start(plan.host_in[0], frames[k % len(frames)]))
            host_copy.append(1e3 * (time.perf_counter() - t))
            if cuda:
                a = stamp()
                wp.copy(plan.frames[0], plan.pin_in[0], stream=plan.compute)
                b = stamp()
                wp.copy(plan.pin_out[0], plan.outs[0], stream=plan.compute)
                copies.append((a, b, stamp()))
        wp.synchronize_device(plan.device)
    except Exception as exc:  # noqa: BLE001 - profiling is extra: report and go on
        print(f"device profile failed: {exc!r}", flush=True)
        return {}
    stages = {}
    for (_, a), (stage, b) in zip(marks, marks[1:]):
        if stage != "start":
            stages[stage] = stages.get(stage, 0.0) + elapsed_ms(a, b) / n
    stages["re-detections per frame"] = len(refills) / n
    stages["detect (when it runs)"] = float(np.mean([elapsed_ms(a, b) for a, b in detect]))
    stages["frame into the ring (host ms)"] = float(np.median(host_copy))
    if copies:
        stages["upload (host->device)"] = float(np.median([elapsed_ms(a, b) for a, b, _ in copies]))
        stages["download (device->host)"] = float(np.median([elapsed_ms(b, c) for _, b, c in copies]))
    return stages


def bench_codec(frames, n):
    """(encode FPS, decode FPS) of OpenCV's mp4v writer and reader on ``n`` frames."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "clip.mp4")
        w = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 30, frames[0].shape[1::-1])
        t = time.perf_counter()
        for f in itertools.islice(itertools.cycle(frames), n):
            w.write(f)
        w.release()
        enc = n / (time.perf_counter() - t)
        cap = cv2.VideoCapture(path)
        t, got = time.perf_counter(), 0
        while cap.read()[0]:
            got += 1
        dec = got / (time.perf_counter() - t)
    return enc, dec


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--backend", default="cuda", choices=("cuda", "warp-cpu", "cpu"))
    p.add_argument("--sizes", default="1920x1080,1280x720,640x480")
    p.add_argument("--frames", type=int, default=600, help="timed frames per measurement at most")
    p.add_argument("--device-frames", type=int, default=5000,
                   help="timed frames per device-engine measurement at most")
    p.add_argument("--profile-frames", type=int, default=100,
                   help="eager frames timed stage by stage for the device engine's breakdown")
    p.add_argument("--seconds", type=float, default=8.0, help="time per measurement at most")
    p.add_argument("--depth", type=int, default=4, help="frames in flight in the graph")
    p.add_argument("--motion", default="homography", choices=st.MOTIONS)
    p.add_argument("--window", type=int, default=st.StabilizerConfig().window)
    p.add_argument("--out", default=os.environ.get("OUT"), help="results folder (default $OUT)")
    args = p.parse_args(argv)
    if not args.out:
        p.error("--out: give a folder (or set $OUT)")
    os.makedirs(args.out, exist_ok=True)
    config = st.StabilizerConfig(window=args.window, motion=args.motion)
    rows = []
    for text in args.sizes.split(","):
        size = parse_size(text)
        frames = synthetic_frames(size)
        enc, dec = bench_codec(frames, min(args.frames, 120))
        model = bench_model(frames, config, args.frames, args.seconds)
        graph = bench_graph(frames, config, args.backend, args.depth, args.frames, args.seconds,
                            os.path.join(args.out, f"gantt_{text}.png"))
        device = bench_device(frames, config, args.backend, args.depth, args.device_frames,
                              args.seconds)
        device["stages_ms"] = profile_device(frames, config, args.backend, args.profile_frames)
        dev_fps = device["fps"]
        row = {"size": text, "model_fps": model, "graph_fps": graph["fps"],
               "ratio": graph["fps"] / model, "decode_fps": dec, "encode_fps": enc,
               "graph_with_decode_fps": 1.0 / (1.0 / dec + 1.0 / graph["fps"]), "graph": graph,
               "device_fps": dev_fps, "device_ratio": dev_fps / model if dev_fps else None,
               "device_with_decode_fps": 1.0 / (1.0 / dec + 1.0 / dev_fps) if dev_fps else None,
               "device": device}
        rows.append(row)
        dev_text = "failed" if dev_fps is None else f"{dev_fps:.1f} FPS (x{row['device_ratio']:.2f})"
        print(f"{text}: model {model:.1f} FPS, graph ({args.backend}) {graph['fps']:.1f} FPS "
              f"(x{row['ratio']:.2f}), device {dev_text}, decode {dec:.0f} FPS, "
              f"encode {enc:.0f} FPS", flush=True)
    report = {"backend": args.backend, "depth": args.depth, "motion": args.motion,
              "window": args.window, "cpu_cores": os.cpu_count(), "machine": platform.platform(),
              "processor": platform.processor(), "opencv": cv2.__version__, "gpu": _gpu_name(args.backend),
              "rows": rows}
    with open(os.path.join(args.out, "stabilize_bench.json"), "w") as f:
        json.dump(report, f, indent=2)
    md = render(report, argv)
    with open(os.path.join(args.out, "stabilize_bench.md"), "w") as f:
        f.write(md)
    print(md)
    return 0


def _gpu_name(backend):
    if not backend.startswith("cuda"):
        return None
    import warp as wp

    return wp.get_device(backend).name


def _size_table(rows, key, corner, title):
    """Markdown lines of a table: one row per entry of the device's ``key`` dict, one column
    per size ([] when the first size has none)."""
    names = list(rows[0].get("device", {}).get(key, {}))
    if not names:
        return []
    lines = ["", title, "", f"| {corner} | " + " | ".join(r["size"] for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    for name in names:
        values = [r["device"].get(key, {}).get(name) for r in rows]
        lines.append(f"| {name} | " + " | ".join("failed" if v is None else f"{v:.3f}" for v in values) + " |")
    return lines


def render(report, argv):
    cmd = "PYTHONPATH=. python benchmarks/stabilize_bench.py " + " ".join(argv or sys.argv[1:])
    lines = [f"<!-- {cmd.strip()} -->",
             f"# Stabilizer speed on {report['backend']} ({report['gpu'] or 'no GPU'}): device "
             f"engine and graph vs the OpenCV model on {report['cpu_cores']} cores", "",
             f"{report['motion']}, window {report['window']}, depth {report['depth']}; frames from "
             "and back to host memory; decode/encode (OpenCV mp4v) apart. device = every step on "
             "the device, one CUDA graph per frame (captured: whether the graphs were captured; "
             "else eager launches with a host read of the re-detection flag).", "",
             "| size | OpenCV model FPS | graph FPS | graph / model | device FPS | device / model | "
             "captured | decode FPS | encode FPS | decode + graph FPS | decode + device FPS | "
             "graph predicted ms/frame | graph measured ms/frame |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def num(v, fmt):
        return "failed" if v is None else format(v, fmt)

    for r in report["rows"]:
        g, d = r["graph"], r.get("device", {})
        meas = g["measured_makespan_ms"]
        lines.append(f"| {r['size']} | {r['model_fps']:.1f} | {r['graph_fps']:.1f} | {r['ratio']:.2f} | "
                     f"{num(r.get('device_fps'), '.1f')} | {num(r.get('device_ratio'), '.2f')} | "
                     f"{d.get('graphs', '-')} | {r['decode_fps']:.0f} | {r['encode_fps']:.0f} | "
                     f"{r['graph_with_decode_fps']:.1f} | {num(r.get('device_with_decode_fps'), '.1f')} | "
                     f"{g['predicted_makespan_ms']:.2f} | {'-' if meas is None else f'{meas:.2f}'} |")
    lines += _size_table(report["rows"], "breakdown_ms", "",
                         "Device engine, where a frame's time goes (medians, ms; device = the "
                         "program as run, the captured graph on CUDA; host = Python per call: the "
                         "frame interval is the larger of the device time and submit + stage + "
                         "the wait left in result):")
    lines += _size_table(report["rows"], "stages_ms", "stage",
                         "Device engine, per stage (eager launches, events between stages; "
                         "mean ms per frame; detection counted in refresh on the frames that "
                         "re-detect):")
    errors = [f"{r['size']}: {r['device'].get('error') or 'capture: ' + r['device']['capture_error']}"
              for r in report["rows"]
              if r.get("device", {}).get("error") or r.get("device", {}).get("capture_error")]
    if errors:
        lines += ["", "Device engine errors: " + "; ".join(errors)]
    last = report["rows"][-1]["graph"]["placement"]
    lines += ["", "Placement (last size): " + ", ".join(f"{k}: {v}" for k, v in sorted(last.items()))]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
