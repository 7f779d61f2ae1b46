"""RANSAC homography on Warp: every hypothesis drawn and scored in parallel, then refined.

1. ``load_points``: the [N, 2] float32/float64 point arrays as float64 ``vec2d`` (one
   overload per input dtype, declared up front);
2. ``sample_hypotheses``: one thread per hypothesis draws 4 distinct points with Warp's
   counter-based generator (``wp.rand_init(seed, hypothesis)``), rejects degenerate samples
   (a collinear triple, or the 4 triangles not oriented alike in both images: OpenCV's
   ``checkSubset``; up to :data:`SAMPLE_TRIES` draws) and solves the 4-point DLT in
   normalised coordinates (8x8 Gaussian elimination with partial pivoting, ``H[2,2] = 1``);
   a hypothesis that finds no valid sample is the zero matrix;
3. ``score_hypotheses`` (one block of :data:`BLOCK` lanes per hypothesis) counts
   inliers (squared reprojection error ``<= threshold^2``) and sums their errors;
4.-6. ``refine_best`` (one block of :data:`BLOCK` lanes) does the rest:
   4. the winner: the most inliers, then the smaller error sum, then the lower hypothesis
      index (a total order, so the block reduction's order cannot change it);
   5. refinement on the inliers of the winner (its mask kept fixed, as OpenCV's): Hartley
      normalisation from the inliers' moments, the normalised DLT over all inliers, then
      at most :data:`LM_ITERS` Levenberg-Marquardt steps on the reprojection error (fewer
      once a step falls under :data:`LM_STEP_EPS`, relative). The dst
      normalisation is isotropic, so the normalised residuals are the pixel residuals times
      one constant: the same minimum. Each lane accumulates its points' terms of the normal
      equations, the block sums them, and every lane runs the same 8x8 solve on the same sums
      (no barrier, no single-thread launch between steps);
   6. H denormalised (``H[2,2] = 1``; zeros when no hypothesis was valid) and the output
      mask, recomputed with the final H.

Each lane sums its points (lane, lane + block size, ...) in order and the block reduces the
lanes in a fixed order (no atomics), so a seed gives the same result on every run, and rows
that are never inliers (NaN padding) change no sum. On Warp's CPU device a block is one lane:
plain sums in point order. Four launches per call, no host sync; scratch buffers and
recorded launches are reused between calls of the same (N, hypothesis count, point dtype)
(:func:`._launch.workspace`).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._launch import Recorded, workspace

# Forward-only kernels; no implicit FMA contraction, so CPU and CUDA builds round alike.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

SAMPLE_TRIES = 16  # draws per hypothesis before it is declared degenerate
LM_ITERS = 10  # Levenberg-Marquardt iterations (OpenCV's refinement runs at most 10)
# Lanes per block of the tiled kernels: scoring runs one block per hypothesis, selection and
# refinement one block. Warp's default block size for plain launches, so the module compiles
# once per device.
BLOCK = 256

# |det| of a triangle of normalised points (mean distance sqrt(2) from the centroid) under
# which three sample points count as collinear.
MIN_AREA = wp.constant(wp.float64(1.0e-5))
# Pivot magnitude under which an 8x8 system counts as singular.
MIN_PIVOT = wp.constant(wp.float64(1.0e-12))
LAMBDA0 = wp.constant(wp.float64(1.0e-3))
# Levenberg-Marquardt stops early when its next step would change the 8 unknowns (normalised
# frame) by less than this, relative (FLT_EPSILON). Measured on the test pairs (LK tracks,
# box, leuven): it stops after 2-5 of the 10 rounds, and the corners move by at most 7e-4 px
# against 10 full rounds.
LM_STEP_EPS = wp.constant(wp.float64(1.1920929e-07))

mat88d = wp.types.matrix(shape=(8, 8), dtype=wp.float64)
vec8d = wp.types.vector(length=8, dtype=wp.float64)
vec7d = wp.types.vector(length=7, dtype=wp.float64)


# --- small linear algebra --------------------------------------------------------------------


@wp.func
def solve8(a: mat88d, b: vec8d):
    """(x, ok): the solution of a x = b by Gaussian elimination with partial pivoting; ok is
    False when a pivot falls under MIN_PIVOT (or is NaN)."""
    for k in range(8):
        p = k
        best = wp.abs(a[k, k])
        for i in range(k + 1, 8):
            if wp.abs(a[i, k]) > best:
                best = wp.abs(a[i, k])
                p = i
        if not (best > MIN_PIVOT):
            return b, False
        if p != k:
            for j in range(8):
                t = a[k, j]
                a[k, j] = a[p, j]
                a[p, j] = t
            t = b[k]
            b[k] = b[p]
            b[p] = t
        for i in range(k + 1, 8):
            f = a[i, k] / a[k, k]
            for j in range(k, 8):
                a[i, j] = a[i, j] - f * a[k, j]
            b[i] = b[i] - f * b[k]
    x = vec8d()
    for kk in range(8):
        k = 7 - kk
        s = b[k]
        for j in range(k + 1, 8):
            s = s - a[k, j] * x[j]
        x[k] = s / a[k, k]
    return x, True


@wp.func
def to_matrix(h: vec8d) -> wp.mat33d:
    """The 8 unknowns (row-major, H[2,2] = 1) as a 3x3 matrix."""
    return wp.mat33d(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], wp.float64(1.0))


@wp.func
def to_vector(m: wp.mat33d) -> vec8d:
    return vec8d(m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1])


@wp.func
def dlt_rows(p: wp.vec2d, q: wp.vec2d):
    """The two DLT equations a . h = b of a correspondence p -> q with H[2,2] = 1."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    a1 = vec8d(p[0], p[1], one, zero, zero, zero, -q[0] * p[0], -q[0] * p[1])
    a2 = vec8d(zero, zero, zero, p[0], p[1], one, -q[1] * p[0], -q[1] * p[1])
    return a1, a2


