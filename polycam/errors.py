"""Errors that polycam reports to a user as one line.

Library code raises :class:`PolycamError` (or a subclass) for anything a user
can fix: a bad file, a bad argument, input the algorithms cannot use. The CLI
prints ``str(error)`` on one line and exits with status 1; any other exception
is a bug and keeps its traceback (the evo convention).
"""

from __future__ import annotations

from os import PathLike

__all__ = ["PolycamError", "FormatError", "InputError"]


class PolycamError(Exception):
    """A user-facing error; its message is one line."""


class FormatError(PolycamError):
    """A file does not follow its format (SPEC.md).

    The message names the file, the field (if any) and the problem:
    ``rigs/a.toml: [grid].rows: expected an integer >= 1, got "x"``.
    """

    def __init__(self, path: str | PathLike, problem: str, field: str | None = None):
        self.path = str(path)
        self.field = field
        self.problem = problem
        where = f"{self.path}: {field}: " if field else f"{self.path}: "
        super().__init__(where + problem)


class InputError(PolycamError):
    """Input that is well formed but cannot be used (e.g. one frame where two are needed)."""
