"""numba for the estimators' kernels, compiled once and cached to disk.

numba keys a cached function on its own source file only, not on the functions it calls: after
an edit of kernels.py, or of a step kernel the whole-run loop (whole.py) inlines, it would load
stale machine code. So the cache lives in a folder named by a hash of every source the kernels
are compiled from (this package, core.rotation, core.samples): any edit there starts a new cache
(and the old folders are removed). The folder is beside the package (`__pycache__`) when that
is writable, else under the user's cache directory (a pipx or system install). NUMBA_CACHE_DIR
set by the user wins. All this must happen before numba is imported.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

_HERE = Path(__file__).parent
#: What the kernels are compiled from, besides this package's modules.
_SOURCES = (_HERE.parent / "rotation.py", _HERE.parent / "samples.py")


def _source_hash() -> str:
    digest = hashlib.sha1()
    for path in sorted(_HERE.glob("*.py")) + list(_SOURCES):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = _HERE / "__pycache__"
    writable = os.access(_HERE, os.W_OK) and (not here.exists() or os.access(here, os.W_OK))
    base = here if writable else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gcs"
    name = f"numba-{_source_hash()}"
    try:
        for old in base.glob("numba-*"):
            if old.name != name:
                shutil.rmtree(old, ignore_errors=True)
    except OSError:
        pass  # another process is at it; a stale folder costs only disk
    os.environ["NUMBA_CACHE_DIR"] = str(base / name)


_cache_dir()

import numba  # noqa: E402 - after NUMBA_CACHE_DIR is settled

#: Compiled in nopython mode, cached on disk; no fastmath: the results must equal the reference's.
kernel = numba.njit(cache=True, nogil=True)
