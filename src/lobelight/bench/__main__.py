"""``python -m lobelight.bench table RESULT.json``: the Markdown table of a ``lobelight bench
all`` record (:func:`lobelight.bench.table`); ``python -m lobelight.bench start [VERTICES
[RUNS]]``: :func:`lobelight.bench.bench_start`'s record as JSON."""

import json
import sys

from .start import bench_start
from .suite import main

if sys.argv[1:2] == ["start"]:
    numbers = [int(a) for a in sys.argv[2:4]]
    options = dict(zip(("vertices", "runs"), numbers, strict=False))
    print(json.dumps(bench_start(**options), indent=2))
    sys.exit(0)
sys.exit(main())
