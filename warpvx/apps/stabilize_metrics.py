"""Quality metrics of video stabilization, callable on any input/output pair of videos.

Frames are lists of BGR uint8 HxWx3 (or gray HxW) images of one size. Everything here uses
plain OpenCV (Shi-Tomasi corners, pyramidal LK, RANSAC similarity), never the stabilizer's own
code, so the metrics can judge it. Black pixels (0 in every channel) count as outside the
valid region (the borders a warp uncovers).

* :func:`mad` -- thesis eq. 3.1: K KLT points tracked through the video; per track the median
  absolute deviation (about the median) of x and of y over time; the mean over tracks and
  both coordinates, in px (0 for a static video).
* :func:`itf` -- inter-frame transformation fidelity: mean PSNR (dB) of consecutive frames over
  their common valid region, capped at :data:`PSNR_MAX` (identical frames).
* :func:`stability_score` -- Liu et al. 2013 (Bundled camera paths): the chained inter-frame
  similarity gives a translation-magnitude and a rotation sequence; for each, the energy in
  FFT bins 1-5 over all bins except DC (one-sided spectrum); the smaller of the two (1 is
  perfectly smooth).
* :func:`cropping_distortion` -- from the per-frame input -> output homographies: cropping
  ratio (mean of 1 / scale) and distortion (worst ratio of the affine part's eigenvalues).
* :func:`shake_rms` -- with a known static scene: the high-passed RMS displacement (px) of a grid
  of points between each frame and the reference image; run on the shaken input (the applied
  shake) and on the output (the residual shake). :func:`shaky_clip` makes such clips.
* :func:`evaluate_shots` -- ITF and stability per shot of a clip with scene cuts (``evaluate``
  with ``cuts`` leaves the pairs across the cuts out of the clip-wide ones).
"""

from __future__ import annotations

import math

import numpy as np

from ..check import check_int
from ..errors import WarpvxTypeError

#: ITF of identical consecutive frames (their PSNR is infinite).
PSNR_MAX = 100.0

_LK = dict(winSize=(21, 21), maxLevel=3)


def _gray(frame):
    import cv2

    return frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)


def _valid(frame, erode=7):
    """uint8 mask of the pixels not black in every channel, eroded by ``erode`` px."""
    import cv2

    m = (frame.reshape(frame.shape[0], frame.shape[1], -1).max(axis=2) > 0).astype(np.uint8)
    return cv2.erode(m, np.ones((erode, erode), np.uint8)) if erode else m


def track_points(frames, n_points=10):
    """KLT tracks through the whole video: float32 [T, K', 2] for the K' <= ``n_points``
    strongest corners of frame 0 (inside the common valid region) that survive every frame."""
    import cv2

    common = _valid(frames[0])
    for f in frames[1:]:
        common &= _valid(f)
    prev = _gray(frames[0])
    pts = cv2.goodFeaturesToTrack(prev, n_points, 0.01, 10, mask=common)
    if pts is None:
        return np.zeros((len(frames), 0, 2), np.float32)
    pts = pts.reshape(-1, 2)
    tracks, alive = [pts], np.ones(len(pts), bool)
    for f in frames[1:]:
        gray = _gray(f)
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev, gray, tracks[-1], None, **_LK)
        alive &= status.reshape(-1).astype(bool)
        tracks.append(nxt.reshape(-1, 2))
        prev = gray
    return np.stack(tracks)[:, alive]


def mad(frames, n_points=10):
    """Thesis MAD (eq. 3.1) in px over ``n_points`` KLT tracks; NaN when no track survives."""
    tracks = track_points(frames, n_points)
    if tracks.shape[1] == 0:
        return float("nan")
    dev = np.median(np.abs(tracks - np.median(tracks, axis=0)), axis=0)  # [K', 2]
    return float(dev.mean())


def _cuts(cuts, n) -> list:
    """``cuts`` checked for an ``n``-frame clip: frame indices 1 .. n-1 (a cut before frame 0
    or past the clip is a caller's mistake, not a cut to ignore), ascending, no repeats."""
    try:
        values = list(cuts)
    except TypeError:
        raise WarpvxTypeError(f"cuts: expected a sequence of frame indices, got {type(cuts).__name__}") from None
    return sorted({check_int(c, "cuts", min_value=1, max_value=n - 1) for c in values})


def _shots(n, cuts):
    """``[(first, end)]`` frame ranges of the shots of an ``n``-frame clip cut before ``cuts``."""
    edges = [0, *_cuts(cuts, n), n]
    return list(zip(edges[:-1], edges[1:]))


