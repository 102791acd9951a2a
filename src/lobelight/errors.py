"""Errors raised at lobelight's public doors.

Every problem with user input (a file, a parameter, an array) is reported as one
:class:`InputError` whose message names the input and the problem, so that the CLI can print
it as a single line and exit with a documented code instead of a traceback.
"""

from __future__ import annotations

__all__ = ["InputError", "LobelightError", "Terminated", "one_line", "os_problem", "shorten"]

#: The longest name or problem an error message quotes in full: a longer one (a million-element
#: argument, a file's whole line) keeps its head and tail (:func:`shorten`).
MAX_QUOTED = 2000


class LobelightError(Exception):
    """Base class of every error lobelight raises on purpose."""


class Terminated(BaseException):
    """SIGTERM arrived (a batch scheduler pre-empting the job): raised by the command line's
    signal handler and unwound like :class:`KeyboardInterrupt`, so that ``finally`` blocks and
    checkpoints run. Not an :class:`Exception`, so that no reader's ``except Exception`` takes
    it for a bad input."""


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
        self.what = shorten(one_line(str(what)), 4 * MAX_QUOTED)  # a whole path (PATH_MAX 4096)
        self.problem = shorten(one_line(str(problem)))
        super().__init__(f"{self.what}: {self.problem}")


def one_line(text: str) -> str:
    """``text`` with every non-printable character (a line break, a terminal escape) written as
    its escape sequence."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def os_problem(e: OSError) -> str:
    """An OSError's reason in the words of an error line (``file name too long``)."""
    return (e.strerror or str(e)).lower()


def shorten(text: str, limit: int = MAX_QUOTED) -> str:
    """``text`` if it has at most ``limit`` characters, else its head and tail around a note of
    how many characters were left out."""
    if len(text) <= limit:
        return text
    keep = max(limit // 2, 1)
    return f"{text[:keep]}... ({len(text) - 2 * keep:,} characters left out) ...{text[-keep:]}"
