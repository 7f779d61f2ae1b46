"""ORB-SLAM2's ORB extractor: smoke, shapes, bad input, parity with ORB-SLAM2 and with OpenCV,
CPU/Warp parity, real use."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import DTypeError, Keypoints, ShapeError, UnsupportedError, WarpvxTypeError
from warpvx import WarpvxValueError
from warpvx import _orb_quadtree, _orb_spec
from warpvx.kernels_cpu import orb as cpu_orb
from warpvx.orb_extractor import orb_compute
from tests.images import gray
from tests.cv.fallback import runs_on_cv2

# SPEC section 6: KITTI settings, 2000 features over 8 levels at 1.2.
SPEC_COUNTS = [434, 362, 302, 251, 209, 175, 145, 122]
# ORB-SLAM2's umax rows of the radius-15 disc, as SPEC lists them.
SPEC_UMAX = [15, 15, 15, 15, 14, 14, 14, 13, 13, 12, 11, 10, 9, 8, 6, 3]


@pytest.fixture(scope="module")
def cpu_result():
    img = gray("astronaut")
    return img, warpvx.orb(img, backend="cpu")


def _host(kps, desc):
    return kps.to("host"), desc if isinstance(desc, np.ndarray) else desc.numpy()


# --- reference implementations (literal transcriptions of ORB-SLAM2's ORBextractor.cc) ----------


class _Node:
    def __init__(self, ul, ur, bl, br):
        self.ul, self.ur, self.bl, self.br = ul, ur, bl, br
        self.keys, self.no_more, self.id = [], False, -1


def _divide_node(node, pts):
    hx = math.ceil((node.ur[0] - node.ul[0]) / 2)
    hy = math.ceil((node.br[1] - node.ul[1]) / 2)
    n1 = _Node(node.ul, (node.ul[0] + hx, node.ul[1]), (node.ul[0], node.ul[1] + hy),
               (node.ul[0] + hx, node.ul[1] + hy))
    n2 = _Node(n1.ur, node.ur, n1.br, (node.ur[0], node.ul[1] + hy))
    n3 = _Node(n1.bl, n1.br, node.bl, (n1.br[0], node.bl[1]))
    n4 = _Node(n3.ur, n2.br, n3.br, node.br)
    for k in node.keys:
        x, y = pts[k]
        if x < n1.ur[0]:
            (n1 if y < n1.br[1] else n3).keys.append(k)
        elif y < n1.br[1]:
            n2.keys.append(k)
        else:
            n4.keys.append(k)
    for c in (n1, n2, n3, n4):
        c.no_more = len(c.keys) == 1
    return n1, n2, n3, n4


def _distribute_octtree_literal(px, py, resp, min_x, max_x, min_y, max_y, n):
    """DistributeOctTree with a Python list as std::list (push_front = insert(0)); equal-sized
    nodes are sorted by creation order where ORB-SLAM2 compares heap addresses."""
    f32 = np.float32
    pts = list(zip(f32(px) - f32(min_x), f32(py) - f32(min_y)))
    n_ini = max(1, int(math.floor(float(f32(max_x - min_x) / f32(max_y - min_y)) + 0.5)))
    hx = f32(f32(max_x - min_x) / f32(n_ini))
    ids = iter(range(1, 1 << 30))
    nodes, ini = [], []
    for i in range(n_ini):
        x0, x1 = int(f32(hx * f32(i))), int(f32(hx * f32(i + 1)))
        node = _Node((x0, 0), (x1, 0), (x0, max_y - min_y), (x1, max_y - min_y))
        node.id = next(ids)
        nodes.append(node)
        ini.append(node)
    for k, (x, _) in enumerate(pts):
        ini[int(f32(x / hx))].keys.append(k)
    nodes = [nd for nd in nodes if nd.keys]
    for nd in nodes:
        nd.no_more = len(nd.keys) == 1

    def push_children(node, expandable):
        for c in _divide_node(node, pts):
            if c.keys:
                c.id = next(ids)
                nodes.insert(0, c)
                if len(c.keys) > 1:
                    expandable.append(c)

    finish = False
    while not finish:
        prev = len(nodes)
        expandable = []
        i = 0
        while i < len(nodes):
            node = nodes[i]
            if node.no_more:
                i += 1
                continue
            before = len(nodes)
            push_children(node, expandable)
            i += len(nodes) - before
            del nodes[i]
        if len(nodes) >= n or len(nodes) == prev:
            finish = True
        elif len(nodes) + len(expandable) * 3 > n:
            while not finish:
                prev = len(nodes)
                previous = sorted(expandable, key=lambda nd: (len(nd.keys), nd.id))
                expandable = []
                for node in reversed(previous):
                    push_children(node, expandable)
                    nodes.remove(node)
                    if len(nodes) >= n:
                        break
                if len(nodes) >= n or len(nodes) == prev:
                    finish = True
    out = []
    for nd in nodes:
        best = nd.keys[0]
        for k in nd.keys[1:]:
            if resp[k] > resp[best]:
                best = k
        out.append(best)
    return np.array(out, np.int64)


def _cells_literal(level, ini_th, min_th):
    """ComputeKeyPointsOctTree's cell loop: FAST at ini_th per cell, min_th when it finds none."""
    h, w = level.shape
    min_b, max_bx, max_by = 16, w - 19 + 3, h - 19 + 3
    width, height = np.float32(max_bx - min_b), np.float32(max_by - min_b)
    n_cols, n_rows = int(width / np.float32(30)), int(height / np.float32(30))
    w_cell = int(math.ceil(np.float32(width / np.float32(n_cols))))
    h_cell = int(math.ceil(np.float32(height / np.float32(n_rows))))
    hi = cv2.FastFeatureDetector_create(ini_th, True)
    lo = cv2.FastFeatureDetector_create(min_th, True)
    out = []
    for i in range(n_rows):
        y0 = min_b + i * h_cell
        if y0 >= max_by - 3:
            continue
        y1 = min(y0 + h_cell + 6, max_by)
        for j in range(n_cols):
            x0 = min_b + j * w_cell
            if x0 >= max_bx - 6:
                continue
            x1 = min(x0 + w_cell + 6, max_bx)
            cell = np.ascontiguousarray(level[y0:y1, x0:x1])
            kps = hi.detect(cell) or lo.detect(cell)
            for k in sorted(kps, key=lambda k: (k.pt[1], k.pt[0])):
                out.append((int(k.pt[0]) + x0, int(k.pt[1]) + y0, int(k.response)))
    a = np.array(out, np.int32).reshape(-1, 3)
    return a[:, 0], a[:, 1], a[:, 2]


