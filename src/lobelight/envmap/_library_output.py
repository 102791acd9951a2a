"""What C and C++ libraries print while we call them, kept off our stdout and stderr.

OpenEXR's reader, for one, prints a warning on the process's stdout (file descriptor 1) when a
file is cut short, and another on stderr, before our own one-line error: under ``--json`` that
corrupts the JSON. :func:`library_output` points descriptors 1 and 2 at a temporary file for
the duration of a call and hands back the lines written there, so the caller can fold them into
its one line.
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout

__all__ = ["library_output"]


@contextmanager
def library_output() -> Iterator[list[str]]:
    """Capture descriptors 1 and 2 (C and C++ writes) and ``sys.stdout``/``sys.stderr``
    (Python writes, which need not go to those descriptors: a binding that prints through
    Python, under a test runner's capture) inside the block.

    Yields a list that holds the captured lines, stripped and without blank ones, once the
    block has ended (also when it raises).
    """
    lines: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        stream.flush()  # what we printed before goes where it belongs
    saved = (os.dup(1), os.dup(2))
    try:
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            py = io.StringIO()
            try:
                with redirect_stdout(py), redirect_stderr(py):
                    yield lines
            finally:
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                tmp.seek(0)
                text = tmp.read().decode("utf-8", errors="replace") + py.getvalue()
                lines.extend(s.strip() for s in text.splitlines() if s.strip())
    finally:
        for fd in saved:
            os.close(fd)
