"""``python -m cuboidlib ...``: the same as the ``cuboidlib`` command."""

import sys

from .cli import main

sys.exit(main())