def _pyramid_cv(img, n_levels, scale=1.2):
    """Level l = cv2.resize(level l-1) to ORB-SLAM2's cvRound(w * (1 / s_l)) (float)."""
    levels, s = [img], np.float32(1.0)
    for _ in range(1, n_levels):
        s = np.float32(s * np.float32(scale))
        inv = np.float32(1.0) / s
        size = (int(np.rint(np.float32(img.shape[1]) * inv)),
                int(np.rint(np.float32(img.shape[0]) * inv)))
        levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
    return levels


# --- smoke and shapes ---------------------------------------------------------------------------


def test_orb_smoke(backend):
    img = gray("astronaut")
    kps, desc = warpvx.orb(img, backend=backend)
    assert isinstance(kps, Keypoints) and kps.is_host and isinstance(desc, np.ndarray)
    n = len(kps)
    assert 1900 <= n <= 2020
    assert desc.shape == (n, 32) and desc.dtype == np.uint8
    assert kps.x.dtype == np.float32 and kps.octave.dtype == np.int32
    assert set(np.unique(kps.octave)) == set(range(8))
    assert np.all((kps.angle >= 0) & (kps.angle < 360))
    sizes = np.array([int(31 * 1.2 ** o) for o in range(8)], np.float32)  # int(PATCH_SIZE * s)
    np.testing.assert_array_equal(kps.size, sizes[kps.octave])
    assert np.all(kps.response >= 7)


