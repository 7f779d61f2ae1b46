"""``python -m warpvx``: the ``warpvx`` command (see :mod:`warpvx.cli`)."""

import sys

from .cli import main

sys.exit(main())