@wp.func
def normalise(p: wp.vec2d, t: wp.vec3d) -> wp.vec2d:
    return wp.vec2d((p[0] - t[0]) * t[2], (p[1] - t[1]) * t[2])


@wp.func
def normaliser(t: wp.vec3d) -> wp.mat33d:
    """The matrix of :func:`normalise`."""
    zero = wp.float64(0.0)
    return wp.mat33d(t[2], zero, -t[0] * t[2], zero, t[2], -t[1] * t[2], zero, zero, wp.float64(1.0))


@wp.func
def denormaliser(t: wp.vec3d) -> wp.mat33d:
    """The inverse of :func:`normaliser`."""
    zero = wp.float64(0.0)
    r = wp.float64(1.0) / t[2]
    return wp.mat33d(r, zero, t[0], zero, r, t[1], zero, zero, wp.float64(1.0))


@wp.func
def reprojection_error2(h: wp.mat33d, p: wp.vec2d, q: wp.vec2d) -> wp.float64:
    """|q - H(p)|^2; NaN or inf where H sends p to infinity or a point is not finite (never
    an inlier: every test is written ``err <= t``)."""
    w = wp.float64(1.0) / (h[2, 0] * p[0] + h[2, 1] * p[1] + h[2, 2])
    dx = (h[0, 0] * p[0] + h[0, 1] * p[1] + h[0, 2]) * w - q[0]
    dy = (h[1, 0] * p[0] + h[1, 1] * p[1] + h[1, 2]) * w - q[1]
    return dx * dx + dy * dy


@wp.func
def triangle_det(a: wp.vec2d, b: wp.vec2d, c: wp.vec2d) -> wp.float64:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


