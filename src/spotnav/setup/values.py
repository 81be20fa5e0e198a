"""Checking one setup value: the error a bad value raises, and the checks every section's dataclass runs.

A setup value is checked as it is built: :func:`number`, :func:`integer`, :func:`vector3` and :func:`matrix3` check
its type, :func:`in_range` its range, each raising :class:`SetupError` with a one-line message that names the TOML
key and the allowed range. The frozen dataclasses of the setup also share :func:`read_only` for their derived arrays
and :func:`hash_once` and :func:`state_without_hash` for a hash kept after its first use.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import numpy as np

from spotnav.errors import SpotnavError

__all__ = [
    "SetupError",
    "hash_once",
    "in_range",
    "integer",
    "matrix3",
    "number",
    "read_only",
    "state_without_hash",
    "vector3",
]


class SetupError(SpotnavError):
    """A setup value is missing, of the wrong type or out of range."""


def read_only(array: np.ndarray) -> np.ndarray:
    """``array``, marked read-only: a setup's derived arrays are computed once and shared."""
    array.setflags(write=False)
    return array


def hash_once(self: Any) -> int:
    """A frozen dataclass's hash, of its fields, computed on first use and kept: the per-setup (and per-camera)
    caches ask for it on every frame, and hashing walks every value of the setup anew."""
    kept: int | None = self.__dict__.get("_hash")
    if kept is None:
        kept = self.__dict__["_hash"] = hash(tuple(getattr(self, f.name) for f in fields(self)))
    return kept


def state_without_hash(self: Any) -> dict[str, Any]:
    """A frozen dataclass's pickled state, without the kept hash: a string's hash differs between processes."""
    return {name: value for name, value in self.__dict__.items() if name != "_hash"}


def number(key: str, value: Any) -> float:
    """``value`` as a float: a number (not a bool) and finite, else :class:`SetupError` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SetupError(f"{key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise SetupError(f"{key} must be finite, got {value!r}")
    return float(value)


def integer(key: str, value: Any) -> int:
    """``value``, an integer (not a bool), else :class:`SetupError` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise SetupError(f"{key} must be an integer, got {value!r}")
    return value


def in_range(
    key: str,
    value: float,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    """:class:`SetupError` naming ``key`` and the allowed range unless ``value`` is in it (``*_open``: the bound
    itself is not)."""
    below = low is not None and (value <= low if low_open else value < low)
    above = high is not None and (value >= high if high_open else value > high)
    if below or above:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        raise SetupError(f"{key} = {value:g} is out of range, allowed {left}{lo}, {hi}{right}")


def vector3(key: str, value: Any) -> tuple[float, float, float]:
    """``value``, a list of 3 numbers, as a tuple of floats, else :class:`SetupError` naming ``key``."""
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise SetupError(f"{key} must be a list of 3 numbers, got {value!r}")
    x, y, z = (number(f"{key}[{i}]", v) for i, v in enumerate(value))
    return (x, y, z)


def matrix3(key: str, value: Any) -> tuple[tuple[float, float, float], ...]:
    """``value``, 3 rows of 3 numbers, as tuples of floats, else :class:`SetupError` naming ``key``."""
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise SetupError(f"{key} must be 3 rows of 3 numbers, got {value!r}")
    return tuple(vector3(f"{key}[{i}]", row) for i, row in enumerate(value))
