"""warpvx.cv.orb (see warpvx.cv)."""

__all__: list[str] = []