@wp.func
def sample_normaliser(p0: wp.vec2d, p1: wp.vec2d, p2: wp.vec2d, p3: wp.vec2d) -> wp.vec3d:
    """(c_x, c_y, s): centroid of the 4 points and the scale bringing their mean distance
    from it to sqrt(2) (Hartley); s = 0 when the points coincide."""
    c = (p0 + p1 + p2 + p3) * wp.float64(0.25)
    d = wp.length(p0 - c) + wp.length(p1 - c) + wp.length(p2 - c) + wp.length(p3 - c)
    s = wp.float64(0.0)
    if d > wp.float64(0.0):
        s = wp.float64(4.0 * 1.4142135623730951) / d
    return wp.vec3d(c[0], c[1], s)


@wp.func
def fit_sample(s0: wp.vec2d, s1: wp.vec2d, s2: wp.vec2d, s3: wp.vec2d,
               d0: wp.vec2d, d1: wp.vec2d, d2: wp.vec2d, d3: wp.vec2d) -> wp.mat33d:
    """The homography through 4 correspondences, H[2,2] = 1, or zeros for a degenerate
    sample (coincident or collinear points, triangles oriented unlike in the two images,
    a singular system, a non-finite result)."""
    zero = wp.mat33d()
    ts = sample_normaliser(s0, s1, s2, s3)
    td = sample_normaliser(d0, d1, d2, d3)
    if not (ts[2] > wp.float64(0.0) and td[2] > wp.float64(0.0)):
        return zero
    a0 = normalise(s0, ts)
    a1 = normalise(s1, ts)
    a2 = normalise(s2, ts)
    a3 = normalise(s3, ts)
    b0 = normalise(d0, td)
    b1 = normalise(d1, td)
    b2 = normalise(d2, td)
    b3 = normalise(d3, td)
    # OpenCV's checkSubset: the triangles (0,1,2), (1,2,3), (0,2,3), (0,1,3) keep their
    # orientation in both images, or all flip; here also none may be (nearly) collinear.
    da = wp.vec4d(triangle_det(a0, a1, a2), triangle_det(a1, a2, a3),
                  triangle_det(a0, a2, a3), triangle_det(a0, a1, a3))
    db = wp.vec4d(triangle_det(b0, b1, b2), triangle_det(b1, b2, b3),
                  triangle_det(b0, b2, b3), triangle_det(b0, b1, b3))
    negative = int(0)
    for t in range(4):
        if not (wp.abs(da[t]) > MIN_AREA and wp.abs(db[t]) > MIN_AREA):
            return zero
        if da[t] * db[t] < wp.float64(0.0):
            negative += 1
    if negative != 0 and negative != 4:
        return zero
    a = mat88d()
    rhs = vec8d()
    for k in range(4):
        p = a0
        q = b0
        if k == 1:
            p = a1
            q = b1
        elif k == 2:
            p = a2
            q = b2
        elif k == 3:
            p = a3
            q = b3
        r1, r2 = dlt_rows(p, q)
        for j in range(8):
            a[2 * k, j] = r1[j]
            a[2 * k + 1, j] = r2[j]
        rhs[2 * k] = q[0]
        rhs[2 * k + 1] = q[1]
    h, ok = solve8(a, rhs)
    if not ok:
        return zero
    m = denormaliser(td) * to_matrix(h) * normaliser(ts)
    if not (wp.abs(m[2, 2]) > wp.float64(0.0)):
        return zero
    m = m / m[2, 2]
    for i in range(3):
        for j in range(3):
            if not wp.isfinite(m[i, j]):
                return zero
    return m


@wp.func
def better(count: int, cost: wp.float64, index: int, best_count: int, best_cost: wp.float64,
           best_index: int) -> bool:
    """More inliers, then a smaller error sum, then a lower index."""
    if count != best_count:
        return count > best_count
    if cost != best_cost:
        return cost < best_cost
    return index < best_index


# --- kernels ---------------------------------------------------------------------------------


