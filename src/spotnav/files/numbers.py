"""Numbers read from text: a field is checked to be a number before it is converted, so that none is refused late.

The fields of spotnav's CSV files, of its JSON truth and of Linux's ``/proc`` are text. :func:`parse_float` and
:func:`parse_int` give what Python's ``float()`` and ``int()`` make of one, or None where those would refuse it (a
regex of the numbers they read says which); :func:`json_floats` gives what ``np.array(value, dtype=float)`` makes of
a JSON value, or None where that would refuse it.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = ["json_floats", "parse_float", "parse_int"]

_DIGITS = r"\d(?:_?\d)*"  # digits, single underscores between them (\d: any Unicode digit, as float() and int())
_FLOAT = re.compile(
    rf"\s*[+-]?(?:(?:{_DIGITS}(?:\.(?:{_DIGITS})?)?|\.{_DIGITS})(?:e[+-]?{_DIGITS})?|inf(?:inity)?|nan)\s*",
    re.IGNORECASE,
)
_INT = re.compile(rf"\s*[+-]?{_DIGITS}\s*")


def parse_float(text: str | None) -> float | None:
    """``float(text)``, or None where ``text`` is None or not a number ``float()`` reads."""
    if text is None or _FLOAT.fullmatch(text) is None:
        return None
    return float(text)


def parse_int(text: str | None) -> int | None:
    """``int(text)``, or None where ``text`` is None or not a whole number ``int()`` reads."""
    if text is None or _INT.fullmatch(text) is None:
        return None
    return int(text)


def json_floats(value: object) -> np.ndarray | None:
    """``np.array(value, dtype=float)`` of a parsed JSON value, or None where a part of it is neither a number, a
    number's text nor null (a table, a word), or its lists are of unequal shapes."""
    if isinstance(value, list):
        items = [json_floats(item) for item in value]
        if any(item is None for item in items) or len({item.shape for item in items}) > 1:  # type: ignore[union-attr]
            return None
        return np.array(items, dtype=float)
    if isinstance(value, str):
        number = parse_float(value)
        return None if number is None else np.array(number)
    if value is None or isinstance(value, int | float):
        return np.array(value, dtype=float)
    return None