@pytest.mark.parametrize("shape", [(376, 1241), (300, 451), (427, 640), (333, 257)])
def test_orb_shapes_and_border(shape):
    """Odd sizes; every keypoint lies >= 19 px (EDGE_THRESHOLD) inside its level."""
    h, w = shape
    img = cv2.resize(gray("coffee"), (w, h), interpolation=cv2.INTER_AREA)
    n_levels = 8 if min(h, w) >= 230 else 6
    kps, desc = warpvx.orb(img, 1000, 1.2, n_levels, backend="cpu")
    assert desc.shape == (len(kps), 32) and len(kps) > 100
    levels = _pyramid_cv(img, n_levels)
    s = np.float32(1.2) ** kps.octave.astype(np.float32)
    lx, ly = np.rint(kps.x / s), np.rint(kps.y / s)
    lw = np.array([lv.shape[1] for lv in levels])[kps.octave]
    lh = np.array([lv.shape[0] for lv in levels])[kps.octave]
    assert lx.min() >= 19 and ly.min() >= 19
    assert np.all(lx <= lw - 20) and np.all(ly <= lh - 20)


def test_orb_device_in_device_out(warp_backend):
    wp = pytest.importorskip("warp")
    img = gray("chelsea")
    dev = "cpu" if warp_backend == "warp-cpu" else warp_backend
    src = wp.array(img, dtype=wp.uint8, device=dev)
    kps, desc = warpvx.orb(src, 500)
    assert not kps.is_host and str(kps.x.device) == str(src.device)
    assert str(desc.device) == str(src.device) and desc.shape[1] == 32
    host_kps, host_desc = warpvx.orb(img, 500, backend=warp_backend)
    np.testing.assert_array_equal(kps.to("host").x, host_kps.x)
    np.testing.assert_array_equal(desc.numpy(), host_desc)


# --- bad input ----------------------------------------------------------------------------------


@pytest.mark.parametrize("kwargs, err, name", [
    ({"n_features": 0}, WarpvxValueError, "n_features"),
    ({"n_features": 2.5}, WarpvxTypeError, "n_features"),
    ({"scale_factor": 1.0}, WarpvxValueError, "scale_factor"),
    ({"scale_factor": 0.8}, WarpvxValueError, "scale_factor"),
    ({"n_levels": 0}, WarpvxValueError, "n_levels"),
    ({"ini_th_fast": 300}, WarpvxValueError, "ini_th_fast"),
    ({"min_th_fast": -1}, WarpvxValueError, "min_th_fast"),
])
def test_orb_bad_parameters(kwargs, err, name):
    with pytest.raises(err, match=name):
        warpvx.orb(gray("camera"), backend="cpu", **kwargs)


def test_orb_bad_images():
    with pytest.raises(ShapeError, match="src.*gray.*BGR2GRAY"):
        warpvx.orb(cv2.cvtColor(gray("camera"), cv2.COLOR_GRAY2BGR), backend="cpu")
    with pytest.raises(DTypeError, match="src"):
        warpvx.orb(gray("camera").astype(np.float32), backend="cpu")
    with pytest.raises(ShapeError, match="n_levels"):
        # level 7 would be 56x56
        warpvx.orb(np.ascontiguousarray(gray("camera")[:200, :200]), n_levels=8, backend="cpu")
    with pytest.raises(ShapeError, match="src"):
        warpvx.orb(np.zeros((0, 100), np.uint8), backend="cpu")
    with pytest.raises(WarpvxTypeError, match="src"):
        warpvx.orb([[1, 2], [3, 4]], backend="cpu")
    # level 7 is 63x63: fine
    warpvx.orb(np.ascontiguousarray(gray("camera")[:224, :224]), n_levels=8, backend="cpu")


def test_orb_compute_bad_input():
    img = gray("camera")
    with pytest.raises(WarpvxValueError, match="octave"):
        orb_compute(img, Keypoints.from_arrays([50.0], [50.0], octave=[-1]), backend="cpu")
    with pytest.raises(WarpvxValueError, match="keypoints"):
        orb_compute(img, Keypoints.from_arrays([np.nan], [50.0], angle=[0.0]), backend="cpu")
    with pytest.raises(WarpvxTypeError, match="keypoints"):
        orb_compute(img, np.zeros((3, 2)), backend="cpu")


# --- ORB-SLAM2's algorithm ----------------------------------------------------------------------


def test_features_per_level_formula():
    assert _orb_spec.features_per_level(2000, 1.2, 8) == SPEC_COUNTS
    assert sum(_orb_spec.features_per_level(1000, 1.2, 8)) == 1000
    assert _orb_spec.umax().tolist() == SPEC_UMAX


