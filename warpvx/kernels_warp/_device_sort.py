"""Sorting a device-counted key buffer without reading the count back.

``wp.utils.radix_sort_pairs`` takes its element count from the host. A captured kernel
sequence cannot read a count the kernels before it produced, so corner detectors sort their
whole key buffer, the keys after the count set to a sentinel that sorts last. Their capacity
(every pixel for Harris candidates, every 2x2 block for FAST maxima) is far above what real
frames hold, so :class:`CountedSort` sorts only the first :data:`SMALL` keys when the device
count fits there, the whole capacity otherwise: a conditional node (``wp.capture_if``) decided
on the device, outside a capture a host read of the flag.
"""

from __future__ import annotations

import warp as wp

from ._launch import Recorded

wp.set_module_options({"enable_backward": False})

#: Keys sorted when the count fits (a power of two: a few times what a real frame holds).
SMALL = 1 << 15


@wp.kernel
def fits_small(count: wp.array(dtype=wp.int32), small: int, flag: wp.array(dtype=wp.int32)):
    """flag[0] = 1 when count[0] <= small."""
    flag[0] = wp.where(count[0] <= small, 1, 0)


class CountedSort:
    """``radix_sort_pairs(keys, values, n, 0, end_bit)`` with ``n`` = :data:`SMALL` when
    ``count[0]`` (int32 [1], device) is at most that, else ``capacity``; keys past the count
    must already sort last (sentinels) up to ``capacity``. ``keys`` and ``values`` hold
    ``2 * capacity`` (the upper half is the sort's scratch).

    Warp keeps the sort's scratch per stream and reallocates it for a larger sort, which must
    not happen inside a capture: the constructor sorts the whole capacity once (on the
    current stream, the one a capture will use) to reserve it.
    """

    def __init__(self, keys, values, count, capacity: int, end_bit: int):
        self.keys, self.values, self.capacity, self.end_bit = keys, values, int(capacity), end_bit
        self.small = min(SMALL, self.capacity)
        self.flag = wp.zeros(1, dtype=wp.int32, device=keys.device)
        self.decide = Recorded(fits_small, 1, keys.device, count=count, small=self.small,
                               flag=self.flag)
        self._sort_all()

    def launch(self, count=None):
        """Sort (``count``: another device count buffer than the constructor's)."""
        if self.small == self.capacity:
            self._sort_all()
            return
        self.decide.launch(**({} if count is None else {"count": count}))
        wp.capture_if(self.flag, on_true=self._sort_small, on_false=self._sort_all)

    def _sort_small(self):
        wp.utils.radix_sort_pairs(self.keys, self.values, self.small, 0, self.end_bit)

    def _sort_all(self):
        wp.utils.radix_sort_pairs(self.keys, self.values, self.capacity, 0, self.end_bit)


__all__ = ["CountedSort", "SMALL"]
