"""Stabilization metrics against hand-computable cases (warpvx.apps.stabilize_metrics)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tests.apps.conftest import static_frames
from warpvx.apps import stabilize_metrics as sm
from warpvx.errors import WarpvxError


def test_static_clip_has_zero_mad_max_itf_full_stability(astronaut):
    frames = static_frames(astronaut, 8)
    assert sm.mad(frames, 10) == pytest.approx(0.0, abs=1e-3)
    assert sm.mad(frames, 100) == pytest.approx(0.0, abs=1e-3)
    assert sm.itf(frames) == sm.PSNR_MAX
    assert sm.stability_score(frames) == pytest.approx(1.0)


def test_itf_is_the_psnr_of_a_known_difference(astronaut):
    a = static_frames(astronaut, 1)[0]
    b = np.clip(a.astype(int) + 10, 1, 255).astype(np.uint8)  # no pixel turns black
    d = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY).astype(float) - cv2.cvtColor(b, cv2.COLOR_BGR2GRAY)
    want = 10 * math.log10(255 ** 2 / np.mean(d ** 2))
    assert sm.itf([a, b]) == pytest.approx(want, rel=1e-9)


def test_black_borders_are_outside_the_valid_region(astronaut):
    a = static_frames(astronaut, 1)[0]
    b = a.copy()
    b[:, :20] = 0  # a border a warp uncovered: ignored, so the pair still matches exactly
    assert sm.itf([a, b]) == sm.PSNR_MAX


def test_mad_of_a_translation_shake_is_the_mad_of_the_shifts(astronaut):
    frames, _, Ms = sm.shaky_clip(astronaut, 12, (160, 120), shift=5.0, angle=0.0, zoom=0.0, seed=3)
    tx = np.array([M[0, 2] for M in Ms])
    ty = np.array([M[1, 2] for M in Ms])
    want = 0.5 * (np.median(np.abs(tx - np.median(tx))) + np.median(np.abs(ty - np.median(ty))))
    assert sm.mad(frames, 10) == pytest.approx(want, abs=0.1)


def test_cropping_and_distortion_of_known_homographies():
    zoom = np.diag([1.25, 1.25, 1.0])
    stretch = np.diag([2.0, 1.0, 1.0])
    crop, distortion = sm.cropping_distortion([zoom, zoom])
    assert crop == pytest.approx(0.8) and distortion == pytest.approx(1.0)
    crop, distortion = sm.cropping_distortion([zoom, stretch])
    assert crop == pytest.approx((0.8 + 0.5) / 2) and distortion == pytest.approx(0.5)


def test_stability_prefers_a_smooth_pan_to_a_shake(astronaut):
    size = (160, 120)
    pan = [cv2.warpAffine(astronaut, np.float32([[1, 0, -100 - 2 * k], [0, 1, -100]]), size)
           for k in range(16)]
    shaky, _, _ = sm.shaky_clip(astronaut, 16, size, shift=4.0, seed=1)
    assert sm.stability_score(pan) > 0.85  # a ramp: most energy in the lowest bins
    assert sm.stability_score(shaky) < sm.stability_score(pan) - 0.2


def test_shake_rms_measures_the_applied_shake(astronaut):
    frames, ref, Ms = sm.shaky_clip(astronaut, 20, (160, 120), shift=4.0, angle=1.0, seed=2)
    # The same measure from the known transforms: grid displacements, high-passed, RMS.
    w, h = 160, 120
    xs, ys = np.meshgrid(np.linspace(0.2 * (w - 1), 0.8 * (w - 1), 5),
                         np.linspace(0.2 * (h - 1), 0.8 * (h - 1), 5))
    grid = np.stack([xs.ravel(), ys.ravel(), np.ones(25)])
    disp = np.array([(M @ grid)[:2].T - grid[:2].T for M in Ms])
    trend = np.array([disp[max(0, k - 7):k + 8].mean(0) for k in range(len(disp))])
    # (edge frames differ: the module pads by repetition; the bulk decides the RMS)
    known = np.sqrt(np.mean(np.sum((disp - trend) ** 2, -1)))
    assert sm.shake_rms(frames, ref) == pytest.approx(known, rel=0.15)


def test_evaluate_reports_every_metric(astronaut):
    frames = static_frames(astronaut, 6)
    report = sm.evaluate(frames, frames)
    assert set(report["input"]) == {"mad10", "mad100", "itf", "stability"}
    assert report["output"]["cropping_ratio"] == pytest.approx(1.0, abs=1e-3)


def test_cuts_leave_the_pairs_across_them_out_of_itf_and_stability(astronaut):
    # Two static shots of different photos: every pair inside a shot matches exactly, the pair
    # across the cut does not. With the cut, ITF is the shots' (PSNR_MAX) and stability theirs
    # (1, a flat path); without it, the jump between the photos counts.
    other = cv2.flip(astronaut, 1)
    frames = static_frames(astronaut, 5) + static_frames(other, 6)
    assert sm.itf(frames, cuts=[5]) == sm.PSNR_MAX
    assert sm.itf(frames) < sm.PSNR_MAX
    assert sm.stability_score(frames, cuts=[5]) == pytest.approx(1.0)
    shaky, _, _ = sm.shaky_clip(astronaut, 9, (160, 120), shift=4.0, seed=4)
    pan = [cv2.warpAffine(astronaut, np.float32([[1, 0, -100 - 2 * k], [0, 1, -100]]), (160, 120))
           for k in range(12)]
    mixed = shaky + pan
    # frame-weighted mean of the shots' scores (9 and 12 frames)
    want = (9 * sm.stability_score(shaky) + 12 * sm.stability_score(pan)) / 21
    assert sm.stability_score(mixed, cuts=[9]) == pytest.approx(want, rel=1e-12)
    report = sm.evaluate(frames, frames, cuts=[5])
    assert report["input"]["itf"] == sm.PSNR_MAX and report["output"]["stability"] == pytest.approx(1.0)


@pytest.mark.parametrize("cuts, error", [([0], "WarpvxValueError"), ([5, 11], "WarpvxValueError"),
                                         ([-2], "WarpvxValueError"), ([2.5], "WarpvxTypeError"),
                                         (["3"], "WarpvxTypeError"), (5, "WarpvxTypeError"),
                                         ([True], "WarpvxTypeError")])
def test_bad_cuts_are_refused_by_name(astronaut, cuts, error):
    frames = static_frames(astronaut, 11)  # cuts may be 1 .. 10
    for fn in (lambda: sm.itf(frames, cuts), lambda: sm.stability_score(frames, cuts),
               lambda: sm.evaluate(frames, frames, cuts=cuts), lambda: sm.evaluate_shots(frames, frames, cuts)):
        with pytest.raises(WarpvxError, match="cuts") as info:
            fn()
        assert type(info.value).__name__ == error
