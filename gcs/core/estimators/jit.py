"""numba for the estimators' per-sample kernels, compiled once and cached to disk.

numba caches compiled code beside the source (`__pycache__`); an installed package may be
read-only (a pipx or system install), so the cache then goes under the user's cache directory
(NUMBA_CACHE_DIR, unless the user set it). This must happen before numba is imported.
"""

from __future__ import annotations

import os
from pathlib import Path


def _cache_dir() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = Path(__file__).parent
    if os.access(here, os.W_OK) and (not (here / "__pycache__").exists() or os.access(here / "__pycache__", os.W_OK)):
        return
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    os.environ["NUMBA_CACHE_DIR"] = str(Path(base) / "gcs" / "numba")


_cache_dir()

import numba  # noqa: E402 - after NUMBA_CACHE_DIR is settled

#: Compiled in nopython mode, cached on disk; no fastmath: the results must equal the reference's.
kernel = numba.njit(cache=True, nogil=True)
