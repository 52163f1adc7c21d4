"""Values compared bit for bit (the equality tests of the receive path's short cuts)."""

from __future__ import annotations

import dataclasses
import struct

import numpy as np


def bits(value: object) -> object:
    """A value as its exact bits: floats (NaN and -0.0 included), arrays, tuples and dataclasses
    compare bit for bit."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return type(value).__name__, tuple(bits(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.shape, value.tobytes()
    if isinstance(value, float):
        return struct.pack("<d", value)
    if isinstance(value, tuple):
        return tuple(bits(v) for v in value)
    return value