def itf(frames, cuts=()):
    """Mean PSNR (dB) of consecutive gray frames over the pixels valid in both; pairs that
    match exactly count :data:`PSNR_MAX`. ``cuts``: frames starting a new shot; the pairs
    across a cut are left out (two shots' frames, not motion)."""
    values = []
    cut = set(_cuts(cuts, len(frames)))
    for i, (a, b) in enumerate(zip(frames[:-1], frames[1:])):
        if i + 1 in cut:
            continue
        region = (_valid(a, 0) & _valid(b, 0)).astype(bool)
        if not region.any():
            continue
        d = _gray(a).astype(np.float64)[region] - _gray(b).astype(np.float64)[region]
        mse = float(np.mean(d * d))
        values.append(PSNR_MAX if mse == 0 else min(PSNR_MAX, 10 * math.log10(255.0 ** 2 / mse)))
    return float(np.mean(values)) if values else float("nan")


def similarity(a, b, n_points=200):
    """The RANSAC similarity (float64 3x3) mapping image ``a`` to image ``b`` (identity when it
    cannot be estimated): Shi-Tomasi corners of ``a`` in its valid region, LK to ``b``."""
    import cv2

    ga, gb = _gray(a), _gray(b)
    pts = cv2.goodFeaturesToTrack(ga, n_points, 0.01, 8, mask=_valid(a))
    if pts is None or len(pts) < 3:
        return np.eye(3)
    nxt, status, _ = cv2.calcOpticalFlowPyrLK(ga, gb, pts, None, **_LK)
    ok = status.reshape(-1).astype(bool)
    if ok.sum() < 3:
        return np.eye(3)
    A, _ = cv2.estimateAffinePartial2D(pts.reshape(-1, 2)[ok], nxt.reshape(-1, 2)[ok],
                                       method=cv2.RANSAC, ransacReprojThreshold=2.0)
    return np.eye(3) if A is None else np.vstack([A, [0.0, 0.0, 1.0]])


def _low_frequency_share(seq):
    """Energy of FFT bins 1-5 over bins 1..n/2 (one-sided, DC excluded); 1 for a flat path."""
    power = np.abs(np.fft.fft(np.asarray(seq, np.float64))) ** 2
    power = power[1:len(power) // 2 + 1]
    total = power.sum()
    return 1.0 if total <= 1e-12 else float(power[:5].sum() / total)


def stability_score(frames, cuts=()):
    """Liu et al. 2013 stability score in [0, 1] of a video (needs >= 3 frames).

    ``cuts``: frames starting a new shot; the score is then the mean of the shots' scores
    weighted by their frames, shots of under 3 frames left out (NaN if none is left): chaining
    the motion across a cut would measure the jump between two shots.
    """
    shots = _shots(len(frames), cuts)
    if len(shots) > 1:
        shots = [(a, b) for a, b in shots if b - a >= 3]
        if not shots:
            return float("nan")
        return float(sum((b - a) * stability_score(frames[a:b]) for a, b in shots)
                     / sum(b - a for a, b in shots))
    P = np.eye(3)
    trans, rot = [], []
    for a, b in zip(frames[:-1], frames[1:]):
        P = similarity(a, b) @ P
        trans.append(math.hypot(P[0, 2], P[1, 2]))
        rot.append(math.atan2(P[1, 0], P[0, 0]))
    return min(_low_frequency_share(trans), _low_frequency_share(rot))


def cropping_distortion(homographies):
    """(cropping ratio, distortion) from float64 3x3 input -> output homographies.

    Cropping ratio: the mean over frames of 1 / s, s the scale of the affine part
    (sqrt(M00^2 + M01^2)); 1 = no zoom. Distortion: the smallest over frames of the ratio
    of the affine part's eigenvalue magnitudes (smaller over larger); 1 = no anisotropy.
    """
    ratios, distortions = [], []
    for M in homographies:
        M = np.asarray(M, np.float64) / M[2, 2]
        ratios.append(1.0 / math.hypot(M[0, 0], M[0, 1]))
        ev = np.sort(np.abs(np.linalg.eigvals(M[:2, :2])))
        distortions.append(ev[0] / ev[1])
    return float(np.mean(ratios)), float(np.min(distortions))


def _grid(size, n=5, margin=0.2):
    w, h = size
    xs = np.linspace(margin * (w - 1), (1 - margin) * (w - 1), n)
    ys = np.linspace(margin * (h - 1), (1 - margin) * (h - 1), n)
    return np.array([[x, y, 1.0] for y in ys for x in xs]).T  # 3 x n^2


def shake_rms(frames, reference, window=15):
    """High-passed RMS displacement (px) of the frames against a static ``reference`` image.

    Each frame is registered to ``reference`` (RANSAC similarity); a 5x5 grid of points over
    the reference's central 60% is moved by each registration; the displacements minus their
    centred moving average over ``window`` frames (smooth motion is not shake) give the RMS.
    """
    size = reference.shape[1::-1]
    grid = _grid(size)
    disp = []
    for f in frames:
        moved = similarity(reference, f) @ grid
        disp.append((moved[:2] / moved[2] - grid[:2]).T)  # [P, 2]
    disp = np.array(disp)  # [T, P, 2]
    kernel = np.ones(window) / window
    pad = window // 2
    padded = np.pad(disp, ((pad, window - 1 - pad), (0, 0), (0, 0)), mode="edge")
    trend = np.apply_along_axis(lambda s: np.convolve(s, kernel, mode="valid"), 0, padded)
    return float(np.sqrt(np.mean(np.sum((disp - trend) ** 2, axis=-1))))


def shaky_clip(image, n_frames, size, *, shift=4.0, angle=1.0, zoom=0.01, seed=0):
    """A known-jitter clip: the centre ``size`` (w, h) of ``image`` moved by an independent
    random similarity per frame (shift px, angle degrees and relative zoom, each uniform in
    +-the given bound) about the centre.

    Returns ``(frames, reference, transforms)``: BGR uint8 frames, the unshaken centre crop,
    and the float64 3x3 reference -> frame transforms.
    """
    import cv2

    rng = np.random.default_rng(seed)
    w, h = size
    H, W = image.shape[:2]
    if W < w or H < h:
        raise ValueError(f"size: {w}x{h} exceeds the image's {W}x{H}")
    to_crop = np.array([[1, 0, -(W - w) / 2], [0, 1, -(H - h) / 2], [0, 0, 1.0]])
    reference = cv2.warpPerspective(image, to_crop, (w, h))
    frames, transforms = [], []
    for _ in range(n_frames):
        tx, ty = rng.uniform(-shift, shift, 2)
        A = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), rng.uniform(-angle, angle),
                                    1 + rng.uniform(-zoom, zoom))
        A[:, 2] += (tx, ty)
        M = np.vstack([A, [0, 0, 1.0]])
        frames.append(cv2.warpPerspective(image, M @ to_crop, (w, h), flags=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_REFLECT))
        transforms.append(M)
    return frames, reference, transforms