@wp.kernel
def load_points(src: wp.array2d(dtype=Any), dst: wp.array2d(dtype=Any),
                src_pts: wp.array(dtype=wp.vec2d), dst_pts: wp.array(dtype=wp.vec2d)):
    i = wp.tid()
    src_pts[i] = wp.vec2d(wp.float64(src[i, 0]), wp.float64(src[i, 1]))
    dst_pts[i] = wp.vec2d(wp.float64(dst[i, 0]), wp.float64(dst[i, 1]))


for _dtype in (wp.float32, wp.float64):
    wp.overload(load_points, {"src": wp.array2d(dtype=_dtype), "dst": wp.array2d(dtype=_dtype)})


@wp.func
def draw_hypothesis(src_pts: wp.array(dtype=wp.vec2d), dst_pts: wp.array(dtype=wp.vec2d),
                    n: int, seed: int, h: int) -> wp.mat33d:
    """Hypothesis ``h``: the homography of a random valid 4-point sample of the first ``n``
    points (n >= 4), or zeros."""
    rng = wp.rand_init(seed, h)
    model = wp.mat33d()
    for _try in range(SAMPLE_TRIES):
        i0 = wp.randi(rng, 0, n)
        i1 = wp.randi(rng, 0, n - 1)
        i1 += int(i1 >= i0)  # distinct without rejection: skip the taken index
        lo = wp.min(i0, i1)
        hi = wp.max(i0, i1)
        i2 = wp.randi(rng, 0, n - 2)
        i2 += int(i2 >= lo)
        i2 += int(i2 >= hi)
        i3 = wp.randi(rng, 0, n)
        while i3 == i0 or i3 == i1 or i3 == i2:  # n >= 4: at most 3 of n values taken
            i3 = wp.randi(rng, 0, n)
        model = fit_sample(src_pts[i0], src_pts[i1], src_pts[i2], src_pts[i3],
                           dst_pts[i0], dst_pts[i1], dst_pts[i2], dst_pts[i3])
        if model[2, 2] != wp.float64(0.0):
            break
    return model


@wp.kernel
def sample_hypotheses(src_pts: wp.array(dtype=wp.vec2d), dst_pts: wp.array(dtype=wp.vec2d),
                      seed: int, hypotheses: wp.array(dtype=wp.mat33d)):
    """hypotheses[h]: the homography of a random valid 4-point sample, or zeros."""
    h = wp.tid()
    hypotheses[h] = draw_hypothesis(src_pts, dst_pts, src_pts.shape[0], seed, h)


@wp.kernel
def score_hypotheses(hypotheses: wp.array(dtype=wp.mat33d), src_pts: wp.array(dtype=wp.vec2d),
                     dst_pts: wp.array(dtype=wp.vec2d), threshold2: wp.float64,
                     count: wp.array(dtype=wp.int32), cost: wp.array(dtype=wp.float64)):
    """count/cost[h] (one block per hypothesis h): its inliers and the sum of their squared
    errors. Lane l sums points l, l + block_dim, ... in order, then the block reduces the
    lanes' sums in a fixed order."""
    h, lane = wp.tid()
    model = hypotheses[h]
    n = int(0)
    c = wp.float64(0.0)
    if model[2, 2] != wp.float64(0.0):
        for i in range(lane, src_pts.shape[0], wp.block_dim()):
            e = reprojection_error2(model, src_pts[i], dst_pts[i])
            if e <= threshold2:
                n += 1
                c += e
    # every lane reaches the reductions (each holds a block barrier)
    total_n = wp.tile_extract(wp.tile_sum(wp.tile(n)), 0)
    total_c = wp.tile_extract(wp.tile_sum(wp.tile(c)), 0)
    if lane == 0:
        count[h] = total_n
        cost[h] = total_c


