"""warpvx.cv.imgproc (see warpvx.cv)."""

__all__: list[str] = []