def evaluate(inputs, outputs, homographies=None, cuts=()):
    """All metrics of one input/output pair as a dict (JSON-ready): for ``"input"`` and
    ``"output"`` MAD10/MAD100 (px), ITF (dB) and stability; for the output also the cropping
    ratio, distortion and ``mad10_input_px``/``mad100_input_px`` (MAD times the cropping ratio).

    ``homographies``: the per-frame input -> output warps when known (the stabilizer's
    ``warp``); else estimated from the frames (RANSAC similarity). ``cuts``: the frames
    starting a new shot (``scene_cuts``): ITF and stability then leave out the pairs across
    the cuts, for the input and the output alike (:func:`itf`, :func:`stability_score`).
    """
    if homographies is None:
        homographies = [similarity(a, b) for a, b in zip(inputs, outputs)]
    crop, distortion = cropping_distortion(homographies)
    report = {}
    for key, frames in (("input", inputs), ("output", outputs)):
        report[key] = {"mad10": mad(frames, 10), "mad100": mad(frames, 100), "itf": itf(frames, cuts),
                       "stability": stability_score(frames, cuts)}
    out = report["output"]
    # The crop's zoom scales every output motion by 1 / crop: MAD in input pixels compares
    # with the input and with stabilizers that do not zoom.
    out.update(cropping_ratio=crop, distortion=distortion, mad10_input_px=out["mad10"] * crop,
               mad100_input_px=out["mad100"] * crop)
    return report


def evaluate_shots(inputs, outputs, cuts):
    """ITF (dB) and stability of each shot of a clip with scene cuts, input and output: a list
    of ``{"frames": [first, last], "input": {...}, "output": {...}}`` (JSON-ready).

    ``cuts``: the frames starting a new shot, ascending (``scene_cuts``). A shot of under 3
    frames has no stability (NaN).
    """
    shots = []
    for a, b in _shots(len(inputs), cuts):
        shot = {"frames": [a, b - 1]}
        for key, frames in (("input", inputs[a:b]), ("output", outputs[a:b])):
            shot[key] = {"itf": itf(frames),
                         "stability": stability_score(frames) if b - a >= 3 else float("nan")}
        shots.append(shot)
    return shots


__all__ = ["PSNR_MAX", "track_points", "mad", "itf", "similarity", "stability_score",
           "cropping_distortion", "shake_rms", "shaky_clip", "evaluate", "evaluate_shots"]
