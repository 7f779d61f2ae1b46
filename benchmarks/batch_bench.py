"""Batch throughput of the stabilizer (issue 16): one process vs Ray workers sharing one GPU.

A batch of ``--clips`` short real clips (cuts of the bundled hand-held clip, every other
batch half mirrored, ``--frames`` frames each, scaled by ``--scale``) is stabilized

* in this process, one clip after another (``warpvx.apps.batch.run_items`` without Ray), and
* on a local Ray instance with W workers (actors) for each W of ``--workers``, each holding
  1/W of the GPU (``num_gpus``) and cores/W CPUs,

after one untimed warm-up clip (Warp's kernel compilation, the graph calibration). The wall
time of each batch includes starting its workers (importing Warp, the CUDA context), as a
user's batch would. Writes ``batch_bench.json`` and ``batch_bench.md`` (table: workers, GPUs
per worker, wall s, frames/s, speed-up over the single process, mean per-clip FPS, failures)
into ``$OUT`` (or ``--out``).

Usage (GPU machine, from the repository root, Ray staged; see benchmarks/README.md)::

    PYTHONPATH=. python3 benchmarks/batch_bench.py                      # cuda, 16 clips, W = 1 2 4 8
    PYTHONPATH=. python3 benchmarks/batch_bench.py --backend cpu --clips 4 --workers 1,2  # anywhere
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

from warpvx.apps import batch  # noqa: E402
from warpvx.apps import stabilize as st  # noqa: E402
from warpvx.apps import stabilize_cli  # noqa: E402

CLIP = os.path.join(ROOT, "warpvx", "data", "bikes_shaky.mp4")


def make_clips(folder, n, frames, scale):
    """``n`` MP4 clips of ``frames`` frames cut from the bundled clip at staggered starts
    (the second half of the batch mirrored), scaled by ``scale``; returns their paths."""
    import cv2

    source = list(st.VideoSource(CLIP))
    if frames > len(source):
        raise SystemExit(f"--frames: the bundled clip has {len(source)} frames, got {frames}")
    h, w = source[0].shape[:2]
    size = (int(round(w * scale)) // 2 * 2, int(round(h * scale)) // 2 * 2)
    paths = []
    for k in range(n):
        start = (k * 3) % (len(source) - frames + 1)
        path = os.path.join(folder, f"clip{k:02d}.mp4")
        writer = st.open_writer(path, size, 25.0)
        for f in source[start:start + frames]:
            f = cv2.resize(f, size, interpolation=cv2.INTER_AREA) if size != (w, h) else f
            writer.write(f[:, ::-1] if k >= n // 2 else f)
        writer.release()
        paths.append(path)
    return paths


def measure(label, clips, out, options, **kwargs):
    """Run the batch once; one result row (wall time, throughput, per-clip FPS, failures)."""
    start = time.perf_counter()
    rows = batch.run_items("stabilize", clips, out, options, progress=False, **kwargs)
    wall = time.perf_counter() - start
    done = [r for r in rows if r["status"] == "done"]
    frames = sum(r["frames"] for r in done)
    result = {"config": label, "workers": kwargs.get("workers") or 1, "num_gpus": kwargs.get("num_gpus"),
              "cpus_per_input": kwargs.get("cpus_per_input"), "wall_s": round(wall, 3), "frames": frames,
              "throughput_fps": round(frames / wall, 2),
              "mean_clip_fps": round(float(np.mean([r["fps"] for r in done])), 2) if done else None,
              "failed": [f"{os.path.basename(r['input'])}: {r['error']}" for r in rows if r["status"] != "done"]}
    print(json.dumps(result), flush=True)
    return result


def markdown(results, meta):
    base = results[0]["throughput_fps"] if results else None
    lines = [f"# Batch throughput: {meta['clips']} clips x {meta['frames']} frames {meta['size']}, "
             f"backend {meta['backend']}, {meta['device']}", "",
             "| config | workers | GPU/worker | CPUs/worker | wall s | frames/s | vs 1 process | mean clip FPS | failed |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        speed = f"{r['throughput_fps'] / base:.2f}x" if base else ""
        lines.append(f"| {r['config']} | {r['workers']} | {r['num_gpus'] if r['num_gpus'] is not None else ''} | "
                     f"{r['cpus_per_input'] or ''} | {r['wall_s']} | {r['throughput_fps']} | {speed} | "
                     f"{r['mean_clip_fps']} | {len(r['failed'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", choices=st.BACKENDS, default="cuda")
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--frames", type=int, default=38, help="frames per clip (the bundled clip has 46)")
    parser.add_argument("--scale", type=float, default=2.0, help="resize the 640x272 clip by this factor")
    parser.add_argument("--workers", default="1,2,4,8", help="Ray worker counts, comma separated")
    parser.add_argument("--out", default=os.environ.get("OUT", "batch-bench-out"))
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    work = tempfile.mkdtemp(prefix="batch_bench_")
    os.environ.setdefault("WARPVX_CACHE_DIR", os.path.join(work, "cache"))
    # Ray's workers import this checkout's warpvx (and inherit the calibration cache).
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [ROOT, os.environ.get("PYTHONPATH")]))
    clips = make_clips(work, args.clips, args.frames, args.scale)
    options = batch.parse_options(stabilize_cli.add_arguments, ["IN", "--backend", args.backend, "--quiet"])
    gpus = 0
    if args.backend == "cuda":
        import warp as wp

        wp.config.quiet = True
        gpus = wp.get_cuda_device_count()
    import cv2

    h, w = cv2.VideoCapture(clips[0]).read()[1].shape[:2]
    meta = {"clips": args.clips, "frames": args.frames, "size": f"{w}x{h}", "backend": args.backend,
            "cores": os.cpu_count(), "gpus": gpus,
            "device": wp.get_cuda_device(0).name if gpus else "CPU"}
    print(json.dumps(meta), flush=True)
    measure("warm-up", clips[:1], os.path.join(work, "warm"), options)
    results = [measure("1 process", clips, os.path.join(work, "seq"), options)]
    try:
        import ray

        ray.init(num_cpus=os.cpu_count(), num_gpus=gpus, include_dashboard=False, log_to_driver=False)
    except Exception as exc:  # noqa: BLE001 -- the single-process figure still counts
        meta["ray_error"] = f"{type(exc).__name__}: {exc}"
        print("Ray unavailable:", meta["ray_error"], flush=True)
    else:
        for n in (int(x) for x in args.workers.split(",")):
            share = round(1.0 / n, 4) if args.backend == "cuda" else 0.0
            results.append(measure(f"Ray x{n}", clips, os.path.join(work, f"ray{n}"), options, ray="",
                                   workers=n, num_gpus=share,
                                   cpus_per_input=max(1, os.cpu_count() // n)))
        ray.shutdown()
    with open(os.path.join(args.out, "batch_bench.json"), "w") as f:
        json.dump({"meta": meta, "results": results}, f, indent=2)
    table = markdown(results, meta)
    with open(os.path.join(args.out, "batch_bench.md"), "w") as f:
        f.write(table)
    print(table)


if __name__ == "__main__":
    main()
