"""``python -m taichi_cloth``: the command line (``cli.py``)."""

import sys

from taichi_cloth.cli import main

sys.exit(main())
