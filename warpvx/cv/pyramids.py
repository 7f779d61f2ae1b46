"""warpvx.cv.pyramids (see warpvx.cv)."""

__all__: list[str] = []
