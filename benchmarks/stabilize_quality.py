"""Quality of the video stabilizer beside what users use today (issue 12's quality table).

Usage (from the repository root, CPU only, about two minutes on 2 cores):

    PYTHONPATH=. python benchmarks/stabilize_quality.py --out benchmarks/results/stabilize

Clips: the bundled real hand-held clip (``warpvx/data/bikes_shaky.mp4``, 46 frames 640x272),
the first ``--montage-frames`` frames of ``bikes.mp4`` (its 6-shot montage, scene cuts at 30, 76
and 137; from ``../shared/data/real/`` when present; also run with cut detection off) and
known-jitter clips: a random similarity shake per frame (``shaky_clip``: +-4 px, +-1 deg,
+-1% zoom) applied to real static photos (the bundled astronaut; ``leuvenA.jpg`` from
``../shared/data/real/`` when present). Methods: the input; ``vidstab`` (PyPI, MIT licence;
skipped with the reason when it does not import) with the same smoothing window and black
borders; and for the homography (thesis) and similarity models: the imperative OpenCV model,
the warpvx graph on ``cpu`` and on ``warp-cpu``. Every output is judged by
:mod:`warpvx.apps.stabilize_metrics` (plain OpenCV, none of the stabilizer's code).

MAD is measured in the output video's pixels (the thesis' definition), so the crop's zoom
(1 / (1 - 2 crop) = 1.25 at the default crop 0.1) scales every residual motion, pans included;
``MAD10 in``/``MAD100 in`` are MAD times the cropping ratio: the same motion in input pixels, comparable
with the input row and with vidstab (no zoom). Residual shake is in output pixels too.

Writes ``quality.md`` (the table) and ``quality.json`` into ``--out`` (default ``$OUT``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from importlib.resources import files

import cv2

from warpvx.apps import stabilize as st
from warpvx.apps import stabilize_metrics as sm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def shared_file(name):
    """The path of ``name`` in ../shared/data/real/ beside the checkout (or beside the folder
    of git worktrees), or None."""
    for up in ([".."], ["..", ".."]):
        path = os.path.join(ROOT, *up, "shared", "data", "real", name)
        if os.path.exists(path):
            return path
    return None

MONTAGE = "bikes.mp4 montage (real, scene cuts)"
#: The montage's scene cuts in its first 150 frames (frames looked at; the stabilizer finds the
#: same): every method's ITF and stability leave out the pairs across them.
MONTAGE_CUTS = (30, 76, 137)
COLUMNS = ("mad10", "mad10_in", "mad100", "mad100_in", "itf", "stability", "cropping_ratio", "distortion",
           "shake")


def read_video(path, max_frames=None):
    return list(st.VideoSource(path, max_frames))


def write_lossless(path, frames, fps=25.0):
    """FFV1 in AVI: vidstab reads and writes files; a lossless codec keeps ITF honest."""
    w = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"FFV1"), fps, frames[0].shape[1::-1])
    for f in frames:
        w.write(f)
    w.release()


def clips(n_jitter, n_montage):
    """(name, frames, reference image or None, scene cuts) of every clip."""
    out = [("bikes_shaky (real)", read_video(str(files("warpvx") / "data" / "bikes_shaky.mp4")), None, ())]
    montage = shared_file("bikes.mp4")
    if montage is not None:
        frames = read_video(montage, n_montage)
        out.append((MONTAGE, frames, None, tuple(c for c in MONTAGE_CUTS if c < len(frames))))
    photos = [("astronaut", cv2.imread(str(files("warpvx") / "data" / "astronaut_448.png")), (320, 240))]
    leuven = shared_file("leuvenA.jpg")
    if leuven is not None:
        photos.append(("leuvenA", cv2.imread(leuven), (640, 480)))
    for name, image, size in photos:
        frames, ref, _ = sm.shaky_clip(image, n_jitter, size, shift=4.0, angle=1.0, zoom=0.01, seed=0)
        out.append((f"{name} + known jitter", frames, ref, ()))
    return out


def vidstab_runner(window):
    """A function frames -> stabilized frames through vidstab, or (None, reason)."""
    try:
        # vidstab 1.7 predates OpenCV 5: imutils' detector table names BRISK_create (gone from
        # the main module) and vidstab takes OpenCV 5 for OpenCV 3 (imutils.is_cv4 is False),
        # and it closes windows a headless build lacks. Only GFTT and the OpenCV 4 path are used.
        if not hasattr(cv2, "BRISK_create"):
            cv2.BRISK_create = None
        cv2.destroyAllWindows = lambda: None
        import imutils

        if int(cv2.__version__.split(".")[0]) >= 4:
            imutils.is_cv4 = lambda *a, **k: True
        from vidstab import VidStab
    except Exception as exc:  # noqa: BLE001 -- any import failure skips the row, with its reason
        return None, f"vidstab does not import ({type(exc).__name__}: {exc}); pip install vidstab"

    def run(frames):
        with tempfile.TemporaryDirectory() as tmp:
            src, dst = os.path.join(tmp, "in.avi"), os.path.join(tmp, "out.avi")
            write_lossless(src, frames)
            VidStab().stabilize(src, dst, smoothing_window=window, border_type="black",
                                output_fourcc="FFV1", show_progress=False)
            return read_video(dst)

    return run, None


def score(frames, inputs, warps, reference, cuts=()):
    rep = sm.evaluate(inputs, frames, warps, cuts)["output"]
    rep["mad10_in"], rep["mad100_in"] = rep["mad10_input_px"], rep["mad100_input_px"]
    rep["shake"] = sm.shake_rms(frames, reference) if reference is not None else None
    return rep


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.environ.get("OUT"), help="results folder (default $OUT)")
    parser.add_argument("--frames", type=int, default=60, help="frames of each known-jitter clip")
    parser.add_argument("--montage-frames", type=int, default=150,
                        help="frames of bikes.mp4's montage (cuts at 30, 76, 137)")
    parser.add_argument("--window", type=int, default=st.StabilizerConfig().window)
    args = parser.parse_args(argv)
    if not args.out:
        parser.error("--out: give a folder (or set $OUT)")
    os.makedirs(args.out, exist_ok=True)
    vidstab, why = vidstab_runner(args.window)
    results = []
    for clip, frames, ref, cuts in clips(args.frames, args.montage_frames):
        print(f"{clip}: {len(frames)} frames {frames[0].shape[1]}x{frames[0].shape[0]}", flush=True)
        inp = sm.evaluate(frames, frames, cuts=cuts)["input"]
        inp.update(mad10_in=inp["mad10"], mad100_in=inp["mad100"], cropping_ratio=1.0, distortion=1.0,
                   shake=sm.shake_rms(frames, ref) if ref is not None else None)
        results.append({"clip": clip, "method": "input", **inp})
        runs = []
        if vidstab is not None:
            runs.append(("vidstab", lambda f: (vidstab(f), None)))
        for motion in ("homography", "similarity"):
            cfg = st.StabilizerConfig(window=args.window, motion=motion)
            runs.append((f"OpenCV model ({motion})", lambda f, c=cfg: _unpack(st.stabilize_model(f, c))))
            for backend in ("cpu", "warp-cpu"):
                runs.append((f"warpvx {backend} ({motion})",
                             lambda f, c=cfg, b=backend: _unpack(st.stabilize(f, c, backend=b))))
        if clip == MONTAGE:  # what the scene cut detection is worth
            cfg = st.StabilizerConfig(window=args.window, cut_threshold=None)
            runs.append(("warpvx cpu (homography, cuts not detected)",
                         lambda f, c=cfg: _unpack(st.stabilize(f, c, backend="cpu"))))
        for method, fn in runs:
            t = time.perf_counter()
            out, warps = fn(frames)
            seconds = time.perf_counter() - t
            results.append({"clip": clip, "method": method, "seconds": seconds,
                            **score(out, frames, warps, ref, cuts)})
            print(f"  {method}: {seconds:.1f} s", flush=True)
    table = render(results, why, args)
    with open(os.path.join(args.out, "quality.md"), "w") as f:
        f.write(table)
    with open(os.path.join(args.out, "quality.json"), "w") as f:
        json.dump({"vidstab_skipped": why, "window": args.window, "results": results}, f, indent=2)
    print(table)
    return 0


def _unpack(stabilized):
    outs = list(stabilized)
    return [o.image for o in outs], [o.warp for o in outs]


def render(results, why, args):
    def cell(v):
        return "-" if v is None else f"{v:.3f}" if abs(v) < 10 else f"{v:.2f}"

    lines = [
        "<!-- PYTHONPATH=. python benchmarks/stabilize_quality.py --out benchmarks/results/stabilize -->",
        f"# Stabilizer quality (window {args.window}, centred, crop 0.1; vidstab: same window, "
        "black borders, no crop)", "",
        "MAD10/MAD100 (px, output pixels, lower is steadier), MAD10/100 in (times the cropping "
        "ratio: input pixels), ITF (dB, higher is better), stability (Liu et al., higher is better), "
        "cropping ratio (1 = no zoom), distortion (1 = none), shake (high-passed RMS px against "
        "the known static scene, lower is better). The bikes.mp4 montage (its first frames, "
        f"scene cuts before frames {', '.join(map(str, MONTAGE_CUTS))}): ITF and stability leave "
        "out the pairs across the cuts, for the input and every method alike; MAD is not defined "
        "across cuts (nan).", "",
        "| clip | method | " + " | ".join(COLUMNS) + " |",
        "|---|---|" + "---|" * len(COLUMNS)]
    for r in results:
        lines.append(f"| {r['clip']} | {r['method']} | " + " | ".join(cell(r.get(c)) for c in COLUMNS) + " |")
    if why:
        lines += ["", f"vidstab skipped: {why}"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
