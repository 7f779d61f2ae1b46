"""``python -m warpvx.bench`` (same as ``warpvx bench``)."""

import sys

from .harness import main

sys.exit(main())
