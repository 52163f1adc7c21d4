"""gcs: a MAVLink ground station and telemetry server for flight tests.

For notebooks and scripts: `gcs.open_session(path)` and `gcs.estimate(log, ...)` (gcs.api),
imported on first use so `import gcs` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

__all__ = ["__version__", "estimate", "open_session"]

_API = frozenset({"open_session", "estimate"})


def __getattr__(name: str) -> Any:
    if name in _API:
        # Imported on first use, by name: pyarrow and the estimators load only when asked for, and
        # a module that imports `gcs` for __version__ (any layer) does not depend on the API.
        # Typed code can import them from gcs.api.
        return getattr(importlib.import_module("gcs.api"), name)
    raise AttributeError(f"module 'gcs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_API})
