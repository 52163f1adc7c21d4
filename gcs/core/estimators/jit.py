"""numba for the estimators' per-sample kernels, compiled once and cached to disk.

numba checks a cached kernel only against the file of the function it compiled, not against what
that function calls or reads (rotation formulas, a gain's position in the state), so a cache
could outlive a change to `kernels.py` or a reference estimator. The cache therefore lives in a
folder named after a hash of every source under `gcs.core`: changed code gets a fresh cache.
The folder sits beside the package when it is writable and under the user's cache directory when
it is not (a pipx or system install); under a NUMBA_CACHE_DIR the user set, its `gcs` folder.
Folders of other sources are removed once unused for a week: two installs or checkouts sharing a
base (a user cache, one NUMBA_CACHE_DIR) would otherwise delete each other's cache at every start.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from pathlib import Path

import numba
from numba.core.registry import cpu_target

CORE = Path(__file__).resolve().parents[1]

#: A cache folder of other sources unused for this long is removed.
STALE_AFTER_S = 7 * 24 * 3600.0


def source_hash(root: Path = CORE) -> str:
    """The first 16 hex digits of a SHA-256 over every .py file under root, in path order."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def cache_base() -> Path:
    """Where cached kernels go before the source hash is appended."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "gcs"
    pycache = Path(__file__).parent / "__pycache__"
    writable = pycache if pycache.exists() else pycache.parent
    if os.access(writable, os.W_OK):
        return pycache / "numba"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gcs" / "numba"


def prune(base: Path, keep: str, now: float) -> None:
    """Remove the folders under base, other than keep, that nobody has used for STALE_AFTER_S."""
    try:
        for folder in base.iterdir() if base.is_dir() else ():
            if folder.name != keep and now - folder.stat().st_mtime > STALE_AFTER_S:
                shutil.rmtree(folder, ignore_errors=True)
    except OSError:
        pass  # another process is pruning too: a stale folder costs only disk


def cache_dir() -> Path:
    """This source's cache folder, marked as used now; stale folders of other sources go."""
    base, name = cache_base(), source_hash()
    now = time.time()
    prune(base, name, now)
    try:
        os.utime(base / name, (now, now))
    except OSError:
        pass  # not created yet: numba creates it on the first compile
    return base / name


numba.config.CACHE_DIR = str(cache_dir())  # type: ignore[attr-defined]


def set_up() -> None:
    """numba's own set-up, paid once per process before the first kernel runs or loads from the
    cache (its typing and lowering registries: ~0.3-0.4 s of CPU, whatever the kernels). Done on
    purpose, it can be timed apart from the work that follows."""
    cpu_target.target_context.refresh()


#: Compiled in nopython mode, cached on disk; no fastmath: the results must equal the reference's.
kernel = numba.njit(cache=True, nogil=True)
