"""Errors raised at lobelight's public doors.

Every problem with user input (a file, a parameter, an array) is reported as one
:class:`InputError` whose message names the input and the problem, so that the CLI can print
it as a single line and exit with a documented code instead of a traceback.
"""

from __future__ import annotations

__all__ = ["InputError", "LobelightError", "one_line"]


class LobelightError(Exception):
    """Base class of every error lobelight raises on purpose."""


class InputError(LobelightError, ValueError):
    """Bad input: names the input (a path, a parameter) and what is wrong with it.

    Parameters
    ----------
    what : str
        The input, e.g. a file path or ``"lam"``.
    problem : str
        What is wrong, in words a user can act on.
    """

    def __init__(self, what: str, problem: str):
        # names and values quoted from the input may hold line breaks or other control
        # characters: escaped, so that the message stays one line
        self.what = one_line(str(what))
        self.problem = one_line(str(problem))
        super().__init__(f"{self.what}: {self.problem}")


def one_line(text: str) -> str:
    """``text`` with every non-printable character (a line break, a terminal escape) written as
    its escape sequence."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
