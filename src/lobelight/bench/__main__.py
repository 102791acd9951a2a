"""``python -m lobelight.bench table RESULT.json``: the Markdown table of a ``lobelight bench
all`` record (:func:`lobelight.bench.table`)."""

import sys

from .suite import main

sys.exit(main())
