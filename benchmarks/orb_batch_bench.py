"""Batched ORB extraction: per-camera time at batch 1, 2, 8, 32 (1241x376, KITTI size) against
single-image calls, and the bandwidth floor.

Cameras are frames of a KITTI-layout sequence rendered from the bundled photos
(:mod:`warpvx.apps.orbslam_synth`), cycled to fill the largest batch. The batch is a stacked
uint8 [B, H, W] Warp array already on the device (what a rig's capture would hand over); the
reference is ``warpvx.orb`` called image by image on the same device arrays. Each timing is
the median over ``--repeat`` calls after warm-up (plan built, modules loaded, the CUDA graph
captured), the device synchronised before and after each call; per camera = call / B.

Bandwidth floor per camera: the bytes the extractor's stages must move per image if each
read its input and wrote its output once (input to level 0; each resize reads level l-1 and
writes level l; blur, FAST score: read and write the pyramid; non-max suppression reads the
scores; per keypoint the orientation disc, 512 descriptor samples, 32 descriptor bytes and 24
bytes of fields), divided by the device's copy bandwidth (a large device-to-device
``wp.copy``, read + write bytes over time). Candidates, sort keys and quadtree nodes are a few
bytes per candidate and left out, so the floor is a lower bound.

Before timing, each batch size's results are checked equal, image by image, to the single
calls (keypoint count and every descriptor byte).

Where a call's time goes: the device program alone (a plan of that batch size replaying its
CUDA graph, or its launches on the CPU device, then a sync; no input copy, read-back or output
arrays), timed the same way; the rest of a call is the host's (validation, input copy, the
one read-back, output allocation and copies).

Writes ``orb_batch.md`` (the command at its top) and ``orb_batch.json`` into ``--out``.

Usage::

    python3 benchmarks/orb_batch_bench.py --device cuda --out $OUT/orb_batch    # H100, < 2 min
    python3 benchmarks/orb_batch_bench.py --device cpu --batches 1,2,4 --repeat 3  # warp-cpu
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warpvx  # noqa: E402
from warpvx import _orb_spec as spec  # noqa: E402
from warpvx._pyramid_sizes import scale_pyramid_sizes  # noqa: E402
from warpvx.apps.orbslam_synth import render_sequence  # noqa: E402
from warpvx.bench.report import machine_info  # noqa: E402
from warpvx.kernels_warp.orb.plan import OrbPlan  # noqa: E402

SIZE = (1241, 376)
PARAMS = (2000, 1.2, 8, 20, 7)  # n_features, scale_factor, n_levels, ini_th_fast, min_th_fast


def log(msg: str) -> None:
    print(msg, flush=True)


def timed(fn, sync, repeat: int) -> list:
    """Seconds of ``repeat`` calls of ``fn``, each between two device synchronisations."""
    times = []
    for _ in range(repeat):
        sync()
        t = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t)
    return times


def copy_bandwidth(wp, device, sync, mib: int = 256) -> float:
    """Bytes per second of a device-to-device copy (read + write), median of 10."""
    n = mib << 20
    src = wp.zeros(n, dtype=wp.uint8, device=device)
    dst = wp.empty(n, dtype=wp.uint8, device=device)
    wp.copy(dst, src)
    return 2 * n / statistics.median(timed(lambda: wp.copy(dst, src), sync, 10))


def bytes_per_image(n_keypoints: float) -> dict:
    """The floor model's bytes per image, by stage (see the module docstring)."""
    w, h = SIZE
    sizes = scale_pyramid_sizes(w, h, PARAMS[2], PARAMS[1])
    px = [lw * lh for lw, lh in sizes]
    pix = sum(px)
    disc = int(sum(2 * u + 1 for u in np.concatenate([spec.umax()[::-1], spec.umax()[1:]])))
    return {
        "input to level 0": 2 * px[0],
        "pyramid (resize)": sum(px[l - 1] + px[l] for l in range(1, len(px))),
        "blur": 2 * pix,
        "FAST score": 2 * pix,
        "non-max suppression": pix,
        "orientation + descriptors": int(n_keypoints * (disc + 512 + 32 + 24)),
    }


