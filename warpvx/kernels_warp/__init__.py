"""Warp implementations, one module per primitive (Warp compiles per module, so one
primitive's kernels compile once), named and called as in ``kernels_cpu``.

Each function takes ``wp.array``s on one device (already validated by the public function),
launches on the current device and stream (set by :func:`warpvx.registry.dispatch`), and
returns ``wp.array``s on that device. No function synchronises unless it must read a result
back to the host (noted in its docstring).
"""
