"""``python -m lobelight.studies.gallery ...``: the same as ``lobelight gallery ...``."""

import sys

from ...cli import main

sys.exit(main(["gallery", *sys.argv[1:]]))