def same(a, b) -> bool:
    (ka, da), (kb, db) = a, b
    return len(ka) == len(kb) and np.array_equal(np.asarray(da.numpy()), np.asarray(db.numpy()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", choices=["cuda", "cpu"], default="cuda",
                   help="cuda, or cpu (Warp's CPU device: warp-cpu) (default: cuda)")
    p.add_argument("--batches", default=None,
                   help="batch sizes, comma separated (default: 1,2,8,32 on cuda, 1,2,4 on cpu)")
    p.add_argument("--repeat", type=int, default=None,
                   help="timed calls per batch size (default: 30 on cuda, 3 on cpu)")
    p.add_argument("--frames", type=int, default=8, help="distinct frames rendered (default: 8)")
    p.add_argument("--out", default=os.path.join(os.environ.get("OUT") or ".", "orb_batch"),
                   help="output folder (default: $OUT/orb_batch)")
    args = p.parse_args(argv)
    cuda = args.device == "cuda"
    batches = [int(b) for b in (args.batches or ("1,2,8,32" if cuda else "1,2,4")).split(",")]
    repeat = args.repeat or (30 if cuda else 3)
    backend = "cuda" if cuda else "warp-cpu"
    if cuda and not warpvx.cuda_available():
        p.error("--device cuda: no CUDA device here (use --device cpu)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    import warp as wp

    device = wp.get_device("cuda:0" if cuda else "cpu")
    sync = (lambda: wp.synchronize_device(device)) if cuda else (lambda: None)
    t0 = time.perf_counter()
    log(f"rendering {args.frames} frames of {SIZE[0]}x{SIZE[1]} ...")
    frames, _, _, _ = render_sequence(args.frames, size=SIZE)
    cams = [np.ascontiguousarray(frames[i % len(frames)]) for i in range(max(batches))]
    on_device = [wp.array(c, dtype=wp.uint8, device=device) for c in cams]
    log(f"  {time.perf_counter() - t0:.1f} s; copy bandwidth ...")
    bandwidth = copy_bandwidth(wp, device, sync)
    log(f"  {bandwidth / 1e9:.1f} GB/s")

    def orb(x):
        return warpvx.orb(x, *PARAMS, backend=backend)

    # Reference: single-image calls in a loop over the largest batch's cameras.
    n_ref = max(batches)
    for img in on_device[:2]:
        orb(img), orb(img)  # warm-up: the single-image plan and its graph
    log(f"single-image calls x {n_ref} ...")
    singles = [orb(img) for img in on_device]
    ref = statistics.median(timed(lambda: [orb(img) for img in on_device],
                                  sync, max(3, repeat // 5))) / n_ref
    n_kp = statistics.mean(len(k) for k, _ in singles)
    log(f"  {ref * 1e3:.3f} ms per camera, {n_kp:.0f} keypoints per camera")
    stages = bytes_per_image(n_kp)
    floor = sum(stages.values()) / bandwidth

    rows = []
    for b in batches:
        stack = wp.array(np.stack(cams[:b]), dtype=wp.uint8, device=device)
        for _ in range(3):  # warm-up: plan, modules, graph capture
            results = orb(stack)
        identical = all(same(r, s) for r, s in zip(results, singles[:b]))
        times = timed(lambda: orb(stack), sync, repeat)
        call = statistics.median(times)
        plan = OrbPlan(device, SIZE[1], SIZE[0], *PARAMS, batch=b)
        for _ in range(3):  # eager, capture, replay
            plan.run(stack)
        program = statistics.median(timed(plan.launch, sync, repeat))
        row = {"batch": b, "call_ms": call * 1e3, "program_ms": program * 1e3,
               "host_ms": (call - program) * 1e3, "per_camera_ms": call / b * 1e3,
               "cameras_per_s": b / call, "vs_single": ref / (call / b),
               "vs_floor": (call / b) / floor, "identical_to_single": identical,
               "call_ms_min": min(times) * 1e3, "call_ms_max": max(times) * 1e3}
        rows.append(row)
        log(f"batch {b:3d}: {row['call_ms']:.3f} ms per call (device program "
            f"{row['program_ms']:.3f}), {row['per_camera_ms']:.3f} ms per camera, "
            f"{row['vs_single']:.2f}x single calls, {row['vs_floor']:.1f}x the floor, "
            f"identical {identical}")

    info = machine_info()
    gpu = info["gpus"][0]["name"] if cuda and info["gpus"] else info["cpu_model"]
    command = "python3 " + " ".join(shlex.quote(a) for a in [sys.argv[0]] + (argv or sys.argv[1:]))
    report = {"command": command, "device": str(device), "device_name": gpu, "size": SIZE,
              "params": PARAMS, "repeat": repeat, "copy_bandwidth_gb_s": bandwidth / 1e9,
              "single_per_camera_ms": ref * 1e3, "keypoints_per_camera": n_kp,
              "floor_bytes_per_camera": stages, "floor_per_camera_ms": floor * 1e3,
              "batches": rows, "machine": info}
    md = [f"# Batched ORB extraction, {SIZE[0]}x{SIZE[1]}, {backend} ({gpu})", "",
          f"Regenerate: `{command}`", "",
          f"Cameras: {args.frames} rendered KITTI-layout frames (cycled), a stacked uint8 "
          f"[B, H, W] device array; ORB {PARAMS[0]} features, scale {PARAMS[1]}, {PARAMS[2]} "
          f"levels; median of {repeat} calls after warm-up, the device synchronised around "
          f"each call.", "",
          f"Single-image calls in a loop: **{ref * 1e3:.3f} ms per camera** "
          f"({n_kp:.0f} keypoints per camera).  ",
          f"Bandwidth floor: {sum(stages.values()) / 1e6:.1f} MB per camera at "
          f"{bandwidth / 1e9:.0f} GB/s (device copy) = **{floor * 1e3:.4f} ms per camera**.", "",
          "| batch | ms per call | device program ms | host ms | ms per camera | cameras/s | "
          "vs single calls | x floor | results = single calls |",
          "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | :---: |"]
    md += [f"| {r['batch']} | {r['call_ms']:.3f} | {r['program_ms']:.3f} | {r['host_ms']:.3f} | "
           f"{r['per_camera_ms']:.4f} | {r['cameras_per_s']:.0f} | {r['vs_single']:.2f}x | "
           f"{r['vs_floor']:.1f} | {'yes' if r['identical_to_single'] else 'NO'} |"
           for r in rows]
    md += ["", "Floor model, bytes per camera:", "", "| stage | bytes |", "| --- | ---: |"]
    md += [f"| {k} | {v:,} |" for k, v in stages.items()]
    (out / "orb_batch.md").write_text("\n".join(md) + "\n")
    (out / "orb_batch.json").write_text(json.dumps(report, indent=2, default=str))
    log(f"wrote {out}/orb_batch.md, orb_batch.json ({time.perf_counter() - t0:.0f} s)")
    return 0 if all(r["identical_to_single"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