def test_per_level_counts_on_textured_image(backend):
    """Each level keeps n_l points, up to 2 more (ORB-SLAM2 stops dividing once n_l nodes
    exist, and a division adds up to 3)."""
    kps, _ = warpvx.orb(gray("brick"), backend=backend)
    counts = np.bincount(kps.to("host").octave, minlength=8)
    assert np.all(counts >= SPEC_COUNTS) and np.all(counts <= np.array(SPEC_COUNTS) + 2), counts


@pytest.mark.parametrize("name", ["astronaut", "rocket", "text"])
def test_cells_match_orbslam2_loop(name):
    """FAST once at 7 plus the per-cell rule equals ORB-SLAM2's loop (FAST at 20 per cell,
    again at 7 when it finds none), cell-local non-max suppression included."""
    for level in _pyramid_cv(gray(name), 4):
        grid = _orb_spec.cell_grid(level.shape[1], level.shape[0])
        x, y, s = cpu_orb.detect_cells(level, 7)
        keep = cpu_orb.select_cells(x, y, s, grid, 20, 7)
        rx, ry, rs = _cells_literal(level, 20, 7)
        np.testing.assert_array_equal(x[keep], rx)
        np.testing.assert_array_equal(y[keep], ry)
        np.testing.assert_array_equal(s[keep], rs)


@pytest.mark.parametrize("name", ["coffee", "camera"])
def test_quadtree_matches_literal_distribute_octtree(name):
    for lv, level in enumerate(_pyramid_cv(gray(name), 8)[::3]):
        grid = _orb_spec.cell_grid(level.shape[1], level.shape[0])
        x, y, s = _cells_literal(level, 20, 7)
        for n in (SPEC_COUNTS[3 * lv], 7, 60, 5000):
            ref = _distribute_octtree_literal(x, y, s, 16, grid.max_border_x, 16,
                                              grid.max_border_y, n)
            got = _orb_quadtree.distribute_octtree(x, y, s, grid, n)
            np.testing.assert_array_equal(got, ref)


def test_orientation_is_intensity_centroid(cpu_result):
    """angle = atan2(m01, m10) over the radius-15 disc of the unblurred level (float64 here;
    fastAtan2 is within 0.02 deg of it)."""
    img, (kps, _) = cpu_result
    levels = _pyramid_cv(img, 8)
    rng = np.random.default_rng(0)
    for i in rng.choice(len(kps), 200, replace=False):
        o = int(kps.octave[i])
        s = np.float32(1.2) ** o
        cx, cy = int(np.rint(kps.x[i] / s)), int(np.rint(kps.y[i] / s))
        lv = levels[o].astype(np.int64)
        m01 = m10 = 0
        for v in range(-15, 16):
            d = SPEC_UMAX[abs(v)]
            row = lv[cy + v, cx - d:cx + d + 1]
            m10 += int(np.dot(np.arange(-d, d + 1), row))
            m01 += v * int(row.sum())
        want = math.degrees(math.atan2(m01, m10)) % 360
        diff = abs(float(kps.angle[i]) - want)
        assert min(diff, 360 - diff) < 0.02, (i, kps.angle[i], want)


def test_fast_atan2_is_opencvs():
    rng = np.random.default_rng(1)
    y = rng.integers(-300000, 300000, 3000).astype(np.float32)
    x = rng.integers(-300000, 300000, 3000).astype(np.float32)
    x[:20] = 0
    y[10:30] = 0
    want = np.array([cv2.fastAtan2(float(a), float(b)) for a, b in zip(y, x)], np.float32)
    np.testing.assert_array_equal(cpu_orb.fast_atan2(y, x), want)


