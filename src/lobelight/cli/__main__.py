"""``python -m lobelight.cli ...``: the same as ``lobelight ...``."""

import sys

from . import main

sys.exit(main())
