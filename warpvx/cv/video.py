"""warpvx.cv.video (see warpvx.cv)."""

__all__: list[str] = []
