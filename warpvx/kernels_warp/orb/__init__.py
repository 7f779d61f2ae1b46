"""ORB-SLAM2's ORB extractor on Warp, the quadtree included (stages as :mod:`warpvx._orb_spec` defines them).

:func:`orb` runs every stage on the device with fixed shapes, so on CUDA the whole extractor is
one captured graph per image size and parameter set (a *plan*: buffers and graph cached, a pool
of them so concurrent calls never share one). The one host sync reads the keypoint count.
All levels go through each kernel together: the pyramid and its blurred copy live in two flat
buffers, a per-level table gives each level's offset, size and cell grid. So do all images of a
batch (equal-sized frames, e.g. a multi-camera rig): every kernel's first thread index runs
over the batch's items image by image (a batch of one launches as the one-image extractor
did), per-image buffers have a leading batch index, the pyramids are level-major (level l of
every image in one [B * h_l, w_l] block, resized and blurred in one launch), the two radix sorts
sort the whole batch with the image above each key, the host reads all images' counts in one
copy and takes all images' keypoints out in one copy per output; each image's result is bit
for bit what it gives alone.

Stages (one launch each unless said):

``stage_pyramid``, ``stage_blur``  ``kernels_warp.scale_pyramid``'s resize kernel (its row
    taps offset per image) and the shared fused Gaussian filter (7x7, sigma 2,
    BORDER_REFLECT_101) into the flat buffers, one launch per level; for a batch,
    ``blur_edge_rows`` redoes the 3 rows at each image's top and bottom. On CUDA the blur runs
    on a side stream, beside detection and the quadtree.
``score_pixels``  FAST-9/16 scores at the lower threshold on the pixels a 30x30 cell owns
    (``fast_corners.fast_score``).
``suppress_pixels``  OpenCV's strict 3x3 maximum *within the cell* (ORB-SLAM2 runs FAST per
    cell: a neighbour in another cell counts as 0); survivors appended to 32 striped lists,
    and a count per cell of those >= iniThFAST.
``select_candidates``  the per-cell rule (iniThFAST when the cell has such a point, else
    minThFAST); each kept point gets its quadtree path (the root column, then the quadrant of
    every division as ``DivideNode`` splits, 16 levels deep: distinct pixels always part).
``pad_paths``, radix sort, ``gather_paths``  points sorted by path (a key of as few bits as
    the image size needs): every quadtree node at depth d is then a run of points sharing d
    digits.
``count_depths``, ``sum_depth_counts``  per point, the depth it shares with each neighbour
    (``lcp``); per level and depth, the nodes holding one point and more than one.
``plan_divisions``  ``DistributeOctTree`` decided from those counts alone (one thread a level):
    the pass K where its first loop stops, and, when it goes on dividing largest nodes first,
    the depth g* of its last round and whether that round stops part way.
``alloc_nodes``, ``link_nodes``, ``rank_nodes``  the nodes of the rounds that divide largest
    first, ordered as ORB-SLAM2 walks them (size, then creation order; each node compared with
    its (level, depth) group by 32 threads), and the nodes added before each one's turn, which
    decide where the last round stops.
``emit_finals``  each node left in the final list, its strongest point (the first in ORB-SLAM2's
    candidate order on a tie) and a key giving the node's place in the list; radix sort.
``gather_heads``, ``accumulate_moments``, ``describe_levels``  the counts the host reads and
    where each image's keypoints start in the batch's packed outputs; ``IC_Angle`` (a thread
    per disc row, integer atomics), then rotated BRIEF and the level-0 fields, packed image
    after image. After the sync, one copy per output takes them out, each image's results
    being views of its rows.

Why the node list order has a closed form: a pass of the first loop puts the children of the
nodes it divides in front, in reverse; so after pass k the nodes created at depth k come first,
ordered by their path with alternating directions (``flipped_prefix``), then the single-point
nodes of earlier passes, newest pass first. A round of the second loop divides the nodes of one
depth, ordered by (size, creation order) descending; its children again go in front in
reverse. Every division is known from the node counts per depth, so each final node's place
is a sort key, and the result equals the sequential algorithm (checked against
:func:`warpvx._orb_quadtree.distribute_octtree` on real and random point sets).

Capacities (candidates, nodes, final nodes) are sized for real images; when a frame exceeds
one (e.g. pure noise), that frame takes :func:`.host.extract_host`, the same stages with the quadtree
on the host (``_orb_quadtree.distribute_octtree``), so results never depend on capacity.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ... import _orb_spec as spec
from ...keypoints import Keypoints
from .funcs import C_CAND, C_FINAL
from .host import (_pattern_on, blur_levels, build_pyramid, compute_descriptors,
                   compute_orientation, describe_keypoints, detect_and_select, distribute,
                   orb_host_quadtree, scale_back)
from .plan import OrbPlan, acquire, release


def orb(src, n_features: int, scale_factor: float, n_levels: int, ini_th_fast: int,
        min_th_fast: int, *, out=None):
    """ORB-SLAM2's extractor on the device of ``src``: (Keypoints of device arrays,
    uint8 [N, 32]); for a batch (a uint8 [B, H, W] array or a list of B equal-sized HxW
    images, one device) a list of B such pairs, each what the image alone gives.

    Every stage, the quadtree included, runs on the device for the whole batch at once (on
    CUDA as one captured graph per device, size, parameters and batch size, cached); the host
    syncs once to read the keypoint counts. ``out`` must be None (UnsupportedError otherwise:
    the count is data-dependent).
    """
    spec.refuse_out(out)
    batched = isinstance(src, (list, tuple)) or src.ndim == 3
    first = src[0] if isinstance(src, (list, tuple)) else src
    batch = (len(src) if isinstance(src, (list, tuple)) else int(src.shape[0])) if batched else 1
    device = first.device
    h, w = int(first.shape[-2]), int(first.shape[-1])
    key = (str(device), h, w, int(n_features), float(scale_factor), int(n_levels),
           int(ini_th_fast), int(min_th_fast), batch)
    plan = acquire(key, lambda: OrbPlan(device, h, w, int(n_features), float(scale_factor),
                                      int(n_levels), int(ini_th_fast), int(min_th_fast),
                                      batch=batch))
    try:
        results = plan.run(src)
    finally:
        release(key, plan)
    return results if batched else results[0]


def orb_compute(src, keypoints: Keypoints, scale_factor: float, n_levels: int, *, out=None):
    """uint8 [N, 32] descriptors of given keypoints (level-0 coordinates, octave, angle).

    The octaves are read on the host (to group the launches per level), one sync. Written into
    ``out`` (uint8 [N, 32] on ``src.device``) when given.
    """
    device = src.device
    kp = keypoints.to(str(device))
    n = len(kp)
    desc = out if out is not None else wp.zeros((n, spec.DESCRIPTOR_BYTES), dtype=wp.uint8,
                                                device=device)
    if n == 0:
        return desc
    octave = kp.octave.numpy()
    pyramid = build_pyramid(src, scale_factor, n_levels)
    blurred = blur_levels(pyramid)
    inv = np.float32(1.0) / spec.level_scales(scale_factor, n_levels)
    pat = _pattern_on(str(device))
    for level in np.unique(octave):
        idx = np.flatnonzero(octave == level).astype(np.int32)
        index = wp.array(idx, dtype=wp.int32, device=device)
        wp.launch(describe_keypoints, dim=(idx.size, spec.DESCRIPTOR_BYTES),
                  inputs=[blurred[level], kp.x, kp.y, kp.angle, index, float(inv[level]), pat],
                  outputs=[desc], device=device)
    return desc



__all__ = ["orb", "orb_compute", "orb_host_quadtree", "OrbPlan", "build_pyramid", "detect_and_select",
           "distribute", "compute_orientation", "blur_levels", "compute_descriptors", "scale_back",
           "C_CAND", "C_FINAL"]
