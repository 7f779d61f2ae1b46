"""The front end's matching (warpvx.apps.orbslam_match): the frame-to-frame ``match`` node's
mutual pairs against ``match_hamming(cross_check=True)``, and the vectorised stereo matching
against a per-keypoint transcription of ORB-SLAM2's ``Frame::ComputeStereoMatches`` rules."""

from __future__ import annotations

import numpy as np
import pytest

import warpvx
from warpvx.apps import orbslam_match as om
from warpvx.apps.orbslam_synth import render_sequence
from warpvx.keypoints import FIELDS


@pytest.fixture(scope="module")
def frames():
    """ORB features of two consecutive rendered frames and the right image of the first
    (640x480, stereo baseline 0.2 m): real descriptors, keypoint counts differing."""
    left, right, _, _ = render_sequence(2, (640, 480), baseline=0.2, supersample=1)
    feats = [warpvx.orb(im, backend="cpu") for im in (left[0], left[1], right[0])]
    return left, right, feats


def _node_pairs(desc, prev, backend):
    """The ``match`` node's outputs on ``backend`` turned into pairs (what ``track`` gets)."""
    if backend == "cpu":
        _, idx, dist, back = om.nearest_both_ways(desc, prev)
        padded_prev = prev
    else:
        import warp as wp

        from warpvx.backend import resolve_backend

        device = resolve_backend(backend).device

        def to(a):
            return wp.array(a, dtype=wp.uint8, device=device)

        padded_prev, *_ = om.nearest_both_ways_warp(to(prev), to(np.zeros((0, 32), np.uint8)))
        padded, idx, dist, back = om.nearest_both_ways_warp(to(desc), padded_prev)
        assert padded.shape[0] % om.ROW_BUCKET == 0 and padded.shape[0] >= len(desc)
        idx, dist, back = idx.numpy(), dist.numpy(), back.numpy()
    return om.mutual_pairs(idx, dist, back, len(desc), len(prev))


@pytest.mark.parametrize("kind", ["orb", "ties"])
def test_match_node_keeps_what_cross_check_keeps(frames, backend, kind):
    if kind == "orb":
        desc, prev = np.asarray(frames[2][1][1]), np.asarray(frames[2][0][1])
    else:  # few distinct rows: ties everywhere, where a padding row could steal a match
        rng = np.random.default_rng(3)
        pool = rng.integers(0, 256, (12, 32), dtype=np.uint8)
        desc, prev = pool[rng.integers(0, 12, 300)], pool[rng.integers(0, 12, 270)]
    assert len(desc) != len(prev)
    want_pairs, want_dist = warpvx.match_hamming(desc, prev, cross_check=True, backend="cpu")
    pairs, dist = _node_pairs(desc, prev, backend)
    assert len(want_pairs) > 10
    np.testing.assert_array_equal(pairs, want_pairs)
    np.testing.assert_array_equal(dist, want_dist)


@pytest.mark.parametrize("empty", [False, True], ids=["orb", "with-empty-frames"])
def test_batch_match_node_equals_cross_check_per_pair(frames, backend, empty):
    """nearest_batch[_warp] (the device: one launch for all pairs): frame f against frame
    f - 1 for B frames, each pair's mutual pairs those of match_hamming(cross_check=True); the
    first output is the last frame's descriptors (the next batch's ``prev``). The descriptors
    are rows of one buffer (as orb returns a batch's) or, with empty frames, separate arrays."""
    descs = [np.asarray(f[1]) for f in frames[2]]  # left 0, left 1, right 0: 3 sizes
    none = np.zeros((0, 32), np.uint8)
    if empty:
        descs = [descs[0], none, descs[1], descs[2], none]
    prev = descs[-2][::2].copy()
    if backend == "cpu":
        last, (nearest, distance, starts) = om.nearest_batch(descs, prev)
    else:
        import warp as wp

        from warpvx.backend import resolve_backend

        device = resolve_backend(backend).device
        if empty:
            on_device = [wp.array(d, dtype=wp.uint8, device=device) for d in descs]
        else:  # views of one buffer, frame after frame
            buf = wp.array(np.concatenate(descs), device=device)
            cut = np.cumsum([0] + [len(d) for d in descs]).tolist()
            on_device = [buf[a:b] for a, b in zip(cut[:-1], cut[1:])]
        last, (nearest, distance, starts) = om.nearest_batch_warp(on_device, wp.array(prev, device=device))
        last, nearest, distance, starts = (a.numpy() for a in (last, nearest, distance, starts))
    np.testing.assert_array_equal(last, descs[-1])
    chain = [prev] + descs
    np.testing.assert_array_equal(starts, np.cumsum([0] + [len(d) for d in chain]))
    for f in range(1, len(chain)):
        want = warpvx.match_hamming(chain[f], chain[f - 1], cross_check=True, backend="cpu")
        got = om.mutual_pairs(*om.batch_pairs(nearest, distance, starts, f), len(chain[f]), len(chain[f - 1]))
        assert len(want[0]) > 10 or 0 in (len(chain[f]), len(chain[f - 1]))
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
    # The nearest rows themselves, both ways, as knn_match_hamming gives them.
    idx, dist = warpvx.knn_match_hamming(chain[1], chain[0], 1, backend="cpu")
    a, b, c = starts[:3]
    np.testing.assert_array_equal(nearest[0, b:c], idx[:, 0])
    np.testing.assert_array_equal(distance[0, b:c], dist[:, 0])
    back, _ = warpvx.knn_match_hamming(chain[0], chain[1], 1, backend="cpu")
    np.testing.assert_array_equal(nearest[1, a:b], back[:, 0])


