"""Module-level callables for tests/runtime/test_processes.py: a worker process imports
them by name (spawn)."""

from __future__ import annotations

import os

import cv2
import numpy as np


def blur(img):
    """A 5x5 Gaussian blur (OpenCV, releases the GIL) and the process that ran it."""
    return cv2.GaussianBlur(img, (5, 5), 1.2), np.int64(os.getpid())


def fails(img):
    raise ValueError(f"bad frame of shape {img.shape}")


def dies(img):
    os._exit(3)


def unpicklable_result(img):
    return lambda: img  # a closure: does not pickle
