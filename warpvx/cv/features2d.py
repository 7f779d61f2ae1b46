"""warpvx.cv.features2d (see warpvx.cv)."""

__all__: list[str] = []
