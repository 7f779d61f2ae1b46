"""Plans of the one-graph ORB extractor: buffers, the launch sequence, CUDA-graph capture.

A :class:`OrbPlan` holds everything one (device, image size, parameters, batch size) needs;
the pool (:func:`acquire`, :func:`release`) hands each call a plan no other call is using.
A batch of B images runs the same launches as one image, each over B images (the kernels'
first thread index; see :mod:`.kernels`), one captured graph for the batch.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ... import _orb_spec as spec
from ..._pyramid_sizes import resize_scales, scale_pyramid_sizes
from ...keypoints import Keypoints
from ...modes import BORDER_REFLECT_101
from .._filtering import blur_taps, fit_block, launch_filter
from .._launch import CapturedProgram
from ..scale_pyramid import RESIZE_ROWS, linear_taps, resize, resize_kernel, resize_tables
from .funcs import (C_FINAL, C_NODES, C_OVER, DEPTHS, RANK_CHUNKS, STRIPES, Division, LevelInfo)
from .host import _capacity, _pattern_on, extract_host
from .kernels import (BLUR_RADIUS, accumulate_moments, blur_edge_rows, describe_levels,
                      gather_heads, gather_paths, pad_keys, pad_paths, score_pixels,
                      select_candidates, suppress_pixels)
from .quadtree import (alloc_nodes, count_depths, emit_finals, link_nodes, plan_divisions,
                       rank_nodes, sum_depth_counts)

# --------------------------------------------------------------------------------------------
# The one-graph extractor: plans
# --------------------------------------------------------------------------------------------


def _round_up(n: int, m: int) -> int:
    return max(m, -(-int(n) // m) * m)


def _view(buf, offset: int, shape: tuple, dtype):
    """A typed view of part of a flat device buffer (kept alive by the plan)."""
    itemsize = wp.types.type_size_in_bytes(dtype)
    return wp.array(ptr=buf.ptr + offset * itemsize, shape=shape, dtype=dtype,
                    device=buf.device)


def _batch_resize(prev, dst, sizes, batch: int, device):
    """The launch resizing level l-1 of every image of a batch into level l, recorded
    (``wp.launch(..., record_cmd=True)``: replayed without packing its arguments again), or
    None where OpenCV's 2x INTER_AREA edge rule applies (it reads the image's own height;
    then each image is resized alone). ``prev``, ``dst``: the levels' [batch * h, w] blocks,
    ``sizes`` their ((w, h) of l-1, (w, h) of l). One ``scale_pyramid.resize_kernel`` launch
    over the block: its y taps, offset per image by b * h_prev, keep every image's rows
    apart."""
    (sw, sh), (dw, dh) = sizes
    _, scales = resize_scales((sw, sh), (dw, dh))
    if tuple(scales) == (2.0, 2.0):
        return None
    x_taps, _ = resize_tables((sw, sh), (dw, dh), tuple(scales), device)
    y_taps = linear_taps(dh, sh, scales[1], False)
    shift = np.repeat(np.arange(batch, dtype=np.int32) * sh, dh)[:, None] * np.array(
        [1, 1, 0, 0], np.int32)
    y_taps = wp.array(np.tile(y_taps, (batch, 1)) + shift, dtype=wp.vec4i, device=device)
    rows, _ = fit_block(RESIZE_ROWS, 1, batch * dh, dw, device)
    return wp.launch(resize_kernel(rows), dim=((batch * dh + rows - 1) // rows, dw),
                     inputs=[prev, 1, x_taps, y_taps, 0], outputs=[dst], device=device,
                     record_cmd=True)


class OrbPlan:
    """Buffers, tables and (on CUDA) the captured graph of one (device, size, parameters,
    batch): ``batch`` equal-sized images go through every launch together.

    Capacities: non-maximum-suppression survivors, the pyramid's pixel count over
    ``survivor_divisor``, and candidates (what the quadtree sorts), over
    ``candidate_divisor`` (real photos keep about 1 pixel in 50, grass 1 in 17, noise 1 in
    12); ``run`` takes :func:`extract_host` for a frame that exceeds one, or the node
    capacities.
    """

    def __init__(self, device, height: int, width: int, n_features: int, scale_factor: float,
                 n_levels: int, ini_th: int, min_th: int, *, batch: int = 1,
                 survivor_divisor: int = 8, candidate_divisor: int = 20, graph: bool = True):
        self.device = wp.get_device(device)
        self.batch = batch
        self.shape = (height, width)
        self.params = (n_features, scale_factor, n_levels, ini_th, min_th)
        self.n_levels = n_levels
        sizes = scale_pyramid_sizes(width, height, n_levels, scale_factor)
        wanted = spec.features_per_level(n_features, scale_factor, n_levels)
        grids = [spec.cell_grid(lw, lh) for lw, lh in sizes]
        scales = spec.level_scales(scale_factor, n_levels)
        kp_sizes = spec.keypoint_sizes(scale_factor, n_levels)

        infos, rows, cols, roots = [], [], [], []
        pix = row = col = cell = root = node = final = 0
        for level, ((lw, lh), grid) in enumerate(zip(sizes, grids)):
            n_ini, hx, bounds, qt_height = spec.root_geometry(grid)
            # Final list: <= n + 2 (a division adds <= 3 past n - 1), or 4 per root after the
            # first pass; ordered nodes: a few rounds of at most n nodes.
            final_cap = max(wanted[level] + 2, 4 * n_ini)
            node_cap = 4 * final_cap + 64
            info = LevelInfo()
            info.pix, info.width, info.height, info.row, info.col = pix, lw, lh, row, col
            info.n_cols, info.cell, info.want = grid.n_cols, cell, wanted[level]
            info.n_ini, info.root, info.qt_height = n_ini, root, qt_height
            info.node, info.node_cap = node, node_cap
            info.hx, info.scale, info.kp_size = float(hx), float(scales[level]), \
                float(kp_sizes[level])
            infos.append(info)
            rows.append(grid.row_of_y)
            cols.append(grid.col_of_x)
            roots.append(np.array(bounds, np.int32))
            pix += lw * lh
            row += lh
            col += lw
            cell += grid.n_rows * grid.n_cols
            root += n_ini + 1
            node += node_cap
            final += final_cap
        # Sort keys: the quadrant digits that separate any two pixels of a root node (a node's
        # pixel columns, its width + 1, halve, rounded up, per division), plus one.
        spans = [max(max(b1 - b0 for b0, b1 in zip(r[:-1], r[1:])) + 1, info.qt_height)
                 for info, r in zip(infos, roots)]
        self.digits = min(16, max(max(1, math.ceil(math.log2(v))) for v in spans) + 1)
        self.root_bits = max(1, (max(info.n_ini for info in infos) - 1).bit_length())
        level_bits = max(1, (n_levels - 1).bit_length())
        self.sort_bits = level_bits + self.root_bits + 2 * self.digits + 1  # top bit: padding
        self.node_caps = np.array([info.node_cap for info in infos])
        self.place_bits = max(self.root_bits + 2 * self.digits,
                              int(self.node_caps.max()).bit_length() + 2)
        self.final_bits = level_bits + 5 + self.place_bits + 1
        self.level_sizes = sizes
        self.wanted = wanted
        self.n_pixels = pix
        # Per-stripe regions, a quarter over the even share: the stripes are interleaved pixels.
        proven = sum(_capacity(g) for g in grids)
        self.surv_region = _round_up(min(pix // survivor_divisor, proven) * 5 // 4 // STRIPES, 64)
        self.cand_region = _round_up(min(pix // candidate_divisor, proven) * 5 // 4 // STRIPES,
                                     64)
        self.surv_cap = STRIPES * self.surv_region
        self.cand_cap = STRIPES * self.cand_region
        self.final_cap = final
        self.node_cap = node
        self.nodes_at = int(C_NODES)
        self.singles_at = int(C_NODES) + n_levels
        self.multis_at = self.singles_at + n_levels * STRIPES * DEPTHS
        self.cells_at = self.multis_at + n_levels * STRIPES * DEPTHS
        self.groups_at = self.cells_at + cell
        n_counters = self.groups_at + n_levels * DEPTHS

        # The batch's images in the sort keys' top bits (see kernels.batch_key).
        self.batch_bits = (batch - 1).bit_length()
        n_heads = int(C_NODES) + n_levels  # read by the host: candidates, finals, overflow, nodes

        dev = self.device
        self.level_info = wp.array(infos, dtype=LevelInfo, device=dev)
        self.row_of_y = wp.array(np.concatenate(rows).astype(np.int32), dtype=wp.int32, device=dev)
        self.col_of_x = wp.array(np.concatenate(cols).astype(np.int32), dtype=wp.int32, device=dev)
        self.roots = wp.array(np.concatenate(roots), dtype=wp.int32, device=dev)
        self.pattern = _pattern_on(str(dev))
        # Flat level-major pyramids (funcs.batch_level_image): level l of image b at
        # batch * pix_l + b * w_l * h_l. Views: per image and level (the input, the host path),
        # per level over the whole batch (the resize).
        def per_image(buf):
            return [[_view(buf, batch * info.pix + b * info.width * info.height,
                           (info.height, info.width), wp.uint8) for info in infos]
                    for b in range(batch)]

        def per_level(buf):
            return [_view(buf, batch * info.pix, (batch * info.height, info.width), wp.uint8)
                    for info in infos]

        self.pyr = wp.empty(batch * pix, dtype=wp.uint8, device=dev)
        self.blurred = wp.empty(batch * pix, dtype=wp.uint8, device=dev)
        self.images, self.blurred_images = per_image(self.pyr), per_image(self.blurred)
        self.blocks, self.blurred_blocks = per_level(self.pyr), per_level(self.blurred)
        self.inputs = _view(self.pyr, 0, (batch, height, width), wp.uint8)
        blocks = self.blocks
        self.resizes = [_batch_resize(blocks[level - 1], blocks[level], sizes[level - 1:level + 1],
                                      batch, dev) for level in range(1, n_levels)]
        self.blur_taps = blur_taps(7, 7, 2.0, 2.0, int(BORDER_REFLECT_101))
        self.scores = wp.empty(batch * pix, dtype=wp.uint8, device=dev)  # image-major
        self.counters = wp.zeros((batch, n_counters), dtype=wp.int32, device=dev)
        cap = self.cand_cap
        self.survivors = wp.empty((batch, self.surv_cap), dtype=wp.int64, device=dev)
        self.cand = wp.empty((batch, cap), dtype=wp.int64, device=dev)
        self.paths = wp.empty((batch, cap), dtype=wp.int64, device=dev)
        # The radix sorts take flat arrays of twice the count; the kernels see the first half
        # (self.flat).
        self.sort_keys = wp.empty(2 * batch * cap, dtype=wp.int64, device=dev)
        self.order = wp.empty(2 * batch * cap, dtype=wp.int32, device=dev)
        self.sorted_paths = wp.empty((batch, cap), dtype=wp.int64, device=dev)
        self.totals = wp.empty((batch, n_levels, 2, DEPTHS), dtype=wp.int32, device=dev)
        self.lcp = wp.empty((batch, cap), dtype=wp.int32, device=dev)
        self.divisions = wp.zeros((batch, n_levels), dtype=Division, device=dev)
        self.node_base = wp.empty((batch, cap), dtype=wp.int32, device=dev)
        nc = self.node_cap
        self.node_start = wp.empty((batch, nc), dtype=wp.int32, device=dev)
        self.node_depth = wp.empty((batch, nc), dtype=wp.int32, device=dev)
        self.node_count = wp.empty((batch, nc), dtype=wp.int32, device=dev)
        self.node_growth = wp.empty((batch, nc), dtype=wp.int32, device=dev)
        self.node_parent = wp.empty((batch, nc), dtype=wp.int32, device=dev)
        self.node_rank = wp.zeros((batch, nc), dtype=wp.int32, device=dev)
        self.node_grown = wp.zeros((batch, nc), dtype=wp.int32, device=dev)
        self.groups = wp.empty((batch, n_levels, DEPTHS, int(self.node_caps.max())),
                               dtype=wp.int32, device=dev)
        fc = self.final_cap
        self.final_keys = wp.empty(2 * batch * fc, dtype=wp.int64, device=dev)
        self.final_values = wp.empty(2 * batch * fc, dtype=wp.int32, device=dev)
        self.final_keys_b = _view(self.final_keys, 0, (batch, fc), wp.int64)
        self.final_values_b = _view(self.final_values, 0, (batch, fc), wp.int32)
        self.moments = wp.empty((batch, fc, 2), dtype=wp.int32, device=dev)
        # Flat views for the kernels taking 1-D arrays only (see kernels.suppress_pixels; the
        # radix sorts' buffers: their first halves).
        self.flat = {name: getattr(self, name).flatten()
                     for name in ("counters", "survivors", "cand", "paths", "sorted_paths", "lcp",
                                  "divisions", "node_base", "node_start", "node_depth",
                                  "node_count", "node_growth", "node_parent", "node_rank",
                                  "node_grown")}
        self.flat.update(order=self.order[:batch * cap], final_keys=self.final_keys[:batch * fc],
                         final_values=self.final_values[:batch * fc])
        # The batch's keypoints packed image after image (kernels.describe_levels) at the
        # starts kernels.gather_heads computes.
        self.starts = wp.empty(batch + 1, dtype=wp.int32, device=dev)
        self.kp_fields = wp.empty(5 * batch * fc, dtype=wp.float32, device=dev)
        self.kp_octave = wp.empty(batch * fc, dtype=wp.int32, device=dev)
        self.desc = wp.empty((batch * fc, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        self.heads = wp.empty((batch, n_heads), dtype=wp.int32, device=dev)
        self.head = wp.empty((batch, n_heads), dtype=wp.int32, device="cpu", pinned=dev.is_cuda)
        self.side = wp.Stream(dev) if dev.is_cuda else None
        self.captured = CapturedProgram(self.program, dev, enabled=bool(graph) and dev.is_cuda)
        self.last_stream = None  # where the last frame's output copies were enqueued (CUDA)

    # -- the device program ---------------------------------------------------------------

    def stage_pyramid(self):
        """Level l of every image from level l - 1: one recorded launch per level for the
        batch (no argument packing per call: on the CPU device the plan runs eagerly)."""
        for level, launch in enumerate(self.resizes, 1):
            if launch is None:  # OpenCV's 2x edge rule: image by image
                w, h = self.level_sizes[level]
                for images in self.images:
                    resize(images[level - 1], (w, h), out=images[level])
                continue
            launch.launch()

    def stage_blur(self):
        """The 7x7 Gaussian of every level (``_filtering``'s fused filter, as
        ``kernels_warp.gaussian_blur``): one launch per level for the whole batch, over the
        level's [batch * h, w] block; then, for a batch, one launch redoes the rows within the
        filter's reach of each image's top and bottom (:func:`.kernels.blur_edge_rows`), which
        the block filter took from the neighbouring image."""
        taps = self.blur_taps
        for src, dst in zip(self.blocks, self.blurred_blocks):
            launch_filter(src, taps, dst, cache=True)
        if self.batch > 1:
            wp.launch(blur_edge_rows,
                      dim=(self.batch, self.n_levels, 2 * int(BLUR_RADIUS), self.level_sizes[0][0]),
                      inputs=[wp.uint64(self.pyr.ptr), self.batch, self.level_info, taps.kx,
                              taps.ky, taps.shift, wp.uint64(self.blurred.ptr)],
                      device=self.device)

    def stage_detect(self):
        dev = self.device
        _, _, n_levels, ini_th, min_th = self.params
        batch = self.batch
        flat = self.flat
        self.counters.zero_()
        wp.launch(score_pixels, dim=batch * self.n_pixels,
                  inputs=[wp.uint64(self.pyr.ptr), batch, self.level_info, n_levels,
                          self.row_of_y, self.col_of_x, min(ini_th, min_th), self.n_pixels],
                  outputs=[self.scores], device=dev)
        wp.launch(suppress_pixels, dim=batch * self.n_pixels,
                  inputs=[self.level_info, n_levels, self.row_of_y, self.col_of_x, batch,
                          self.n_pixels, self.scores, ini_th, self.cells_at, self.surv_region],
                  outputs=[flat["counters"], flat["survivors"]], device=dev)
        wp.launch(select_candidates, dim=batch * self.surv_cap,
                  inputs=[batch, flat["survivors"], self.surv_region, self.level_info,
                          self.roots, ini_th, min_th, self.cells_at, self.cand_region,
                          self.digits, self.root_bits, self.sort_bits],
                  outputs=[flat["counters"], flat["cand"], flat["paths"], self.sort_keys,
                           self.order], device=dev)

    def stage_quadtree(self):
        self.stage_sort()
        self.stage_nodes()
        self.stage_finals()

    def stage_sort(self):
        """Candidates sorted by quadtree path (fixed size: the padding goes last), the whole
        batch in one sort (each image's run at its row)."""
        dev = self.device
        batch = self.batch
        wp.launch(pad_paths, dim=batch * self.cand_cap,
                  inputs=[batch, self.flat["counters"], self.surv_region, self.cand_region,
                          self.sort_bits],
                  outputs=[self.sort_keys], device=dev)
        wp.utils.radix_sort_pairs(self.sort_keys, self.order, batch * self.cand_cap, 0,
                                  self.sort_bits + self.batch_bits)
        wp.launch(gather_paths, dim=batch * self.cand_cap,
                  inputs=[batch, self.flat["order"], self.flat["counters"], self.flat["paths"]],
                  outputs=[self.flat["sorted_paths"]], device=dev)

    def stage_nodes(self):
        """Node counts per depth, DistributeOctTree's decisions, the second loop's order."""
        dev = self.device
        batch = self.batch
        n_levels = self.n_levels
        cap = self.cand_cap
        flat = self.flat
        wp.launch(count_depths, dim=batch * cap,
                  inputs=[batch, flat["sorted_paths"], flat["counters"], cap, self.digits,
                          self.singles_at, self.multis_at],
                  outputs=[flat["lcp"]], device=dev)
        wp.launch(sum_depth_counts, dim=(batch, n_levels, 2, DEPTHS),
                  inputs=[self.counters, self.singles_at, self.multis_at], outputs=[self.totals],
                  device=dev)
        wp.launch(plan_divisions, dim=(batch, n_levels), inputs=[self.level_info, self.totals],
                  outputs=[self.divisions], device=dev)
        wp.launch(alloc_nodes, dim=batch * cap,
                  inputs=[batch, flat["sorted_paths"], flat["lcp"], flat["counters"], cap,
                          self.level_info, flat["divisions"], self.groups_at],
                  outputs=[flat["node_base"], flat["node_start"], flat["node_depth"],
                           flat["node_count"], flat["node_growth"], self.groups], device=dev)
        nc = self.node_cap
        wp.launch(link_nodes, dim=batch * nc,
                  inputs=[batch, nc, self.level_info, n_levels, flat["counters"],
                          flat["divisions"], flat["lcp"], flat["node_base"], flat["node_start"],
                          flat["node_depth"]],
                  outputs=[flat["node_parent"]], device=dev)
        self.node_rank.zero_()
        self.node_grown.zero_()
        wp.launch(rank_nodes, dim=(batch * nc, RANK_CHUNKS),
                  inputs=[batch, nc, self.level_info, n_levels, flat["counters"],
                          flat["divisions"], flat["sorted_paths"], self.groups_at, self.groups,
                          flat["node_start"], flat["node_depth"], flat["node_count"],
                          flat["node_growth"], flat["node_parent"]],
                  outputs=[flat["node_rank"], flat["node_grown"]], device=dev)

    def stage_finals(self):
        """The final list's nodes, their strongest points, sorted into the list order."""
        dev = self.device
        batch = self.batch
        cap = self.cand_cap
        flat = self.flat
        wp.launch(emit_finals, dim=batch * cap,
                  inputs=[batch, flat["sorted_paths"], flat["order"], flat["lcp"], flat["cand"],
                          flat["counters"], cap, self.level_info, flat["divisions"],
                          flat["node_base"], flat["node_rank"], flat["node_grown"],
                          self.place_bits, self.final_bits],
                  outputs=[flat["final_keys"], flat["final_values"]], device=dev)
        wp.launch(pad_keys, dim=batch * self.final_cap,
                  inputs=[batch, self.final_cap, flat["counters"], int(C_FINAL),
                          self.final_bits],
                  outputs=[flat["final_keys"]], device=dev)
        wp.utils.radix_sort_pairs(self.final_keys, self.final_values, batch * self.final_cap, 0,
                                  self.final_bits + self.batch_bits)

    def stage_describe(self):
        dev = self.device
        batch = self.batch
        self.moments.zero_()
        wp.launch(accumulate_moments, dim=(batch * self.final_cap, spec.PATCH_SIZE),
                  inputs=[wp.uint64(self.pyr.ptr), batch, self.level_info, self.counters,
                          self.final_values_b, self.cand],
                  outputs=[self.moments], device=dev)
        wp.launch(describe_levels, dim=(batch * self.final_cap, spec.DESCRIPTOR_BYTES),
                  inputs=[wp.uint64(self.blurred.ptr), batch, self.level_info, self.counters,
                          self.final_values_b, self.cand, self.moments, self.pattern,
                          self.starts],
                  outputs=[self.kp_fields, self.kp_octave, self.desc], device=dev)

    def stage_heads(self):
        """Each image's counters the host reads, into one block (:meth:`read_head`), and where
        each image's keypoints go in the packed outputs (:meth:`stage_describe`)."""
        wp.launch(gather_heads, dim=self.heads.shape, inputs=[self.counters, self.final_cap],
                  outputs=[self.heads, self.starts], device=self.device)

    def program(self):
        """Every device stage, fixed shapes: what the graph holds. On CUDA the blur runs on a
        side stream, beside detection and the quadtree (the graph keeps the concurrency)."""
        self.stage_pyramid()
        if self.side is None:
            self.stage_blur()
            self.stage_detect()
            self.stage_quadtree()
        else:
            main = wp.get_stream(self.device)
            with wp.ScopedStream(self.side):  # waits for the pyramid on entry
                self.stage_blur()
            self.stage_detect()
            self.stage_quadtree()
            main.wait_stream(self.side)
        self.stage_heads()
        self.stage_describe()

    def launch(self):
        """Run the program: eagerly the first time (loads the modules), then from a graph
        (:class:`~warpvx.kernels_warp._launch.CapturedProgram`)."""
        self.captured()

    # -- one batch ------------------------------------------------------------------------

    def read_head(self) -> np.ndarray:
        """int32 [batch, C_NODES + n_levels]: per image the counters the host needs
        (candidates, finals, overflow, nodes) as :meth:`stage_heads` left them; one copy, one
        sync."""
        wp.copy(self.head, self.heads)
        if self.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(self.device))
        return self.head.numpy().copy()

    def overflowed(self, head: np.ndarray) -> bool:
        """Whether the image of ``head`` (one row of :meth:`read_head`) exceeded a capacity."""
        return bool(head[C_OVER] != 0 or head[C_FINAL] > self.final_cap
                    or np.any(head[C_NODES:C_NODES + self.n_levels] > self.node_caps))

    def load(self, src):
        """Copy the input into level 0 of the pyramids: one uint8 HxW image (batch 1), a
        [batch, H, W] array or a list of ``batch`` HxW images, on the plan's device."""
        if isinstance(src, (list, tuple)):
            for b, img in enumerate(src):
                wp.copy(self.images[b][0], img)
        elif src.ndim == 3:
            wp.copy(self.inputs, src)
        else:
            wp.copy(self.images[0][0], src)

    def run(self, src) -> list:
        """Extract from every image of ``src`` (see :meth:`load`): [(Keypoints, descriptors)]
        in the batch's order, each what the image alone gives."""
        if self.device.is_cuda:
            # On another stream than the last batch, wait for that batch's output copies.
            stream = wp.get_stream(self.device)
            if self.last_stream is not None and self.last_stream is not stream:
                stream.wait_stream(self.last_stream)
            self.last_stream = stream
        self.load(src)
        self.launch()
        heads = self.read_head()
        over = [self.overflowed(head) for head in heads]
        results = self.take_outputs([min(int(head[C_FINAL]), self.final_cap) for head in heads])
        n_features, scale_factor, _, ini_th, min_th = self.params
        for b in np.flatnonzero(over):
            results[b] = extract_host(self.images[b], n_features, scale_factor, ini_th, min_th,
                                      blurred=self.blurred_images[b])
        return results

    def take_outputs(self, counts: list) -> list:
        """Fresh arrays holding each image's keypoints (the plan's buffers are reused):
        ``counts[b]`` keypoints of image b, at most ``final_cap`` (the rows
        ``kernels.describe_levels`` packed it into; an overflowed image's rows are skipped).
        One allocation and one copy per output for the batch, as for one image; each image's
        results are views of its rows."""
        dev = self.device
        starts = np.concatenate([[0], np.cumsum(counts)]).tolist()
        total = starts[-1]
        fields = wp.empty((5, total), dtype=wp.float32, device=dev)
        octave = wp.empty(total, dtype=wp.int32, device=dev)
        desc = wp.empty((total, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        if total:
            wp.copy(fields, self.kp_fields, count=5 * total)
            wp.copy(octave, self.kp_octave, count=total)
            wp.copy(desc, self.desc, count=total * spec.DESCRIPTOR_BYTES)
        results = []
        for a, b in zip(starts[:-1], starts[1:]):
            if a == b:  # Warp has no empty slices
                rows = [wp.empty(0, dtype=wp.float32, device=dev) for _ in range(5)]
                results.append((Keypoints(*rows, wp.empty(0, dtype=wp.int32, device=dev)),
                                wp.empty((0, spec.DESCRIPTOR_BYTES), dtype=wp.uint8,
                                         device=dev)))
            else:
                kps = Keypoints(*(fields[f, a:b] for f in range(5)), octave[a:b])
                results.append((kps, desc[a:b]))
        return results


_plans: OrderedDict = OrderedDict()  # key -> idle plans, least recently used first
_plans_lock = threading.Lock()
_PLANS_PER_KEY = 8
_PLAN_KEYS = 16


def acquire(key, make):
    with _plans_lock:
        free = _plans.get(key)
        if free:
            _plans.move_to_end(key)
            return free.pop()
    return make()


def release(key, plan):
    with _plans_lock:
        free = _plans.setdefault(key, [])
        _plans.move_to_end(key)
        if len(free) < _PLANS_PER_KEY:
            free.append(plan)
        while len(_plans) > _PLAN_KEYS:
            _plans.popitem(last=False)


