"""Plans of the one-graph ORB extractor: buffers, the launch sequence, CUDA-graph capture.

A :class:`OrbPlan` holds everything one (device, image size, parameters) needs; the pool
(:func:`acquire`, :func:`release`) hands each call a plan no other call is using.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ... import _orb_spec as spec
from ..._pyramid_sizes import scale_pyramid_sizes
from ...keypoints import Keypoints
from ..scale_pyramid import scale_pyramid
from .funcs import (C_FINAL, C_NODES, C_OVER, DEPTHS, RANK_CHUNKS, STRIPES, Division, LevelInfo)
from .host import _capacity, _pattern_on, blur_levels, extract_host
from .kernels import (accumulate_moments, alloc_nodes, count_depths, describe_levels, emit_finals,
                      gather_paths, link_nodes, pad_keys, pad_paths, plan_divisions, rank_nodes,
                      score_pixels, select_candidates, sum_depth_counts, suppress_pixels)

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


class OrbPlan:
    """Buffers, tables and (on CUDA) the captured graph of one (device, size, parameters).

    Capacities: non-maximum-suppression survivors, the pyramid's pixel count over
    ``survivor_divisor``, and candidates (what the quadtree sorts), over
    ``candidate_divisor`` (real photos keep about 1 pixel in 50, grass 1 in 17, noise 1 in
    12); ``run`` takes :func:`extract_host` for a frame that exceeds one, or the node
    capacities.
    """

    def __init__(self, device, height: int, width: int, n_features: int, scale_factor: float,
                 n_levels: int, ini_th: int, min_th: int, *, survivor_divisor: int = 8,
                 candidate_divisor: int = 20, graph: bool = True):
        self.device = wp.get_device(device)
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

        dev = self.device
        self.level_info = wp.array(infos, dtype=LevelInfo, device=dev)
        self.row_of_y = wp.array(np.concatenate(rows).astype(np.int32), dtype=wp.int32, device=dev)
        self.col_of_x = wp.array(np.concatenate(cols).astype(np.int32), dtype=wp.int32, device=dev)
        self.roots = wp.array(np.concatenate(roots), dtype=wp.int32, device=dev)
        self.pattern = _pattern_on(str(dev))
        # Flat pyramids: level l at offset LevelInfo.pix; per-level views for the resize and blur.
        self.pyr = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.blurred = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.levels = [_view(self.pyr, info.pix, (info.height, info.width), wp.uint8)
                       for info in infos]
        self.blurred_levels = [_view(self.blurred, info.pix, (info.height, info.width),
                                     wp.uint8) for info in infos]
        self.scores = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.counters = wp.zeros(n_counters, dtype=wp.int32, device=dev)
        cap = self.cand_cap
        self.survivors = wp.empty(self.surv_cap, dtype=wp.int64, device=dev)
        self.cand = wp.empty(cap, dtype=wp.int64, device=dev)
        self.paths = wp.empty(cap, dtype=wp.int64, device=dev)
        self.sort_keys = wp.empty(2 * cap, dtype=wp.int64, device=dev)  # radix sort: 2x
        self.order = wp.empty(2 * cap, dtype=wp.int32, device=dev)
        self.sorted_paths = wp.empty(cap, dtype=wp.int64, device=dev)
        self.totals = wp.empty((n_levels, 2, DEPTHS), dtype=wp.int32, device=dev)
        self.lcp = wp.empty(cap, dtype=wp.int32, device=dev)
        self.divisions = wp.zeros(n_levels, dtype=Division, device=dev)
        self.node_base = wp.empty(cap, dtype=wp.int32, device=dev)
        nc = self.node_cap
        self.node_start = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_depth = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_count = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_growth = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_parent = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_rank = wp.zeros(nc, dtype=wp.int32, device=dev)
        self.node_grown = wp.zeros(nc, dtype=wp.int32, device=dev)
        self.groups = wp.empty((n_levels, DEPTHS, int(self.node_caps.max())), dtype=wp.int32,
                               device=dev)
        fc = self.final_cap
        self.final_keys = wp.empty(2 * fc, dtype=wp.int64, device=dev)
        self.final_values = wp.empty(2 * fc, dtype=wp.int32, device=dev)
        self.moments = wp.empty((fc, 2), dtype=wp.int32, device=dev)
        self.kp_fields = wp.empty(5 * fc, dtype=wp.float32, device=dev)
        self.kp_octave = wp.empty(fc, dtype=wp.int32, device=dev)
        self.desc = wp.empty((fc, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        self.head = (wp.empty(C_NODES + n_levels, dtype=wp.int32, device="cpu",
                              pinned=dev.is_cuda))
        self.use_graph = bool(graph) and dev.is_cuda
        self.side = wp.Stream(dev) if dev.is_cuda else None
        self.graph = None
        self.runs = 0
        self.last_stream = None  # where the last frame's output copies were enqueued (CUDA)

    # -- the device program ---------------------------------------------------------------

    def stage_pyramid(self):
        scale_pyramid(self.levels[0], self.n_levels, self.params[1], out=self.levels)

    def stage_blur(self):
        blur_levels(self.levels, out=self.blurred_levels)

    def stage_detect(self):
        dev = self.device
        _, _, n_levels, ini_th, min_th = self.params
        self.counters.zero_()
        wp.launch(score_pixels, dim=self.n_pixels,
                  inputs=[wp.uint64(self.pyr.ptr), self.level_info, n_levels, self.row_of_y,
                          self.col_of_x, min(ini_th, min_th)],
                  outputs=[self.scores], device=dev)
        wp.launch(suppress_pixels, dim=self.n_pixels,
                  inputs=[self.level_info, n_levels, self.row_of_y, self.col_of_x, self.scores,
                          ini_th, self.cells_at, self.surv_region],
                  outputs=[self.counters, self.survivors], device=dev)
        wp.launch(select_candidates, dim=self.surv_cap,
                  inputs=[self.survivors, self.surv_region, self.level_info, self.roots, ini_th,
                          min_th, self.cells_at, self.cand_region, self.digits, self.root_bits],
                  outputs=[self.counters, self.cand, self.paths, self.sort_keys, self.order],
                  device=dev)

    def stage_quadtree(self):
        self.stage_sort()
        self.stage_nodes()
        self.stage_finals()

    def stage_sort(self):
        """Candidates sorted by quadtree path (fixed size: the padding goes last)."""
        dev = self.device
        wp.launch(pad_paths, dim=self.cand_cap,
                  inputs=[self.counters, self.surv_region, self.cand_region,
                          wp.int64((1 << self.sort_bits) - 1)],
                  outputs=[self.sort_keys], device=dev)
        wp.utils.radix_sort_pairs(self.sort_keys, self.order, self.cand_cap, 0, self.sort_bits)
        wp.launch(gather_paths, dim=self.cand_cap, inputs=[self.order, self.counters, self.paths],
                  outputs=[self.sorted_paths], device=dev)

    def stage_nodes(self):
        """Node counts per depth, DistributeOctTree's decisions, the second loop's order."""
        dev = self.device
        n_levels = self.n_levels
        cap = self.cand_cap
        wp.launch(count_depths, dim=cap,
                  inputs=[self.sorted_paths, self.counters, cap, self.digits, self.singles_at,
                          self.multis_at],
                  outputs=[self.lcp], device=dev)
        wp.launch(sum_depth_counts, dim=(n_levels, 2, DEPTHS),
                  inputs=[self.counters, self.singles_at, self.multis_at], outputs=[self.totals],
                  device=dev)
        wp.launch(plan_divisions, dim=n_levels, inputs=[self.level_info, self.totals],
                  outputs=[self.divisions], device=dev)
        wp.launch(alloc_nodes, dim=cap,
                  inputs=[self.sorted_paths, self.lcp, self.counters, cap, self.level_info,
                          self.divisions, self.groups_at],
                  outputs=[self.node_base, self.node_start, self.node_depth, self.node_count,
                           self.node_growth, self.groups], device=dev)
        wp.launch(link_nodes, dim=self.node_cap,
                  inputs=[self.level_info, n_levels, self.counters, self.divisions, self.lcp,
                          self.node_base, self.node_start, self.node_depth],
                  outputs=[self.node_parent], device=dev)
        self.node_rank.zero_()
        self.node_grown.zero_()
        wp.launch(rank_nodes, dim=(self.node_cap, RANK_CHUNKS),
                  inputs=[self.level_info, n_levels, self.counters, self.divisions,
                          self.sorted_paths, self.groups_at, self.groups, self.node_start,
                          self.node_depth, self.node_count, self.node_growth, self.node_parent],
                  outputs=[self.node_rank, self.node_grown], device=dev)

    def stage_finals(self):
        """The final list's nodes, their strongest points, sorted into the list order."""
        dev = self.device
        cap = self.cand_cap
        wp.launch(emit_finals, dim=cap,
                  inputs=[self.sorted_paths, self.order, self.lcp, self.cand, self.counters, cap,
                          self.level_info, self.divisions, self.node_base, self.node_rank,
                          self.node_grown, self.place_bits],
                  outputs=[self.final_keys, self.final_values], device=dev)
        wp.launch(pad_keys, dim=self.final_cap,
                  inputs=[self.counters, int(C_FINAL), wp.int64((1 << self.final_bits) - 1)],
                  outputs=[self.final_keys], device=dev)
        wp.utils.radix_sort_pairs(self.final_keys, self.final_values, self.final_cap, 0,
                                  self.final_bits)

    def stage_describe(self):
        dev = self.device
        self.moments.zero_()
        wp.launch(accumulate_moments, dim=(self.final_cap, spec.PATCH_SIZE),
                  inputs=[wp.uint64(self.pyr.ptr), self.level_info, self.counters,
                          self.final_values, self.cand],
                  outputs=[self.moments], device=dev)
        wp.launch(describe_levels, dim=(self.final_cap, spec.DESCRIPTOR_BYTES),
                  inputs=[wp.uint64(self.blurred.ptr), self.level_info, self.counters,
                          self.final_values, self.cand, self.moments, self.pattern],
                  outputs=[self.kp_fields, self.kp_octave, self.desc], device=dev)

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
        self.stage_describe()

    def launch(self):
        """Run the program: eagerly the first time (loads the modules), then from a graph."""
        if self.graph is not None:
            wp.capture_launch(self.graph)
            return
        if self.use_graph and self.runs > 0:
            try:
                with wp.ScopedCapture(device=self.device) as capture:
                    self.program()
                self.graph = capture.graph
            except Exception:  # noqa: BLE001 - e.g. inside a caller's capture: run eagerly
                self.use_graph = False
                self.program()
            else:
                wp.capture_launch(self.graph)
            return
        self.program()

    # -- one frame ------------------------------------------------------------------------

    def read_head(self) -> np.ndarray:
        """The counters the host needs (one sync): candidates, finals, overflow, nodes."""
        wp.copy(self.head, self.counters, count=self.head.shape[0])
        if self.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(self.device))
        return self.head.numpy().copy()

    def overflowed(self, head: np.ndarray) -> bool:
        return bool(head[C_OVER] != 0 or head[C_FINAL] > self.final_cap
                    or np.any(head[C_NODES:C_NODES + self.n_levels] > self.node_caps))

    def run(self, src):
        """Extract from ``src`` (uint8 HxW on the plan's device): (Keypoints, descriptors)."""
        if self.device.is_cuda:
            # On another stream than the last frame, wait for that frame's output copies.
            stream = wp.get_stream(self.device)
            if self.last_stream is not None and self.last_stream is not stream:
                stream.wait_stream(self.last_stream)
            self.last_stream = stream
        wp.copy(self.levels[0], src)
        self.launch()
        self.runs += 1
        head = self.read_head()
        if self.overflowed(head):
            n_features, scale_factor, _, ini_th, min_th = self.params
            return extract_host(self.levels, n_features, scale_factor, ini_th, min_th,
                                blurred=self.blurred_levels)
        return self.take_outputs(int(head[C_FINAL]))

    def take_outputs(self, n: int):
        """Fresh arrays holding the frame's n keypoints (the plan's buffers are reused)."""
        dev = self.device
        octave = wp.empty(n, dtype=wp.int32, device=dev)
        desc = wp.empty((n, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        if n == 0:
            rows = [wp.empty(0, dtype=wp.float32, device=dev) for _ in range(5)]
            return Keypoints(*rows, octave), desc
        fields = wp.empty((5, n), dtype=wp.float32, device=dev)
        wp.copy(fields, self.kp_fields, count=5 * n)
        wp.copy(octave, self.kp_octave, count=n)
        wp.copy(desc, self.desc, count=n * spec.DESCRIPTOR_BYTES)
        return Keypoints(x=fields[0], y=fields[1], response=fields[2], size=fields[3],
                         angle=fields[4], octave=octave), desc


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


