"""The one JSON encoder for everything gcs sends or prints: strict JSON, never `NaN`/`Infinity`.

Python's json writes non-finite floats as bare `NaN` and `Infinity` tokens, which browsers'
`JSON.parse` and most strict parsers reject: one NaN used to make a whole WebSocket frame,
`/api/history` or `gcs status --json` unreadable. Here a non-finite number becomes `null`, and a
top-level object says how many were replaced in `"nonfinite"`, so a reader can tell "unknown"
from "became null". The common case (everything finite) costs one ordinary `json.dumps`.
"""

from __future__ import annotations

import json
import math
from typing import Any

#: Key added to a top-level object when values in it were not finite.
NONFINITE_KEY = "nonfinite"


def dumps(obj: Any, **kwargs: Any) -> str:
    """json.dumps(obj) as strict JSON (kwargs as json.dumps: separators, indent, default)."""
    try:
        return json.dumps(obj, allow_nan=False, **kwargs)
    except ValueError:
        pass  # a non-finite float somewhere: replace, count, encode again
    counter = [0]
    default = kwargs.pop("default", None)
    cleaned = _finite(obj if default is None else json.loads(json.dumps(obj, default=default)), counter)
    if isinstance(cleaned, dict):
        cleaned[NONFINITE_KEY] = counter[0]
    return json.dumps(cleaned, allow_nan=False, **kwargs)


def _finite(obj: Any, counter: list[int]) -> Any:
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        counter[0] += 1
        return None
    if isinstance(obj, dict):
        return {k: _finite(v, counter) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v, counter) for v in obj]
    return obj


def loads(text: str | bytes) -> Any:
    """json.loads that refuses `NaN`, `Infinity` and `-Infinity`: how tests and clients read strictly."""

    def refuse(token: str) -> Any:
        raise ValueError(f"non-finite JSON token {token}")

    return json.loads(text, parse_constant=refuse)
