"""Kernels of the one-graph ORB extractor but the quadtree's (:mod:`.quadtree`): pyramid edge
rows, detection, the candidate sort's keys, orientation, descriptors packed into the batch's
outputs; every level in each launch (see :mod:`.plan`)."""

from __future__ import annotations

import warp as wp

from .._filtering import round_shift, taps16i
from .._sampling import read_reflect101
from ..fast_corners import fast_score
from .funcs import (C_CAND, C_CAND_R, C_FINAL, C_OVER, C_SURV_R, HALF_PATCH, KEY_CELL_SHIFT,
                    KEY_LEVEL_SHIFT, KEY_X_SHIFT, KEY_Y_SHIFT, N_STRIPES, PATH_DEPTH,
                    PATH_ROOT_SHIFT, STRIPES, UMAX, LevelInfo, batch_final, batch_image,
                    batch_key, batch_level_image, batch_offset, batch_pad, candidate_key,
                    describe_byte, fast_atan2, key_field, level_holding, quadtree_path)

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

# Radius of the 7x7 Gaussian ORB describes on.
BLUR_RADIUS = wp.constant(3)

# --------------------------------------------------------------------------------------------
# Kernels of the one-graph extractor (all levels per launch, all images of a batch)
#
# Each kernel runs over the images of a batch of equal-sized images: its first thread index
# t runs over the batch's items, image by image (t = b * n + i for n items an image: pixels,
# survivor or candidate slots, keypoints), and ``funcs.batch_image`` finds b, without a
# division for one image: a batch of one launches as the one-image extractor did (on the CPU
# device a multi-dimensional index costs every thread a division). Per-image buffers carry
# the image as their first index and each kernel takes its image's part
# (``counters = counters[b]``: a view, no copy), so the body reads as for one image and every
# index stored in a buffer is one of the image's own. Threads with nothing to do return before
# taking the views (on the CPU device a view costs each thread time). The pyramids
# are flat and level-major (:func:`.funcs.batch_level_image`); the two radix sorts sort the
# whole batch at once, the image above each key (:func:`.funcs.batch_key`).
# --------------------------------------------------------------------------------------------


@wp.kernel
def blur_edge_rows(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                   kx: taps16i, ky: taps16i, shift: int, blurred: wp.uint64):
    """The 7x7 Gaussian (BORDER_REFLECT_101) of the BLUR_RADIUS rows at the top and bottom
    of every level of every image, from the quantised taps of ``_filtering.blur_taps``: exact
    integer row sums, weighted column sum, one rounding shift, the integers of OpenCV's 8-bit
    GaussianBlur (so bit-exact). The batch's levels are blurred as [batch * h, w] blocks, where
    these rows read the neighbouring image instead of reflecting: this redoes them."""
    b, level, e, x = wp.tid()
    info = levels[level]
    if x >= info.width:
        return
    y = e
    if e >= BLUR_RADIUS:
        y = info.height - 2 * BLUR_RADIUS + e
    img = batch_level_image(pyr, levels, level, batch, b)
    acc = int(0)
    for dy in range(-BLUR_RADIUS, BLUR_RADIUS + 1):
        row = int(0)
        for dx in range(-BLUR_RADIUS, BLUR_RADIUS + 1):
            row += kx[wp.abs(dx)] * read_reflect101(img, y + dy, x + dx)
        acc += ky[wp.abs(dy)] * row
    out = batch_level_image(blurred, levels, level, batch, b)
    out[y, x] = round_shift(acc, shift)


@wp.kernel
def gather_heads(counters: wp.array2d(dtype=wp.int32), final_cap: int,
                 heads: wp.array2d(dtype=wp.int32), starts: wp.array(dtype=wp.int32)):
    """heads[b, j] = counters[b, j]: each image's leading counters in one block (one copy to
    the host); thread (b, 0) also writes starts[b + 1], the keypoints of images 0..b (each
    count capped at ``final_cap``: what the plan holds), starts[0] = 0: where
    ``describe_levels`` packs each image's keypoints."""
    b, j = wp.tid()
    heads[b, j] = counters[b, j]
    if j == 0:
        total = int(0)
        for c in range(b + 1):
            total += wp.min(counters[c, C_FINAL], final_cap)
        starts[b + 1] = total
        if b == 0:
            starts[0] = 0


@wp.kernel
def score_pixels(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo), n_levels: int,
                 row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                 threshold: int, n_pixels: int, scores: wp.array(dtype=wp.uint8)):
    """FAST score at ``threshold`` of each pixel a cell owns (>= 19 px inside), 0 elsewhere:
    scores[t] of pixel i of image b, t = b * n_pixels + i (a 1-D launch: on the CPU device a
    2-D one costs every thread an index split, and so do views; same on a GPU)."""
    t = wp.tid()
    b = batch_image(t, batch, n_pixels)
    i = t - b * n_pixels
    level = level_holding(i, levels, n_levels, False)
    info = levels[level]
    w = info.width
    r = i - info.pix
    y = r // w
    x = r - y * w
    s = int(0)
    if row_of_y[info.row + y] >= 0 and col_of_x[info.col + x] >= 0:
        s = fast_score(batch_level_image(pyr, levels, level, batch, b), y, x, threshold)
    scores[t] = wp.uint8(s)


