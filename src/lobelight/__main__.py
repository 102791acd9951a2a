"""``python -m lobelight ...``: the same as ``lobelight ...``."""

import sys

from .cli import main

sys.exit(main())
