"""Errors raised at lobelight's public doors.

Every problem with user input (a file, a parameter, an array) is reported as one
:class:`InputError` whose message names the input and the problem, so that the CLI can print
it as a single line and exit with a documented code instead of a traceback.
"""

from __future__ import annotations

__all__ = ["InputError", "LobelightError"]


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
        self.what = str(what)
        self.problem = problem
        super().__init__(f"{self.what}: {problem}")