def test_spread_over_cells(backend):
    """The quadtree spreads level 0 over the 30x30 cells that have texture (cells where FAST at
    threshold 7 finds a corner): with the default budget most of them hold a keypoint, far more
    than cv2's ORB reaches with the same budget; with a budget above the number of candidates
    every such cell does (no cell left empty)."""
    img = gray("astronaut")
    h, w = img.shape
    grid = _orb_spec.cell_grid(w, h)
    det = cv2.FastFeatureDetector_create(7, True)
    textured = {(i, j) for i, (y0, y1) in enumerate(grid.row_spans)
                for j, (x0, x1) in enumerate(grid.col_spans)
                if det.detect(np.ascontiguousarray(img[y0:y1, x0:x1]))}
    assert len(textured) > 150

    def coverage(xs, ys):
        xi, yi = np.rint(xs).astype(int), np.rint(ys).astype(int)
        cells = set(zip(grid.row_of_y[yi], grid.col_of_x[xi]))
        return np.mean([c in cells for c in textured])

    kps, _ = warpvx.orb(img, 2000, backend=backend)
    kps = kps.to("host")
    l0 = kps.octave == 0
    ours = coverage(kps.x[l0], kps.y[l0])
    cv_kps = [k for k in cv2.ORB_create(2000).detect(img) if k.octave == 0]
    theirs = coverage(np.array([k.pt[0] for k in cv_kps]).clip(0, w - 1),
                      np.array([k.pt[1] for k in cv_kps]).clip(0, h - 1))
    assert ours >= 0.85 and ours > theirs + 0.3, (ours, theirs)
    every, _ = warpvx.orb(img, 100000, 1.2, 1, backend=backend)
    every = every.to("host")
    assert coverage(every.x, every.y) == 1.0


# --- OpenCV parity and backend parity -----------------------------------------------------------


def _bit_agreement(a, b):
    return 1.0 - np.unpackbits(np.bitwise_xor(a, b)).mean()


@pytest.mark.parametrize("name", ["coffee", "rocket"])
def test_descriptors_match_opencv(backend, name):
    """Our descriptors vs cv2.ORB_create().compute on the same keypoints and angles (cv2
    keeps keypoints >= edgeThreshold from the border; 19 keeps them all)."""
    img = gray(name)
    kps, desc = _host(*warpvx.orb(img, 2000, backend=backend))
    cv_in = kps.to_cv()
    cv_kps, cv_desc = cv2.ORB_create(edgeThreshold=19).compute(img, cv_in)
    assert len(cv_kps) == len(cv_in)
    index = {(k.pt, k.octave): i for i, k in enumerate(cv_in)}
    rows = np.array([index[(k.pt, k.octave)] for k in cv_kps])
    assert _bit_agreement(desc[rows], cv_desc) >= 0.95
    level0 = kps.octave[rows] == 0  # same image, same blur: nearly every bit
    assert _bit_agreement(desc[rows][level0], cv_desc[level0]) >= 0.99


def test_orb_compute_matches_opencv(backend):
    """Descriptors of cv2's own keypoints (its angles and octaves) against cv2's."""
    img = gray("chelsea")
    cv_kps, cv_desc = cv2.ORB_create(1000).detectAndCompute(img, None)
    desc = orb_compute(img, list(cv_kps), 1.2, backend=backend)
    assert desc.shape == cv_desc.shape
    assert _bit_agreement(desc, cv_desc) >= 0.95


FIELDS = ("x", "y", "response", "size", "angle", "octave")

# CUDA contracts fastAtan2's a*b+c into fused multiply-adds, so an angle may differ from the
# CPU transcription in its last bit or two; Warp's CPU device reproduces it exactly.
ANGLE_ULPS = {"warp-cpu": 0}


def assert_angles(actual, desired, backend):
    """Orientation angles: bit-exact on warp-cpu, within 2 float32 ulps on CUDA."""
    ulps = ANGLE_ULPS.get(backend, 2)
    if ulps == 0:
        np.testing.assert_array_equal(actual, desired)
    else:
        np.testing.assert_array_max_ulp(actual, desired, maxulp=ulps)


def assert_same_extraction(kw, dw, kc, dc, backend):
    """Warp (kw, dw) against CPU (kc, dc): every keypoint field exact except the angle (see
    :func:`assert_angles`); descriptors exact wherever the angles agree bit for bit, and 99%+
    of bits where a last-bit angle difference moved a rotated test point across a pixel."""
    for f in FIELDS:
        if f != "angle":
            np.testing.assert_array_equal(getattr(kw, f), getattr(kc, f), err_msg=f)
    assert_angles(kw.angle, kc.angle, backend)
    same = kw.angle == kc.angle
    np.testing.assert_array_equal(dw[same], dc[same])
    if not same.all():
        assert _bit_agreement(dw[~same], dc[~same]) >= 0.99