@wp.kernel
def suppress_pixels(levels: wp.array(dtype=LevelInfo), n_levels: int,
                    row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                    batch: int, n_pixels: int, scores: wp.array(dtype=wp.uint8), ini_th: int,
                    cells_at: int, region: int, counters: wp.array(dtype=wp.int32),
                    survivors: wp.array(dtype=wp.int64)):
    """OpenCV's strict 3x3 maximum within the cell: append the survivors (candidate keys) to
    the region of stripe i % N_STRIPES, and count those >= ``ini_th`` per cell. Pixels as in
    ``score_pixels``; most score 0 and return first. ``counters`` and ``survivors`` are the
    batch's [B, n] buffers seen flat (1-D arrays only: Warp's CPU device then runs the kernel
    with constant strides, 2x faster here)."""
    t = wp.tid()
    s = int(scores[t])
    if s == 0:
        return
    b = batch_image(t, batch, n_pixels)
    i = t - b * n_pixels
    n_counters = counters.shape[0] // batch
    level = level_holding(i, levels, n_levels, False)
    info = levels[level]
    w = info.width
    r = i - info.pix
    y = r // w
    x = r - y * w
    ro = info.row
    co = info.col
    cr = row_of_y[ro + y]
    cc = col_of_x[co + x]
    # Owned pixels lie >= 19 px inside the level: the neighbours exist.
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if dy != 0 or dx != 0:
                if row_of_y[ro + y + dy] == cr and col_of_x[co + x + dx] == cc:
                    if int(scores[t + dy * w + dx]) >= s:
                        return
    cell = cr * info.n_cols + cc
    if s >= ini_th:
        wp.atomic_add(counters, b * n_counters + cells_at + info.cell + cell, 1)
    stripe = i % N_STRIPES
    slot = wp.atomic_add(counters, b * n_counters + C_SURV_R + stripe, 1)
    # Past the capacity the count still grows: pad_paths flags it, the frame takes extract_host.
    if slot < region:
        survivors[(b * N_STRIPES + stripe) * region + slot] = candidate_key(level, cell, y, x, s)


@wp.kernel
def select_candidates(batch: int, survivors: wp.array(dtype=wp.int64), surv_region: int,
                      levels: wp.array(dtype=LevelInfo),
                      roots: wp.array(dtype=wp.int32), ini_th: int, min_th: int, cells_at: int,
                      cand_region: int, digits: int, root_bits: int, key_bits: int,
                      counters: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                      paths: wp.array(dtype=wp.int64), sort_keys: wp.array(dtype=wp.int64),
                      order: wp.array(dtype=wp.int32)):
    """Keep a survivor when its score reaches its cell's threshold; write its candidate key,
    its quadtree path, the path's sort key (level | root | first ``digits`` quadrants) and its
    slot (the sort's value) into the region of stripe j % N_STRIPES. A 1-D launch over the
    batch's survivor slots (see ``score_pixels``); the per-image buffers seen flat (see
    ``suppress_pixels``)."""
    t = wp.tid()
    n = N_STRIPES * surv_region
    b = batch_image(t, batch, n)
    j = t - b * n
    cb = batch_offset(b, counters.shape[0], batch)
    r = j // surv_region
    if j - r * surv_region >= wp.min(counters[cb + C_SURV_R + r], surv_region):
        return
    key = survivors[t]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    cell = key_field(key, KEY_CELL_SHIFT, 0x3FFFF)
    s = key_field(key, 0, 0xFF)
    th = min_th
    if counters[cb + cells_at + levels[level].cell + cell] > 0:
        th = ini_th
    if s < th:
        return
    stripe = j % N_STRIPES
    slot = wp.atomic_add(counters, cb + C_CAND_R + stripe, 1)
    if slot < cand_region:
        at = stripe * cand_region + slot
        ib = b * N_STRIPES * cand_region + at
        cand[ib] = key
        path = quadtree_path(level, key_field(key, KEY_X_SHIFT, 0xFFFF),
                             key_field(key, KEY_Y_SHIFT, 0xFFFF), levels, roots)
        paths[ib] = path
        root = (path >> wp.int64(PATH_ROOT_SHIFT)) & wp.int64(511)
        kept = (path & wp.int64(0xFFFFFFFF)) >> wp.int64(2 * (PATH_DEPTH - digits))
        sort_keys[ib] = batch_key(b, key_bits, (((wp.int64(level) << wp.int64(root_bits)) | root)
                                                << wp.int64(2 * digits)) | kept)
        order[ib] = at


