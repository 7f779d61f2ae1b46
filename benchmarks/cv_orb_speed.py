"""Time ``warpvx.cv.ORB_create(n).detectAndCompute`` (OpenCV's algorithm since issue 17) against
``cv2.ORB_create(n)`` and against :func:`warpvx.orb` (ORB-SLAM2's extractor, which the drop-in
ran before), per backend, on real photos; NumPy in and out, as a cv2 script calls it.

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/cv_orb_speed.py --backends cuda cpu --out DIR

Writes ``DIR/cv_orb_speed.md`` (the command at its top) and ``DIR/cv_orb_speed.json``; prints
progress. Median per-call time of several batches (:func:`warpvx.bench.timing.time_per_call_s`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import cv2

import warpvx
from warpvx import cv as wcv
from warpvx.bench.report import machine_info
from warpvx.bench.timing import Settings, time_per_call_s

DATA = Path(__file__).resolve().parent.parent / "tests" / "data"
PHOTOS = ["box_in_scene.png", "basketball1.png", "leuvenA.jpg"]


def _calls(gray, n, backends):
    """(label, callable returning the keypoints) of every timed call on one gray image."""
    yield "cv2.ORB_create(n).detectAndCompute", \
        lambda: cv2.ORB_create(n).detectAndCompute(gray, None)[0]
    for be in backends:
        orb = wcv.ORB_create(n, backend=be)
        yield f"warpvx.cv.ORB_create(n) [{be}]", lambda orb=orb: orb.detectAndCompute(gray, None)[0]
        yield f"warpvx.orb (ORB-SLAM2, before) [{be}]", \
            lambda be=be: warpvx.orb(gray, n, backend=be)[0].to("host")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--backends", nargs="+", default=["cpu"])
    p.add_argument("--nfeatures", type=int, default=1000)
    p.add_argument("--out", default="benchmarks/results/opencv_suite")
    args = p.parse_args(argv)
    settings = Settings(repeat=5, warmup=3, min_batch_s=0.2, gpu_min_calls=1)
    rows = []
    for name in PHOTOS:
        gray = cv2.imread(str(DATA / name), cv2.IMREAD_GRAYSCALE)
        for label, fn in _calls(gray, args.nfeatures, args.backends):
            seconds, _ = time_per_call_s(fn, settings=settings)
            rows.append({"photo": name, "size": f"{gray.shape[1]}x{gray.shape[0]}",
                         "call": label, "ms": round(seconds * 1e3, 3), "keypoints": len(fn())})
            print(f"{name} {label}: {seconds * 1e3:.2f} ms", flush=True)
    command = " ".join(["PYTHONPATH=. python benchmarks/cv_orb_speed.py"] + sys.argv[1:])
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "cv_orb_speed.json"), "w") as f:
        json.dump({"command": command, "machine": machine_info(), "rows": rows}, f, indent=1)
    lines = [f"Regenerate: `{command}`", "",
             f"nfeatures={args.nfeatures}; median ms per call, NumPy in and out.", "",
             "| photo | size | call | ms | keypoints |", "|---|---|---|---|---|"]
    lines += [f"| {r['photo']} | {r['size']} | {r['call']} | {r['ms']:.2f} | {r['keypoints']} |"
              for r in rows]
    with open(os.path.join(args.out, "cv_orb_speed.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
