"""Nearest descriptor rows between consecutive frames of a batch, both ways, in one launch.

The frames' 256-bit descriptors lie one frame after the other in one uint8 [T, 32] array (frame
f owns rows ``starts[f]`` to ``starts[f + 1]``). ``find_nearest_chain`` runs a thread per (row,
direction): direction 0 finds the row's nearest row of the frame before, direction 1 of the
frame after (the "back" rows a cross-check reads). Keys are (distance << 32 | index) as in
:mod:`.match_hamming` (``pair_key``): the smaller distance wins, then the lower index (cv2's
batchDistance tie rule), so the results equal ``knn_match_hamming(k=1)`` of each pair. Indices
are local to the other frame; -1 (distance 0) where that frame is missing or empty.
"""

from __future__ import annotations

import warp as wp

from ._launch import view
from .match_hamming import NONE_KEY, pair_key

wp.set_module_options({"enable_backward": False})

WORDS = 8  # uint32 words of a 32-byte descriptor


@wp.func
def frame_of(row: int, starts: wp.array(dtype=wp.int32)) -> int:
    """The frame owning ``row`` (frames are few: a linear scan)."""
    f = int(0)
    while starts[f + 1] <= row:
        f += 1
    return f


@wp.kernel
def find_nearest_chain(words: wp.array2d(dtype=wp.uint32), starts: wp.array(dtype=wp.int32),
                       nearest: wp.array2d(dtype=wp.int32), distance: wp.array2d(dtype=wp.int32)):
    """nearest[d, r], distance[d, r]: row r's nearest row of the frame before (d = 0) or after
    (d = 1), as a local index, and its Hamming distance."""
    d, r = wp.tid()
    f = frame_of(r, starts)
    other = f - 1 + 2 * d
    nearest[d, r] = -1
    distance[d, r] = 0
    if other < 0 or other >= starts.shape[0] - 1:
        return
    q = wp.vector(length=WORDS, dtype=wp.uint32)
    for w in range(WORDS):
        q[w] = words[r, w]
    t0 = starts[other]
    best = NONE_KEY
    for t in range(t0, starts[other + 1]):
        h = int(0)
        for w in range(WORDS):
            h += int(wp.bit_count(q[w] ^ words[t, w]))
        best = wp.min(best, pair_key(h, t - t0))
    if best != NONE_KEY:
        nearest[d, r] = int(best & wp.int64(0xFFFFFFFF))
        distance[d, r] = int(best >> wp.int64(32))


def nearest_chain(desc, starts):
    """Nearest rows both ways between consecutive frames (see the module docstring).

    Parameters
    ----------
    desc : wp.array uint8 [T, 32], C-contiguous
        The frames' descriptors, one frame after the other.
    starts : wp.array int32 [F + 1]
        Frame f's rows are ``starts[f]:starts[f + 1]`` (``starts[0] = 0``, ``starts[F] = T``).

    Returns
    -------
    nearest, distance : int32 [2, T]
        Row 0: each row's nearest row of the frame before; row 1: of the frame after.
    """
    rows = desc.shape[0]
    nearest = wp.empty((2, rows), dtype=wp.int32, device=desc.device)
    distance = wp.empty((2, rows), dtype=wp.int32, device=desc.device)
    if rows:
        # A row of 32 bytes read as 8 words (the array starts 4-byte aligned: Warp allocations).
        words = view(desc, wp.uint32, (rows, WORDS), (desc.strides[0], 4))
        wp.launch(find_nearest_chain, dim=(2, rows), inputs=[words, starts],
                  outputs=[nearest, distance], device=desc.device)
    return nearest, distance


__all__ = ["nearest_chain"]
