"""NumPy/OpenCV implementations, one module per primitive, named as in ``kernels_warp``.

Each function takes host NumPy arrays (already validated by the public function) and an
``out=`` array or None, and returns NumPy arrays.
"""
