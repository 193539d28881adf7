"""The one error hierarchy of gazehdr: what it raises on purpose, apart from its bugs.

Every deliberate refusal (bad input, a missing extra, a busy server) is a `GazehdrError`, and
bad input from outside (a file, a message, an option, a parameter) is an `InputError`, which is
also a `ValueError` so that callers' `except ValueError` keep working. The command line prints
these as one line saying what is wrong; anything else that escapes is a bug, shown with its
traceback and how to report it (`gazehdr.cli`).
"""

from __future__ import annotations


class GazehdrError(Exception):
    """A deliberate refusal; its message says what is wrong and, where it can, what to do."""


class InputError(GazehdrError, ValueError):
    """Input from outside that gazehdr cannot take: the message names what was wrong."""