def test_mutual_pairs_with_nothing_to_match():
    for n, n_prev in ((0, 5), (5, 0)):
        pairs, dist = om.mutual_pairs(np.zeros((n, 1), np.int32), np.zeros((n, 1), np.int32),
                                      np.zeros((n_prev, 1), np.int32), n, n_prev)
        assert pairs.shape == (0, 2) and dist.shape == (0,)
    _, idx, _, back = om.nearest_both_ways(np.zeros((0, 32), np.uint8), np.ones((4, 32), np.uint8))
    assert idx.shape == (0,) and back.tolist() == [-1] * 4


def _stereo_reference(kl, dl, kr, dr, left, right, fx, baseline, sf=1.2, max_distance=75):
    """ORB-SLAM2's stereo rules one left keypoint at a time (loops, no vectorisation)."""
    xl, yl, ol = np.asarray(kl.x), np.asarray(kl.y), np.asarray(kl.octave)
    xr, yr, orr = np.asarray(kr.x), np.asarray(kr.y), np.asarray(kr.octave)
    lp = np.pad(left.astype(np.int64), 11, mode="edge")
    rp = np.pad(right.astype(np.int64), 11, mode="edge")
    found = {}
    for i in range(len(xl)):
        best = None
        for j in range(len(xr)):
            disp = xl[i] - xr[j]
            if (abs(yl[i] - yr[j]) <= 2.0 * sf ** orr[j] and 0 <= disp <= fx
                    and abs(int(ol[i]) - int(orr[j])) <= 1):
                d = int(np.unpackbits(dl[i] ^ dr[j]).sum())
                if best is None or d < best[0]:
                    best = (d, j)
        if best is None or best[0] >= max_distance:
            continue
        cx, cy = int(np.rint(xl[i])) + 11, int(np.rint(yl[i])) + 11
        cr = int(np.rint(xr[best[1]])) + 11
        if not (cr - 10 >= 0 and cr + 10 < rp.shape[1] and cy - 5 >= 0 and cy + 5 < rp.shape[0]):
            continue
        pl = lp[cy - 5:cy + 6, cx - 5:cx + 6]
        pl = pl - pl[5, 5]
        sad = []
        for s in range(-5, 6):
            pr = rp[cy - 5:cy + 6, cr + s - 5:cr + s + 6]
            sad.append(float(np.abs(pl - (pr - pr[5, 5])).sum()))
        k = int(np.argmin(sad))
        if k in (0, 10):
            continue
        d1, d2, d3 = sad[k - 1], sad[k], sad[k + 1]
        den = 2.0 * (d1 + d3 - 2.0 * d2)
        delta = (d1 - d3) / den if den != 0 else 0.0
        ur = float(np.rint(xr[best[1]])) + (k - 5) + delta  # float64 throughout
        if abs(delta) <= 1.0 and float(xl[i]) - ur > 0:
            found[i] = (sad[k], fx * baseline / (float(xl[i]) - ur))
    median = np.median([v[0] for v in found.values()])
    depth = np.full(len(xl), np.nan, np.float32)
    for i, (s, z) in found.items():
        if s <= 1.5 * 1.4 * median:
            depth[i] = z
    return depth


def _random_keypoints(rng, n, size, near=None):
    """n keypoints at random (or, given ``near`` (x, y), within 4 px in x and 6 rows of it)."""
    w, h = size
    if near is None:
        x, y = rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n)
    else:
        x, y = near[0] + rng.uniform(-4, 4, n), near[1] + rng.uniform(-6, 6, n)
    return warpvx.Keypoints(np.clip(x, 0, w - 1).astype(np.float32),
                            np.clip(y, 0, h - 1).astype(np.float32), np.ones(n, np.float32),
                            np.full(n, 31, np.float32), np.zeros(n, np.float32),
                            rng.integers(0, 8, n).astype(np.int32))


@pytest.mark.parametrize("kind", ["orb", "random"])
def test_stereo_depth_equals_the_rules_one_keypoint_at_a_time(frames, kind):
    left, right, feats = frames
    (kl, dl), (kr, dr) = feats[0], feats[2]
    left, right = left[0], right[0]
    if kind == "orb":  # every 7th left keypoint keeps the reference's double loop short
        keep = np.arange(0, len(kl), 7)
        kl, dl = warpvx.Keypoints(*(np.asarray(getattr(kl, f))[keep] for f in FIELDS)), np.asarray(dl)[keep]
        kr, dr = kr, np.asarray(dr)
    else:  # random rows, octaves and near-copies of descriptors: every rule is decisive
        rng = np.random.default_rng(5)
        right = np.roll(left, -8, axis=1)  # disparity 8 px: the SAD refinement converges
        kl = _random_keypoints(rng, 200, (640, 480))
        kr = _random_keypoints(rng, 400, (640, 480),
                               near=(np.repeat(np.asarray(kl.x), 2) - 8, np.repeat(np.asarray(kl.y), 2)))
        dl = rng.integers(0, 256, (200, 32), dtype=np.uint8)
        flips = np.packbits(rng.random((400, 256)) < rng.uniform(0, 0.4, (400, 1)), axis=1)
        dr = np.repeat(dl, 2, axis=0) ^ flips
    args = dict(fx=364.8, baseline=0.2)
    got = om.stereo_depth(kl, dl, kr, dr, left, right, **args)
    want = _stereo_reference(kl, dl, kr, dr, left, right, **args)
    assert np.isfinite(want).sum() > 20
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=1e-6)
