"""``python -m lobelight.gallery {list,references,run}`` (:func:`lobelight.gallery.main`)."""

import sys

from ._cli import main

sys.exit(main())