@pytest.mark.parametrize("name", ["coffee", "astronaut", "brick"])
def test_cpu_and_warp_extractors_agree(warp_backend, name):
    """The Warp extractor returns exactly the CPU one (every field, every descriptor byte, in
    the same order); SPEC section 4's bars (90% of keypoints within 1 px, count within 10%,
    95% of descriptor bits) hold as a consequence, asserted second."""
    img = gray(name)
    kc, dc = warpvx.orb(img, backend="cpu")
    kw, dw = _host(*warpvx.orb(img, backend=warp_backend))
    assert_same_extraction(kw, dw, kc, dc, warp_backend)
    # SPEC section 4: for each CPU keypoint, a Warp keypoint of the same octave within 1 px.
    found = np.zeros(len(kc), bool)
    desc_same = []
    for o in range(8):
        ic, iw = np.flatnonzero(kc.octave == o), np.flatnonzero(kw.octave == o)
        if iw.size == 0:
            continue
        d = np.hypot(kc.x[ic, None] - kw.x[None, iw], kc.y[ic, None] - kw.y[None, iw])
        j = d.argmin(1)
        near = d[np.arange(ic.size), j] <= 1.0
        found[ic[near]] = True
        desc_same.append(_bit_agreement(dc[ic[near]], dw[iw[j[near]]]))
    assert found.mean() >= 0.90 and abs(len(kw) - len(kc)) <= 0.1 * len(kc)
    assert min(desc_same) >= 0.95


def _decode(keys):
    """Candidate keys (kernels_warp.orb KEY_* layout) as (level, cell, y, x, score) arrays."""
    from warpvx.kernels_warp.orb import funcs

    keys = np.asarray(keys, np.int64)
    return (keys >> int(funcs.KEY_LEVEL_SHIFT), (keys >> int(funcs.KEY_CELL_SHIFT)) & 0x3FFFF,
            (keys >> int(funcs.KEY_Y_SHIFT)) & 0xFFFF, (keys >> int(funcs.KEY_X_SHIFT)) & 0xFFFF,
            keys & 0xFF)