@wp.kernel
def pad_paths(batch: int, counters: wp.array(dtype=wp.int32), surv_region: int,
              cand_region: int, key_bits: int, sort_keys: wp.array(dtype=wp.int64)):
    """Pad the candidate regions' unused slots (a fixed-size sort puts them last); thread 0
    writes the candidate total and whether a region overflowed. Buffers seen flat."""
    t = wp.tid()
    n = N_STRIPES * cand_region
    b = batch_image(t, batch, n)
    i = t - b * n
    cb = batch_offset(b, counters.shape[0], batch)
    r = i // cand_region
    if i - r * cand_region >= counters[cb + C_CAND_R + r]:
        sort_keys[t] = batch_pad(b, key_bits)
    if i == 0:
        total = int(0)
        over = int(0)
        for k in range(STRIPES):
            c = counters[cb + C_CAND_R + k]
            total += wp.min(c, cand_region)
            if c > cand_region or counters[cb + C_SURV_R + k] > surv_region:
                over = 1
        counters[cb + C_CAND] = total
        counters[cb + C_OVER] = over


@wp.kernel
def pad_keys(batch: int, n: int, counters: wp.array(dtype=wp.int32), which: int,
             key_bits: int, keys: wp.array(dtype=wp.int64)):
    """keys[i] = the image's padding key past the count (a fixed-size sort puts them last);
    ``n`` keys an image, buffers seen flat."""
    t = wp.tid()
    b = batch_image(t, batch, n)
    if t - b * n >= counters[batch_offset(b, counters.shape[0], batch) + which]:
        keys[t] = batch_pad(b, key_bits)


@wp.kernel
def gather_paths(batch: int, order: wp.array(dtype=wp.int32),
                 counters: wp.array(dtype=wp.int32), paths: wp.array(dtype=wp.int64),
                 sorted_paths: wp.array(dtype=wp.int64)):
    """The full paths in sorted order (``order``: each image's own slots); buffers seen
    flat."""
    t = wp.tid()
    n = sorted_paths.shape[0]
    if batch > 1:
        n = n // batch
    b = batch_image(t, batch, n)
    if t - b * n < counters[batch_offset(b, counters.shape[0], batch) + C_CAND]:
        sorted_paths[t] = paths[b * n + order[t]]


@wp.kernel
def accumulate_moments(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                       counters: wp.array2d(dtype=wp.int32),
                       final_values: wp.array2d(dtype=wp.int32),
                       cand: wp.array2d(dtype=wp.int64), moments: wp.array3d(dtype=wp.int32)):
    """IC_Angle's moments of keypoint i, one disc row v per thread: m10 += sum u I,
    m01 += v sum I (integer sums: the order of the atomics does not matter). Keypoint i of
    image b is thread row b * final_cap + i (2-D, as for one image: see ``score_pixels``)."""
    t, r = wp.tid()
    b, i, _key, level, cx, cy = batch_final(t, batch, moments.shape[1], counters, final_values,
                                            cand)
    if i < 0:
        return
    img = batch_level_image(pyr, levels, level, batch, b)
    moments = moments[b]
    v = r - HALF_PATCH
    d = UMAX[wp.abs(v)]
    row = int(0)
    weighted = int(0)
    for u in range(-d, d + 1):
        val = read_reflect101(img, cy + v, cx + u)
        row += val
        weighted += u * val
    wp.atomic_add(moments, i, 0, weighted)
    wp.atomic_add(moments, i, 1, v * row)


@wp.kernel
def describe_levels(blurred: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                    counters: wp.array2d(dtype=wp.int32),
                    final_values: wp.array2d(dtype=wp.int32), cand: wp.array2d(dtype=wp.int64),
                    moments: wp.array3d(dtype=wp.int32), pattern: wp.array2d(dtype=wp.int32),
                    starts: wp.array(dtype=wp.int32), kp_fields: wp.array(dtype=wp.float32),
                    kp_octave: wp.array(dtype=wp.int32), desc: wp.array2d(dtype=wp.uint8)):
    """Descriptor byte j of keypoint i on its blurred level; thread j = 0 also writes the
    keypoint's level-0 fields. Image b's keypoints go to rows starts[b] + i of the batch's
    packed outputs (``gather_heads``), N = starts[batch] rows in all: ``kp_fields`` holds x,
    y, response, size, angle as a (5, N) block, so one contiguous copy per output takes the
    whole batch out. Threads as in ``accumulate_moments``."""
    t, j = wp.tid()
    b, i, key, level, x, y = batch_final(t, batch, moments.shape[1], counters, final_values,
                                         cand)
    if i < 0:
        return
    angle = fast_atan2(float(moments[b, i, 1]), float(moments[b, i, 0]))
    img = batch_level_image(blurred, levels, level, batch, b)
    at = starts[b] + i
    desc[at, j] = wp.uint8(describe_byte(img, y, x, angle, pattern, j))
    if j == 0:
        n = starts[batch]
        s = levels[level].scale
        kp_fields[at] = float(x) * s
        kp_fields[n + at] = float(y) * s
        kp_fields[2 * n + at] = float(key_field(key, 0, 0xFF))
        kp_fields[3 * n + at] = levels[level].kp_size
        kp_fields[4 * n + at] = angle
        kp_octave[at] = level
