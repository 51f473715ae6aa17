"""Strict TOML reading for the project's small config files (rig, board, grid, session).

Every value read through :class:`Table` is checked for type and range, and
unknown keys are reported, so a typo in a user's file becomes one clear line
(``FILE: [table].key: problem``) instead of a silently ignored setting.
"""

from __future__ import annotations

import errno
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from .errors import FormatError

__all__ = ["load_toml", "Table", "atomic_write_text", "atomic_write_bytes"]

_MISSING = object()


def load_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Parse a TOML file; a missing or malformed file raises :class:`FormatError`."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise FormatError(path, "no such file") from None
    except IsADirectoryError:
        raise FormatError(path, "is a directory, expected a TOML file") from None
    except UnicodeDecodeError:
        raise FormatError(path, "not UTF-8 text") from None
    except OSError as e:
        raise FormatError(path, f"cannot read ({e.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise FormatError(path, f"invalid TOML ({e})") from None


class Table:
    """A view on one TOML table that validates as it is read.

    ``name`` is how the table is shown in messages (``[grid]``, ``[[camera]] #2``).
    Call :meth:`finish` after reading to reject keys that were never asked for.
    """

    def __init__(self, path: str | os.PathLike, name: str, data: Any):
        self.path = Path(path)
        self.name = name
        if not isinstance(data, dict):
            raise FormatError(path, f"expected a table, got {_typename(data)}", name)
        self.data = data
        self._seen: set[str] = set()

    def error(self, key: str | None, problem: str) -> FormatError:
        if key is None:
            field = self.name or None
        else:
            field = f"{self.name}.{key}" if self.name else key
        return FormatError(self.path, problem, field)

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = _MISSING) -> Any:
        """Value of ``key`` checked to be of ``kind``; required unless a default is given."""
        self._seen.add(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(key, "missing")
            return default
        value = self.data[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if isinstance(value, bool) and bool not in kinds:
            raise self.error(key, f"expected {_kindname(kinds)}, got a boolean")
        if not isinstance(value, kinds):
            raise self.error(key, f"expected {_kindname(kinds)}, got {_typename(value)} {value!r}")
        return value

    def number(self, key: str, default: Any = _MISSING, *, min: float | None = None,
               max: float | None = None, integer: bool = False, open_min: bool = False) -> Any:
        """A finite number within ``[min, max]`` (``(min, max]`` with ``open_min``)."""
        value = self.get(key, int if integer else float, default)
        if value is default and key not in self.data:
            return value
        if not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value}")
        if min is not None and (value < min or (open_min and value == min)):
            raise self.error(key, f"must be {'>' if open_min else '>='} {min}, got {value}")
        if max is not None and value > max:
            raise self.error(key, f"must be <= {max}, got {value}")
        return value

    def choice(self, key: str, choices: tuple[str, ...], default: Any = _MISSING) -> Any:
        value = self.get(key, str, default)
        if key in self.data and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def vector(self, key: str, n: int | None, default: Any = _MISSING, *, integer: bool = False) -> Any:
        """A list of ``n`` numbers (any length if ``n`` is None)."""
        value = self.get(key, list, default)
        if key not in self.data:
            return value
        kind = int if integer else (int, float)
        if (n is not None and len(value) != n) or not all(
            isinstance(v, kind) and not isinstance(v, bool) and math.isfinite(v) for v in value
        ):
            what = f"a list of {n} " if n is not None else "a list of "
            raise self.error(key, f"expected {what}{'integers' if integer else 'finite numbers'}, got {value!r}")
        return [v if integer else float(v) for v in value]

    def subtable(self, key: str, default: Any = _MISSING) -> "Table | Any":
        self._seen.add(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(key, "missing table")
            return default
        return Table(self.path, f"{self.name}.{key}" if self.name else f"[{key}]", self.data[key])

    def finish(self) -> None:
        """Raise on the first key that was not read (an unknown key)."""
        for key in self.data:
            if key not in self._seen:
                raise self.error(key, "unknown key")


def _typename(v: Any) -> str:
    return {dict: "a table", list: "a list", str: "a string", int: "an integer",
            float: "a number", bool: "a boolean"}.get(type(v), type(v).__name__)


def _kindname(kinds: tuple[type, ...]) -> str:
    names = {dict: "a table", list: "a list", str: "a string", int: "an integer",
             float: "a number", bool: "a boolean"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename.

    A reader never sees a half-written file; a crash leaves at most a
    ``.tmp-*`` file beside it.
    """
    path = Path(path)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    if not path.parent.is_dir():         # name the file asked for, not the temporary one
        raise FileNotFoundError(errno.ENOENT, f"its folder {path.parent} does not exist", str(path))
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))
