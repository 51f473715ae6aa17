"""argparse ``type=`` helpers shared by every verb (light: imports nothing heavy).

Each returns a parser that raises ``argparse.ArgumentTypeError`` with one clear
line, so bad usage exits 2 with argparse's message.
"""

from __future__ import annotations

import argparse
from typing import Callable

__all__ = ["number", "positive_int", "nonneg_int", "positive_float", "nonneg_float"]


def number(kind: type, minimum: float, strict: bool = False, *, why: str = "") -> Callable[[str], float]:
    """A parser accepting a ``kind`` (int or float) >= ``minimum`` (> with ``strict``).

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
        return v

    return parse


positive_int = number(int, 1)
nonneg_int = number(int, 0)
positive_float = number(float, 0.0, strict=True)
nonneg_float = number(float, 0.0)