@pytest.mark.parametrize("name, batch", [("coffee", 1), ("rocket", 1), ("coffee", 2)])
def test_warp_internals_match_orbslam2_transcription(warp_backend, name, batch):
    """The one-graph Warp extractor's intermediate buffers against the CPU transcription of
    ORB-SLAM2, level by level: the pyramid, which cells pass iniThFAST (the per-cell FAST
    threshold), the candidates after it, the quadtree's kept points in DistributeOctTree's
    node order, and the IC_Angle orientations. With a batch, those of its last image (the
    first is the image flipped: other content in the same launches)."""
    wp = pytest.importorskip("warp")
    from warpvx.kernels_warp.orb import funcs
    from warpvx.kernels_warp.orb.plan import OrbPlan

    img = gray(name)
    dev = "cpu" if warp_backend == "warp-cpu" else warp_backend
    plan = OrbPlan(dev, *img.shape, 2000, 1.2, 8, 20, 7, batch=batch)
    stack = np.stack([np.ascontiguousarray(img[::-1, ::-1])] * (batch - 1) + [img])
    plan.run(wp.array(stack if batch > 1 else img, dtype=wp.uint8, device=dev))
    b = batch - 1
    counters = plan.counters.numpy()[b]
    assert counters[funcs.C_OVER] == 0  # the device quadtree ran, not the host fallback
    # Candidates: each stripe's region holds its count.
    per_stripe = counters[funcs.C_CAND_R:funcs.C_CAND_R + funcs.STRIPES]
    cand = plan.cand.numpy()[b].reshape(funcs.STRIPES, plan.cand_region)
    keys = np.concatenate([cand[r, :c] for r, c in enumerate(per_stripe)])
    level_k, cell_k, y_k, x_k, s_k = _decode(keys)
    # Kept points, in the final list's order.
    n = int(counters[funcs.C_FINAL])
    kept = plan.cand.numpy()[b][plan.final_values_b.numpy()[b, :n]]
    level_f, _, y_f, x_f, s_f = _decode(kept)
    # Orientations: image b's rows of the batch's packed (5, N) field block.
    starts = plan.starts.numpy()
    first, total = int(starts[b]), int(starts[batch])
    angles = plan.kp_fields.numpy()[4 * total + first:4 * total + first + n]
    assert np.all(np.diff(level_f) >= 0)  # level by level

    levels = cpu_orb.build_pyramid(img, 1.2, 8)
    wanted = _orb_spec.features_per_level(2000, 1.2, 8)
    cell_strong = counters[plan.cells_at:plan.groups_at]
    cell_at = 0
    for lv, level in enumerate(levels):
        np.testing.assert_array_equal(plan.images[b][lv].numpy(), level)
        grid = _orb_spec.cell_grid(level.shape[1], level.shape[0])
        x, y, s = cpu_orb.detect_cells(level, 7)
        cell = grid.row_of_y[y].astype(np.int64) * grid.n_cols + grid.col_of_x[x]
        # Per-cell threshold: a cell counts points >= iniThFAST exactly where ORB-SLAM2's
        # first FAST pass finds some.
        n_cells = grid.n_rows * grid.n_cols
        strong = np.bincount(cell[s >= 20], minlength=n_cells)
        np.testing.assert_array_equal(cell_strong[cell_at:cell_at + n_cells], strong)
        cell_at += n_cells
        keep = cpu_orb.select_cells(x, y, s, grid, 20, 7)
        x, y, s, cell = x[keep], y[keep], s[keep], cell[keep]
        # Candidates: the same set (sorted in ORB-SLAM2's order: cell, y, x).
        mine = level_k == lv
        order = np.lexsort((x_k[mine], y_k[mine], cell_k[mine]))
        np.testing.assert_array_equal(cell_k[mine][order], cell)
        np.testing.assert_array_equal(y_k[mine][order], y)
        np.testing.assert_array_equal(x_k[mine][order], x)
        np.testing.assert_array_equal(s_k[mine][order], s)
        # Quadtree: DistributeOctTree's kept points, in its node order.
        chosen = _orb_quadtree.distribute_octtree(x, y, s, grid, wanted[lv])
        here = level_f == lv
        np.testing.assert_array_equal(x_f[here], x[chosen])
        np.testing.assert_array_equal(y_f[here], y[chosen])
        np.testing.assert_array_equal(s_f[here], s[chosen])
        # Orientation: IC_Angle on the unblurred level.
        assert_angles(angles[here], cpu_orb.compute_orientation(level, x[chosen], y[chosen]),
                      warp_backend)


def test_warp_overflow_takes_the_host_quadtree(warp_backend):
    """A frame past a plan's candidate capacity is redone with the host quadtree: the same
    result as the device path and the CPU extractor."""
    wp = pytest.importorskip("warp")
    from warpvx.kernels_warp.orb import funcs
    from warpvx.kernels_warp.orb.plan import OrbPlan

    img = gray("coffee")
    dev = "cpu" if warp_backend == "warp-cpu" else warp_backend
    plan = OrbPlan(dev, *img.shape, 2000, 1.2, 8, 20, 7, candidate_divisor=10 ** 6)
    (kw, dw), = [_host(*r) for r in plan.run(wp.array(img, dtype=wp.uint8, device=dev))]
    assert plan.counters.numpy()[0, funcs.C_OVER] == 1
    kc, dc = warpvx.orb(img, backend="cpu")
    assert_same_extraction(kw, dw, kc, dc, warp_backend)


def test_orb_out_is_refused(backend):
    """orb's output size is data-dependent: both backends refuse out= rather than ignore it."""
    if backend == "cpu":
        impl, src = cpu_orb.orb, gray("camera")
    else:
        wp = pytest.importorskip("warp")
        from warpvx.kernels_warp import orb as warp_orb

        dev = "cpu" if backend == "warp-cpu" else backend
        impl, src = warp_orb.orb, wp.array(gray("camera"), dtype=wp.uint8, device=dev)
    with pytest.raises(UnsupportedError, match="out"):
        impl(src, 500, 1.2, 8, 20, 7, out=np.zeros((500, 32), np.uint8))


