"""Progress of long jobs, for every user: bars on a terminal, plain lines everywhere else.

Long calls (a bake, a reference render, a turntable) take ``progress=``:

- ``True`` (the default of the public entry points): a :class:`Reporter` on stderr;
- ``None`` or ``False``: silent;
- any callable ``progress(stage: str, done: int, total: int)``: called after each chunk of
  work, with ``done == total`` when a stage ends. A stage whose total is only a bound
  (:attr:`Reporter.AT_MOST`: the Gaussians' reordering, which stops when a sweep gains nothing)
  ends with ``done == total`` at the count it reached.

:func:`resolve` turns the argument into a callable or None. A :class:`Reporter` draws tqdm bars
when its stream is a terminal; on a file, a pipe or a CI log it writes one line when a stage
starts, at most one every ``interval`` seconds while it runs, and one when it ends, so a batch job
is never silent for long and its log stays short.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import ClassVar, TextIO

from tqdm import tqdm

__all__ = ["ProgressFn", "Reporter", "resolve"]

ProgressFn = Callable[[str, int, int], None]


class Reporter:
    """``progress(stage, done, total)`` as bars on a terminal or plain lines on other streams.

    Parameters
    ----------
    stream : where to write (default ``sys.stderr``, looked up at each call so that a test or a
        caller may redirect it)
    interval : seconds between two plain lines of one stage
    bars : draw tqdm bars (default: when the stream is a terminal)
    """

    #: what a stage counts, when not chunks of work
    UNITS: ClassVar[dict[str, str]] = {
        "frames": "frame", "turntable": "frame", "lobe tables": "fit", "reference": "spp",
        "reference, glossy": "spp", "reorder": "sweep",
    }  # fmt: skip
    #: units whose plural is the word itself (samples per pixel)
    SAME_PLURAL: ClassVar[frozenset[str]] = frozenset({"spp"})
    #: stages whose total is only a bound (they may end sooner, their last call ``done ==
    #: total`` with the count they reached): no share or time left is estimated for them
    AT_MOST: ClassVar[frozenset[str]] = frozenset({"reorder"})

    def __init__(
        self, stream: TextIO | None = None, *, interval: float = 5.0, bars: bool | None = None
    ):
        self._stream = stream
        self.interval = float(interval)
        self._bars_flag = bars
        self._bars: dict[str, tqdm] = {}
        self._started: dict[str, float] = {}
        self._last: dict[str, float] = {}

    @property
    def stream(self) -> TextIO:
        return self._stream if self._stream is not None else sys.stderr

    def _use_bars(self) -> bool:
        if self._bars_flag is not None:
            return self._bars_flag
        isatty = getattr(self.stream, "isatty", None)
        return bool(isatty and isatty())

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self._use_bars():
            self._bar(stage, done, total)
        else:
            self._line(stage, done, total)

    def note(self, text: str) -> None:
        """One line of context (what is about to happen), on any stream."""
        print(f"lobelight: {text}", file=self.stream, flush=True)

    def _bar(self, stage: str, done: int, total: int) -> None:
        bar = self._bars.get(stage)
        if bar is None:
            unit = self.UNITS.get(stage, "chunk")
            bar = self._bars[stage] = tqdm(
                total=total, desc=stage, unit=unit, leave=False, file=self.stream
            )
        bar.n = done
        bar.refresh()
        if done >= total:
            bar.close()
            del self._bars[stage]

    def _line(self, stage: str, done: int, total: int) -> None:
        now = time.monotonic()
        start = self._started.setdefault(stage, now)
        first = stage not in self._last
        end = done >= total
        if not (first or end or now - self._last[stage] >= self.interval):
            return
        self._last[stage] = now
        unit = self.UNITS.get(stage, "chunk")
        units = unit if unit in self.SAME_PLURAL else unit + "s"
        elapsed = now - start
        bound = stage in self.AT_MOST
        if bound:
            count = f"{done} {units}" if end else f"{unit} {done} of at most {total}"
            text = f"lobelight: {stage}: {count}"
        else:
            text = f"lobelight: {stage}: {done}/{total} {units}"
        if total > 0 and not bound:
            text += f" ({100 * done / total:.0f} %)"
        if end:
            text += f", done in {elapsed:.1f} s"
            del self._started[stage], self._last[stage]
        elif bound:
            text += f", {elapsed:.0f} s elapsed" if elapsed > 0 else ""
        elif done > 0 and elapsed > 0:
            left = elapsed * (total - done) / done
            text += f", {elapsed:.0f} s elapsed, about {left:.0f} s left"
        print(text, file=self.stream, flush=True)


def resolve(progress) -> ProgressFn | None:
    """The callable a ``progress=`` argument stands for (module docstring), or None."""
    if progress is None or progress is False:
        return None
    if progress is True:
        return Reporter()
    if callable(progress):
        return progress
    raise TypeError(
        f"progress must be True, False, None or a callable (stage, done, total), got {progress!r}"
    )
