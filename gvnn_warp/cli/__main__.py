"""``python -m gvnn_warp.cli ...``: the same as ``gvnn-warp ...``."""

import sys

from . import main

sys.exit(main())