def test_orb_compute_out(backend):
    """orb_compute writes into out= (the descriptors computed without it) and validates it."""
    img = gray("chelsea")
    kps, _ = _host(*warpvx.orb(img, 300, backend="cpu"))
    want = orb_compute(img, kps, 1.2, backend=backend)
    want = want if isinstance(want, np.ndarray) else want.numpy()
    out = np.full((len(kps), 32), 7, np.uint8)
    got = orb_compute(img, kps, 1.2, out=out, backend=backend)
    assert got is out
    np.testing.assert_array_equal(out, want)
    if backend != "cpu":  # device in, device out: the kernels write into it
        wp = pytest.importorskip("warp")
        dev = "cpu" if backend == "warp-cpu" else backend
        dev_out = wp.full((len(kps), 32), 7, dtype=wp.uint8, device=dev)
        got = orb_compute(wp.array(img, dtype=wp.uint8, device=dev), kps, 1.2, out=dev_out)
        assert got is dev_out
        np.testing.assert_array_equal(dev_out.numpy(), want)
    with pytest.raises(ShapeError, match="out"):
        orb_compute(img, kps, 1.2, out=np.zeros((len(kps) + 1, 32), np.uint8), backend=backend)
    with pytest.raises(DTypeError, match="out"):
        orb_compute(img, kps, 1.2, out=np.zeros((len(kps), 32), np.int32), backend=backend)
    frozen = np.zeros((len(kps), 32), np.uint8)
    frozen.setflags(write=False)
    with pytest.raises(WarpvxValueError, match="out"):
        orb_compute(img, kps, 1.2, out=frozen, backend=backend)


@pytest.mark.parametrize("name", ["astronaut", "coffee"])
def test_real_use_recovers_rotation_and_scale(backend, name):
    """Photo vs a 20 deg rotated, 0.8 scaled view of it: mutual Hamming matches plus RANSAC
    recover the transform."""
    img = gray(name)
    h, w = img.shape
    affine = cv2.getRotationMatrix2D((w / 2, h / 2), 20, 0.8)
    view = cv2.warpAffine(img, affine, (w, h), flags=cv2.INTER_LINEAR)
    k1, d1 = _host(*warpvx.orb(img, 2000, backend=backend))
    k2, d2 = _host(*warpvx.orb(view, 2000, backend=backend))
    pairs, _ = warpvx.match_hamming(d1, d2, cross_check=True, backend=backend)
    pairs = np.asarray(pairs if isinstance(pairs, np.ndarray) else pairs.numpy())
    assert len(pairs) >= 300
    H, inliers = cv2.findHomography(k1.xy()[pairs[:, 0]], k2.xy()[pairs[:, 1]], cv2.RANSAC, 3.0)
    corners = np.array([[[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]]], np.float64)
    got = cv2.perspectiveTransform(corners, H)[0]
    want = cv2.perspectiveTransform(corners, np.vstack([affine, [0, 0, 1]]))[0]
    assert inliers.mean() >= 0.6
    assert np.linalg.norm(got - want, axis=1).max() <= 3.0


# --- the cv2 drop-in ----------------------------------------------------------------------------


def test_cv_orb_drop_in():
    from warpvx import cv as wcv

    img = gray("chelsea")
    orb = wcv.ORB_create(1000)
    kps, desc = orb.detectAndCompute(img, None)
    assert all(isinstance(k, cv2.KeyPoint) for k in kps) and desc.shape == (len(kps), 32)
    assert orb.descriptorSize() == 32 and orb.defaultNorm() == cv2.NORM_HAMMING
    kps2 = orb.detect(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))  # colour converted, as cv2
    assert len(kps2) == len(kps)
    # compute drops keypoints within edgeThreshold of the border, as cv2 does.
    cv_kps = cv2.ORB_create(1000, edgeThreshold=5, patchSize=5).detect(img)
    kept, cdesc = orb.compute(img, cv_kps)
    ref_kept, _ = cv2.ORB_create(1000).compute(img, cv_kps)
    assert sorted(k.pt for k in kept) == sorted(k.pt for k in ref_kept)
    assert cdesc.shape == (len(kept), 32)
    with runs_on_cv2("WTA_K"):
        wcv.ORB_create(WTA_K=3).detect(img)
    assert len(orb.detect(img, np.ones_like(img))) == len(orb.detect(img))  # masks: tests/cv
    with runs_on_cv2("patchSize"):
        wcv.ORB_create(patchSize=21).detect(img)
