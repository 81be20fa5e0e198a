"""The camera's response: linear light to pixel values and back (contract, "The frames' encoding").

The responses are ``"linear"``, ``"srgb"``, a gamma (a number) and ``"agx"``, an AgX-like tone curve; the tables
(:func:`encoding_table`, :func:`decoding_table`) serve the renderer and the readers of 8- and 16-bit frames.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["decode_values", "decoding_table", "encode_light", "encoding_table"]


# The AgX-like tone curve: log2 exposure over the width of Blender's AgX range (16.5 stops), full scale at nine
# tenths of it, through a sigmoid polynomial (increasing on [0, 1]).
_AGX_STOPS = 4.026069 + 12.47393
_AGX_FULL_SCALE = 0.9
_AGX_SIGMOID = (15.5, -40.14, 31.96, -6.868, 0.4298, 0.1191, -0.00232)


def _agx(light: np.ndarray) -> np.ndarray:
    t = np.clip(_AGX_FULL_SCALE + np.log2(np.maximum(light, 2.0**-_AGX_STOPS)) / _AGX_STOPS, 0.0, 1.0)
    return np.clip(np.polyval(_AGX_SIGMOID, t), 0.0, 1.0)


_AGX_LIGHT = np.concatenate([[0.0], np.logspace(-_AGX_STOPS * np.log10(2.0), 0.0, 4096)])
_AGX_VALUES = _agx(_AGX_LIGHT)
_AGX_KNOTS = np.concatenate([[0], np.flatnonzero(np.diff(_AGX_VALUES) > 0) + 1])  # strictly increasing values


def encode_light(light: np.ndarray, response: str | float) -> np.ndarray:
    """Pixel values in [0, 1] of linear light in [0, 1], by the response (contract, "The frames' encoding").

    ``"agx"`` is an AgX-like tone curve, a sigmoid in log exposure (Blender's
    AgX view transform at about +11 stops puts a spot near the top of its
    range and the dim background near the bottom).
    """
    light = np.clip(np.asarray(light, dtype=float), 0.0, 1.0)
    if response == "srgb":
        return np.where(light <= 0.0031308, 12.92 * light, 1.055 * light ** (1 / 2.4) - 0.055)
    if response == "linear":
        return light
    if response == "agx":
        return _agx(light)
    return light ** (1.0 / float(response))


def decode_values(values: np.ndarray, response: str | float) -> np.ndarray:
    """Linear light of pixel values in [0, 1]: the inverse of :func:`encode_light`."""
    values = np.clip(np.asarray(values, dtype=float), 0.0, 1.0)
    if response == "srgb":
        return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)
    if response == "linear":
        return values
    if response == "agx":
        light: np.ndarray = np.interp(values, _AGX_VALUES[_AGX_KNOTS], _AGX_LIGHT[_AGX_KNOTS])
        return light
    return values ** float(response)


@lru_cache(maxsize=16)
def decoding_table(response: str | float, bits: int) -> np.ndarray:
    """Linear light (full scale 1) of every ``bits``-bit pixel value under ``response``, shape (2**bits,), float32.

    The inverse of :func:`encoding_table` (cached, read-only).
    """
    table = decode_values(np.arange(2**bits) / (2**bits - 1), response).astype(np.float32)
    table.setflags(write=False)
    return table


@lru_cache(maxsize=16)
def encoding_table(response: str | float, bits: int) -> np.ndarray:
    """The ``bits``-bit pixel value of linear light quantized to 1/65535 under ``response``, shape (65536,).

    ``table[round(65535 * light)]`` encodes ``light`` in [0, 1] (cached, read-only).
    """
    values = encode_light(np.linspace(0.0, 1.0, 65536), response)
    dtype = np.uint8 if bits == 8 else np.uint16
    table: np.ndarray = np.round((2**bits - 1) * values).astype(dtype)
    table.setflags(write=False)
    return table
