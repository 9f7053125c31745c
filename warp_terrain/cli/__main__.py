"""``python -m warp_terrain.cli``: the same as the ``warp-terrain`` command."""

import sys

from . import main

sys.exit(main())
