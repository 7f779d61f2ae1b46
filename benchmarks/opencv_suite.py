"""OpenCV's own Python tests and samples, run against ``warpvx.cv`` as their ``cv2``.

Each listed OpenCV test file (unittest methods, one result each) and sample (driven headlessly
for a few frames) runs in a fresh subprocess, once with the real ``cv2`` and once per warpvx
backend with its ``import cv2`` answered by a proxy: warpvx.cv's names first, cv2's for the
rest, and the HighGUI calls stubbed (``waitKey`` returns ESC after ``--frames`` calls; a mouse
drag selects the central half of the window for samples that wait for one). warpvx's own
modules keep importing the real cv2. The record says, per test or sample, whether it passed
with cv2 and with each backend, and which calls warpvx.cv routed to cv2 (CvFallbackWarning).

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/opencv_suite.py --opencv ROOT [--opencv ROOT2 ...] \
        --data SAMPLES_DATA_DIR --backends cpu warp-cpu --out DIR

Every ``ROOT`` is an OpenCV source tree (4.x: ``modules/python/test``, ``samples/python``;
5.x: ``modules/*/misc/python/test``, ``samples/python/snippets``); each file is taken from the
first root that has it. Writes ``DIR/results.json`` and ``DIR/results.md``.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time

TESTS = [
    "test_lk_track.py",
    "test_lk_homography.py",
    "test_goodfeatures.py",
    "test_features2d.py",
    "test_features.py",
    "test_imgproc.py",
    "test_feature_homography.py",
    "test_legacy.py",
    "test_algorithm_rw.py",
    "test_umat.py",
]

# name -> argv after the script; "{data}" is the samples/data folder.
SAMPLES = {
    "lk_track.py": ["{data}/vtest.avi"],
    "lk_homography.py": ["synth:class=book:bg=graf1.png:noise=0.1:size=640x480"],
    "plane_tracker.py": ["synth:class=book:bg=graf1.png:noise=0.1:size=640x480"],
    "find_obj.py": ["--feature=orb", "{data}/box.png", "{data}/box_in_scene.png"],
    "find_obj.py --feature=orb-flann": ["--feature=orb-flann", "{data}/box.png",
                                        "{data}/box_in_scene.png"],
}

_TEST_DIRS = ["modules/python/test", "modules/*/misc/python/test"]
_SAMPLE_DIRS = ["samples/python", "samples/python/snippets"]
_ESC = 27


def find(roots, name, patterns):
    """First ``root/pattern/name`` that exists, or None."""
    for root in roots:
        for pattern in patterns:
            hits = sorted(glob.glob(os.path.join(root, pattern, name)))
            if hits:
                return hits[0]
    return None


# --- child side: one test file or sample under one mode ---------------------------------------


def _install_proxy(mode, frames):
    """Answer ``import cv2`` outside warpvx (and cv2 itself) with warpvx.cv over cv2."""
    import builtins
    import types

    import cv2 as real

    mouse = {}
    calls = [0]

    def wait_key(delay=0):
        calls[0] += 1
        if calls[0] == 1 and "cb" in mouse:
            _drag(mouse)
        return _ESC if calls[0] >= frames else -1

    def set_mouse_callback(win, callback, param=None):
        mouse["cb"], mouse["param"] = callback, param

    def shown(win, img):
        mouse.setdefault("size", img.shape[:2])

    headless = {"imshow": shown, "waitKey": wait_key, "setMouseCallback": set_mouse_callback,
                "namedWindow": lambda *a, **k: None, "destroyAllWindows": lambda *a: None,
                "destroyWindow": lambda *a: None, "createTrackbar": lambda *a: None,
                "setTrackbarPos": lambda *a: None, "getTrackbarPos": lambda *a: 0,
                "moveWindow": lambda *a: None, "resizeWindow": lambda *a: None,
                "waitKeyEx": wait_key, "pollKey": lambda: -1}
    if mode == "cv2":
        target = real
    else:
        import warpvx
        from warpvx import cv as target

        warpvx.set_backend(mode)
    proxy = types.ModuleType("cv2")

    def lookup(name):
        if name in headless:
            return headless[name]
        return getattr(target, name)

    proxy.__getattr__ = lookup
    proxy.__dict__.update({"__file__": real.__file__, "__path__": getattr(real, "__path__", [])})
    original_import = builtins.__import__

    def importer(name, globals=None, locals=None, fromlist=(), level=0):
        caller = (globals or {}).get("__name__", "") or ""
        if name == "cv2" and level == 0 and not caller.startswith(("warpvx", "cv2")):
            return proxy
        return original_import(name, globals, locals, fromlist, level)

    builtins.__import__ = importer


def _drag(mouse):
    """A left-button drag over the central half of the first shown frame."""
    import cv2

    h, w = mouse.get("size", (480, 640))
    cb, param = mouse["cb"], mouse["param"]
    x0, y0, x1, y1 = w // 4, h // 4, 3 * w // 4, 3 * h // 4
    cb(cv2.EVENT_LBUTTONDOWN, x0, y0, cv2.EVENT_FLAG_LBUTTON, param)
    cb(cv2.EVENT_MOUSEMOVE, x1, y1, cv2.EVENT_FLAG_LBUTTON, param)
    cb(cv2.EVENT_LBUTTONUP, x1, y1, 0, param)


def _child(args):
    import io
    import runpy
    import unittest
    import warnings

    os.environ["OPENCV_TEST_DATA_PATH"] = args.repo
    os.environ["OPENCV_SAMPLES_DATA_PATH"] = args.data
    _install_proxy(args.mode, args.frames)
    sys.path[:0] = [os.path.dirname(args.file)] + args.extra_path
    fallbacks = set()
    shown = warnings.showwarning

    def record(message, category, *rest):
        if category.__name__ == "CvFallbackWarning":
            fallbacks.add(str(message).split(":")[0])
        else:
            shown(message, category, *rest)

    warnings.showwarning = record
    warnings.simplefilter("always")
    results = {}
    if args.kind == "test":
        module = runpy.run_path(args.file, run_name="opencv_test")
        suite = unittest.TestSuite()
        loader = unittest.TestLoader()
        for obj in module.values():
            if hasattr(obj, "repoPath"):  # tests_common.NewOpenCVTests: where samples/data is
                obj.repoPath = args.repo
            if isinstance(obj, type) and issubclass(obj, unittest.TestCase) \
                    and obj.__module__ == "opencv_test":
                suite.addTests(loader.loadTestsFromTestCase(obj))
        tests = list(_flatten(suite))  # the runner empties the suite as it goes
        outcome = unittest.TextTestRunner(stream=io.StringIO(), verbosity=0).run(suite)
        failed = {t.id(): "fail: " + tb.strip().splitlines()[-1] for t, tb in outcome.failures}
        failed.update({t.id(): "error: " + tb.strip().splitlines()[-1] for t, tb in outcome.errors})
        skipped = {t.id(): "skip: " + why for t, why in outcome.skipped}
        for test in tests:
            tid = test.id()
            results[tid.split(".", 1)[-1]] = failed.get(tid) or skipped.get(tid) or "pass"
    else:
        sys.argv = [args.file] + [a.format(data=args.data) for a in args.argv]
        os.chdir(args.data)
        try:
            runpy.run_path(args.file, run_name="__main__")
            results["run"] = "pass"
        except SystemExit as e:
            results["run"] = "pass" if e.code in (None, 0) else f"fail: exit {e.code}"
    print("@@RESULT@@" + json.dumps({"results": results, "fallbacks": sorted(fallbacks)}))


def _flatten(suite):
    for t in suite:
        yield from (_flatten(t) if hasattr(t, "__iter__") else [t])


# --- parent side ---------------------------------------------------------------------------------


def _run_one(args, kind, name, path, argv, mode, extra_path):
    cmd = [sys.executable, os.path.abspath(__file__), "--child", "--kind", kind, "--file", path,
           "--mode", mode, "--data", args.data, "--repo", args.repo, "--frames", str(args.frames),
           "--extra-path", *extra_path, "--argv=", *[f"--argv={a}" for a in argv]]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
    except subprocess.TimeoutExpired:
        return {"results": {"run": f"fail: timeout {args.timeout}s"}, "fallbacks": [],
                "seconds": args.timeout}
    seconds = round(time.perf_counter() - t0, 1)
    for line in proc.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            out = json.loads(line[len("@@RESULT@@"):])
            out["seconds"] = seconds
            return out
    tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
    return {"results": {"run": f"error: {tail}"}, "fallbacks": [], "seconds": seconds}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--opencv", action="append", default=[], help="OpenCV source tree (repeat)")
    p.add_argument("--data", help="OpenCV samples/data folder")
    p.add_argument("--backends", nargs="+", default=["cpu", "warp-cpu"])
    p.add_argument("--frames", type=int, default=60, help="frames per sample (waitKey calls)")
    p.add_argument("--timeout", type=int, default=300, help="seconds per file and mode")
    p.add_argument("--out", default="benchmarks/results/opencv_suite")
    p.add_argument("--only", nargs="*", help="run only these tests/samples (by name)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--kind", help=argparse.SUPPRESS)
    p.add_argument("--file", help=argparse.SUPPRESS)
    p.add_argument("--mode", help=argparse.SUPPRESS)
    p.add_argument("--repo", help=argparse.SUPPRESS)
    p.add_argument("--extra-path", nargs="*", default=[], help=argparse.SUPPRESS)
    p.add_argument("--argv", action="append", default=[], help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.argv = [a for a in args.argv if a]
    if args.child:
        return _child(args)
    if not args.opencv or not args.data:
        p.error("--opencv and --data are required")
    args.data = os.path.abspath(args.data)
    args.repo = _repo_with_data(args.data, args.out)
    roots = [os.path.abspath(r) for r in args.opencv]
    extra_path = [d for r in roots for pat in _TEST_DIRS[:1] + _SAMPLE_DIRS
                  for d in glob.glob(os.path.join(r, pat))]
    jobs = [("test", n, find(roots, n, _TEST_DIRS), []) for n in TESTS]
    jobs += [("sample", n, find(roots, n.split()[0], _SAMPLE_DIRS), a) for n, a in SAMPLES.items()]
    jobs = [j for j in jobs if not args.only or j[1] in args.only]
    modes = ["cv2"] + list(args.backends)
    record = {"command": " ".join(["PYTHONPATH=. python benchmarks/opencv_suite.py"] + sys.argv[1:]),
              "modes": modes, "items": []}
    for kind, name, path, sample_argv in jobs:
        if path is None:
            print(f"{name}: not found under {roots}", flush=True)
            record["items"].append({"kind": kind, "name": name, "path": None})
            continue
        item = {"kind": kind, "name": name, "path": _relative(path, roots), "modes": {}}
        for mode in modes:
            item["modes"][mode] = _run_one(args, kind, name, path, sample_argv, mode, extra_path)
            print(f"{name} [{mode}]: {item['modes'][mode]}", flush=True)
        record["items"].append(item)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(record, f, indent=1)
    with open(os.path.join(args.out, "results.md"), "w") as f:
        f.write(_markdown(record))
    print(_markdown(record))


def _repo_with_data(data, out):
    """A folder whose ``samples/data`` is ``data`` (what OpenCV's tests look files up under)."""
    import tempfile

    repo = tempfile.mkdtemp(prefix="opencv_suite_")
    os.makedirs(os.path.join(repo, "samples"))
    os.symlink(data, os.path.join(repo, "samples", "data"))
    return repo


def _relative(path, roots):
    for r in roots:
        if path.startswith(r + os.sep):
            return f"{os.path.basename(r)}/{os.path.relpath(path, r)}"
    return path


def _markdown(record):
    modes = record["modes"]
    lines = [f"Command: `{record['command']}`", "",
             "| kind | test / sample | " + " | ".join(modes) + " | routed to cv2 (warpvx) |",
             "|---" * (len(modes) + 3) + "|"]
    totals = {m: [0, 0] for m in modes}
    for item in record["items"]:
        if item.get("path") is None:
            lines.append(f"| {item['kind']} | {item['name']} (not found) |" + " |" * (len(modes) + 1))
            continue
        names = list(item["modes"][modes[0]]["results"])
        for m in modes[1:]:
            names += [n for n in item["modes"][m]["results"] if n not in names]
        fallbacks = sorted({f for m in modes[1:] for f in item["modes"][m]["fallbacks"]})
        for n in names:
            cells = []
            for m in modes:
                r = item["modes"][m]["results"].get(n, "missing")
                totals[m][0] += r == "pass"
                totals[m][1] += 1
                cells.append("pass" if r == "pass" else r[:90].replace("|", "/"))
            label = item["name"] if n == "run" else f"{item['name']}::{n.split('.')[-1]}"
            lines.append(f"| {item['kind']} | {label} | " + " | ".join(cells) + " | "
                         + ", ".join(fallbacks) + " |")
    lines += ["", "Passed: " + ", ".join(f"{m} {p}/{t}" for m, (p, t) in totals.items()), ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