@wp.func
def pick_better(a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    """Of two (inliers, error sum, index) scores, the one :func:`better` prefers."""
    if better(int(b[0]), b[1], int(b[2]), int(a[0]), a[1], int(a[2])):
        return b
    return a


@wp.func
def block_sum8(a: mat88d, b: vec8d, c: wp.float64):
    """The block's sums of every lane's (a, b, c), in every lane."""
    return (wp.tile_extract(wp.tile_sum(wp.tile(a, preserve_type=True)), 0),
            wp.tile_extract(wp.tile_sum(wp.tile(b, preserve_type=True)), 0),
            wp.tile_extract(wp.tile_sum(wp.tile(c)), 0))


@wp.func
def accumulate_system(src_pts: wp.array(dtype=wp.vec2d), dst_pts: wp.array(dtype=wp.vec2d),
                      mask: wp.array(dtype=wp.uint8), norm_src: wp.vec3d, norm_dst: wp.vec3d,
                      m: wp.mat33d, jacobian: int, lane: int):
    """The block's sums over the inliers, in the normalised frame: with ``jacobian = 0`` the
    DLT normal equations (sum a a^T, sum a b); with 1 the Gauss-Newton ones at ``m``
    (sum J^T J, sum J^T r) and the sum of squared residuals. Lane l adds its points
    l, l + block_dim, ... (the inliers it marked itself: no barrier needed)."""
    a_acc = mat88d()
    b_acc = vec8d()
    cost = wp.float64(0.0)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    for i in range(lane, src_pts.shape[0], wp.block_dim()):
        if mask[i] != wp.uint8(0):
            p = normalise(src_pts[i], norm_src)
            q = normalise(dst_pts[i], norm_dst)
            if jacobian == 0:
                r1, r2 = dlt_rows(p, q)
                a_acc += wp.outer(r1, r1) + wp.outer(r2, r2)
                b_acc += r1 * q[0] + r2 * q[1]
            else:
                w = one / (m[2, 0] * p[0] + m[2, 1] * p[1] + one)
                x = (m[0, 0] * p[0] + m[0, 1] * p[1] + m[0, 2]) * w
                y = (m[1, 0] * p[0] + m[1, 1] * p[1] + m[1, 2]) * w
                px = p[0] * w
                py = p[1] * w
                j1 = vec8d(px, py, w, zero, zero, zero, -x * px, -x * py)
                j2 = vec8d(zero, zero, zero, px, py, w, -y * px, -y * py)
                e1 = x - q[0]
                e2 = y - q[1]
                a_acc += wp.outer(j1, j1) + wp.outer(j2, j2)
                b_acc += j1 * e1 + j2 * e2
                cost += e1 * e1 + e2 * e2
    return block_sum8(a_acc, b_acc, cost)


@wp.func
def moments_normaliser(n: wp.float64, sx: wp.float64, sy: wp.float64, s2: wp.float64) -> wp.vec3d:
    """(c_x, c_y, s) with s = sqrt(2) / RMS distance from the centroid (1 if it is 0)."""
    cx = sx / n
    cy = sy / n
    var = s2 / n - cx * cx - cy * cy
    s = wp.float64(1.0)
    if var > wp.float64(0.0):
        s = wp.float64(1.4142135623730951) / wp.sqrt(var)
    return wp.vec3d(cx, cy, s)


@wp.kernel
def refine_best(hypotheses: wp.array(dtype=wp.mat33d), count: wp.array(dtype=wp.int32),
                cost: wp.array(dtype=wp.float64), src_pts: wp.array(dtype=wp.vec2d),
                dst_pts: wp.array(dtype=wp.vec2d), threshold2: wp.float64,
                inliers: wp.array(dtype=wp.uint8), out: wp.array2d(dtype=wp.float64),
                mask: wp.array(dtype=wp.uint8)):
    """Steps 4-6 in one block: the winner, its inliers (``inliers``, scratch), the refinement,
    ``out`` (float64 3x3 H, zeros when there is no model) and ``mask`` (uint8 [N], the
    inliers of ``out``). Every lane runs the same small solves on the same block sums, so
    all lanes hold the same estimate and no lane waits for another's result."""
    _blk, lane = wp.tid()
    stride = wp.block_dim()
    n_pts = src_pts.shape[0]
    # 4. the winner: each lane's best of its hypotheses, then the block's best
    best = wp.vec3d(wp.float64(-1.0), wp.float64(wp.inf), wp.float64(-1.0))
    for j in range(lane, hypotheses.shape[0], stride):
        best = pick_better(best, wp.vec3d(wp.float64(count[j]), cost[j], wp.float64(j)))
    best = wp.tile_extract(wp.tile_reduce(pick_better, wp.tile(best, preserve_type=True)), 0)
    # found is the same in every lane: the block reductions under it are reached by all
    found = best[0] > wp.float64(0.0)
    m = wp.mat33d()
    if found:
        m = hypotheses[int(best[2])]
    # 5. its inliers (kept fixed, as OpenCV's), their moments and the Hartley normalisation
    acc = vec7d()
    for i in range(lane, n_pts, stride):
        p = src_pts[i]
        q = dst_pts[i]
        inlier = found and reprojection_error2(m, p, q) <= threshold2
        inliers[i] = wp.uint8(int(inlier))
        if inlier:
            acc += vec7d(wp.float64(1.0), p[0], p[1], q[0], q[1], wp.dot(p, p), wp.dot(q, q))
    acc = wp.tile_extract(wp.tile_sum(wp.tile(acc, preserve_type=True)), 0)
    if found:
        norm_src = moments_normaliser(acc[0], acc[1], acc[2], acc[5])
        norm_dst = moments_normaliser(acc[0], acc[3], acc[4], acc[6])
        h = normaliser(norm_dst) * m * denormaliser(norm_src)
        h = h / h[2, 2]
        # the DLT over all inliers (kept at the RANSAC winner when singular)
        a, b, _c = accumulate_system(src_pts, dst_pts, inliers, norm_src, norm_dst, h, 0, lane)
        x, ok = solve8(a, b)
        if ok:
            h = to_matrix(x)
        # Levenberg-Marquardt on the reprojection error: accept a trial that lowered the
        # cost (and relax the damping), else raise the damping; the next trial solves
        # (J^T J + lam diag(J^T J)) d = -J^T r at h
        trial = h
        best_cost = wp.float64(wp.inf)
        lam = LAMBDA0
        jtj = mat88d()
        jtr = vec8d()
        for _it in range(LM_ITERS):
            ta, tb, tc = accumulate_system(src_pts, dst_pts, inliers, norm_src, norm_dst, trial, 1,
                                          lane)
            if tc < best_cost:
                h = trial
                best_cost = tc
                jtj = ta
                jtr = tb
                lam = lam * wp.float64(0.1)
            else:
                lam = lam * wp.float64(10.0)
            damped = jtj
            for k in range(8):
                damped[k, k] = damped[k, k] * (wp.float64(1.0) + lam)
            d, ok_step = solve8(damped, -jtr)
            if ok_step and wp.length(d) <= LM_STEP_EPS * wp.length(to_vector(h)):
                break  # converged (the same in every lane: no lane skips a block sum)
            trial = h
            if ok_step:
                trial = to_matrix(to_vector(h) + d)
        # 6. back to pixels; no model when the refinement ran away to non-finite values
        m = denormaliser(norm_dst) * h * normaliser(norm_src)
        m = m / m[2, 2]
        for r in range(3):
            for c in range(3):
                if not wp.isfinite(m[r, c]):
                    found = False
        if not found:
            m = wp.mat33d()
    if lane == 0:
        for r in range(3):
            for c in range(3):
                out[r, c] = m[r, c]
    for i in range(lane, n_pts, stride):
        inlier = found and reprojection_error2(m, src_pts[i], dst_pts[i]) <= threshold2
        mask[i] = wp.uint8(int(inlier))


# --- host side -------------------------------------------------------------------------------


class Workspace:
    """Buffers and recorded launches for one (N, hypothesis count, point dtype, device): four
    launches per call, named ``load``, ``sample``, ``score`` and ``refine`` (a caller may
    assign another :class:`Recorded` of the same parameters to one of them, as
    :class:`~warpvx.kernels_warp.stabilize_points.DeviceRansac` does to ``sample``);
    ``src_pts``, ``dst_pts`` (vec2d [N]) and ``hypotheses`` (mat33d [n_hyp]) are its buffers."""

    def __init__(self, src, dst, n_hyp: int, threshold2: float, seed: int, device):
        n = src.shape[0]

        def empty(shape, dtype):
            return wp.empty(shape, dtype=dtype, device=device)

        self.src_pts, self.dst_pts = empty(n, wp.vec2d), empty(n, wp.vec2d)
        self.hypotheses = hyps = empty(n_hyp, wp.mat33d)
        count, cost = empty(n_hyp, wp.int32), empty(n_hyp, wp.float64)
        pts, thr2 = [self.src_pts, self.dst_pts], wp.float64(threshold2)
        # Placeholders for the per-call arrays (set before each launch).
        h_out, mask_out = empty((3, 3), wp.float64), empty(n, wp.uint8)

        def rec(kernel, dim, inputs, block_dim=None):
            # the kernel's parameters in order, named for Recorded
            names = [a.label for a in kernel.adj.args]
            return Recorded(kernel, dim, device, block_dim=block_dim, **dict(zip(names, inputs)))

        self.load = rec(load_points, n, [src, dst, *pts])
        self.sample = rec(sample_hypotheses, n_hyp, [*pts, int(seed), hyps])
        self.score = rec(score_hypotheses, [n_hyp], [hyps, *pts, thr2, count, cost], BLOCK)
        self.refine = rec(refine_best, [1], [hyps, count, cost, *pts, thr2, empty(n, wp.uint8),
                                             h_out, mask_out], BLOCK)
        self.threshold2 = threshold2

    def run(self, src, dst, threshold2: float, seed: int, h_out, mask_out):
        self.load.launch(src=src, dst=dst)
        self.sample.set(seed=int(seed))
        if threshold2 != self.threshold2:
            for cmd in (self.score, self.refine):  # the launches that take the threshold
                cmd.set(threshold2=wp.float64(threshold2))
            self.threshold2 = threshold2
        self.refine.set(out=h_out, mask=mask_out)
        for cmd in (self.sample, self.score, self.refine):
            cmd.launch()


def find_homography(src, dst, ransac_reproj_threshold: float, max_iters: int, confidence: float,
                    seed: int, *, out=None) -> tuple:
    """RANSAC homography on Warp arrays; see :func:`warpvx.find_homography`.

    ``src``, ``dst``: float32 or float64 [N, 2] on one device, N >= 4. ``max_iters``
    hypotheses are all drawn and scored (``confidence`` only shortens OpenCV's sequential
    loop, so it is not used here). ``out``: optional (float64 [3, 3], uint8 [N]) on the same
    device. Returns (H, mask); H is zeros and mask all 0 when there is no model. No host sync.
    """
    device = src.device
    n = src.shape[0]
    if out is None:
        h_out = wp.empty((3, 3), dtype=wp.float64, device=device)
        mask_out = wp.empty(n, dtype=wp.uint8, device=device)
    else:
        h_out, mask_out = out
    threshold2 = float(ransac_reproj_threshold) ** 2
    ws = workspace("find_homography", (n, int(max_iters), src.dtype, dst.dtype), device,
                   lambda: Workspace(src, dst, int(max_iters), threshold2, seed, device))
    ws.run(src, dst, threshold2, seed, h_out, mask_out)
    return h_out, mask_out


__all__ = ["find_homography", "LM_ITERS", "SAMPLE_TRIES", "Workspace"]
