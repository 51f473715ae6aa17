"""argparse ``type=`` helpers shared by every verb (light: imports nothing heavy).

Each returns a parser that raises ``argparse.ArgumentTypeError`` with one clear
line, so bad usage exits 2 with argparse's message. :func:`check_output_file` and
:func:`check_output_folder` check where a verb will write before it starts its work
(:class:`~polycam.errors.InputError`: one line, exit 1).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Callable

from .errors import InputError

__all__ = ["number", "positive_int", "nonneg_int", "positive_float", "nonneg_float", "check_output_file",
           "check_output_folder"]


def number(kind: type, minimum: float, strict: bool = False, *, why: str = "") -> Callable[[str], float]:
    """A parser accepting a finite ``kind`` (int or float) >= ``minimum`` (> with ``strict``).

    ``why`` is appended to the range message, e.g. ``"PnP needs 6 corners"``.
    """
    what = "an integer" if kind is int else "a number"
    bound = f"{'>' if strict else '>='} {minimum:g}" + (f" ({why})" if why else "")

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not (v > minimum if strict else v >= minimum):
            raise argparse.ArgumentTypeError(f"expected {what} {bound}, got {text}")
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
        return v

    return parse


positive_int = number(int, 1)
nonneg_int = number(int, 0)
positive_float = number(float, 0.0, strict=True)
nonneg_float = number(float, 0.0)


def check_output_file(path: str | os.PathLike, option: str) -> None:
    """Raise :class:`~polycam.errors.InputError` naming ``option`` (e.g. ``--out``) and ``path``
    when a file cannot be written there: ``path`` is a folder, or its folder does not exist.
    Called before a verb's work, so that a long computation does not end in that error."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{option} {p}: is a folder; expected a file name")
    parent = p.parent
    if not parent.is_dir():
        raise InputError(f"{option} {p}: its folder {parent} does not exist")


def check_output_folder(path: str | os.PathLike, option: str) -> None:
    """Raise :class:`~polycam.errors.InputError` naming ``option`` and ``path`` when ``path``
    exists but is not a folder (the verb creates a missing one)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: exists and is not a folder")
