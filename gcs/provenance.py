"""Which gcs made a file: its version, the git commit it was built from and the versions of the
libraries whose numbers it depends on. Written into every session's meta.json and every report,
so a figure can be traced to the code that produced it."""

from __future__ import annotations

import json
import os
import platform
import subprocess
from dataclasses import asdict, dataclass
from functools import cache
from importlib import metadata
from pathlib import Path

from gcs import __version__

PACKAGE = Path(__file__).resolve().parent
#: Written by the wheel's build hook (setup.py); absent in a source checkout.
BUILD_INFO = PACKAGE / "_build.json"
DEPENDENCIES = ("pymavlink", "numpy", "numba", "filterpy", "scipy", "pyarrow", "fastapi", "uvicorn", "viser")


@dataclass(frozen=True)
class Provenance:
    version: str
    commit: str | None  # git commit, "+dirty" when the checkout had changes; None if unknown
    python: str
    dependencies: dict[str, str]

    def as_json(self) -> dict[str, object]:
        return asdict(self)

    def __str__(self) -> str:
        return f"gcs {self.version}" + (f" ({self.commit})" if self.commit else "")


#: git's own switch for background queries: `git status` then leaves the index as it is, where it
#: takes index.lock to refresh it. Every gcs command run from a checkout asks; a git killed in
#: the middle (the 5 s timeout, a file size limit's SIGXFSZ) left a stale lock, and the engineer's
#: own `git commit` meanwhile failed with "Another git process seems to be running".
NO_OPTIONAL_LOCKS = {"GIT_OPTIONAL_LOCKS": "0"}


def git_commit(folder: Path) -> str | None:
    """HEAD of the git checkout holding folder, with "+dirty" for uncommitted changes; None when
    folder is not in a checkout or git is missing. Read only: no lock taken in the checkout."""
    env = {**os.environ, **NO_OPTIONAL_LOCKS}
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=folder, capture_output=True, text=True, timeout=5, env=env
        )
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=5,
            env=env,
        ).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


@cache
def provenance() -> Provenance:
    if BUILD_INFO.is_file():
        commit = json.loads(BUILD_INFO.read_text()).get("commit")
    else:
        commit = git_commit(PACKAGE)
    versions = {}
    for name in DEPENDENCIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return Provenance(__version__, commit, platform.python_version(), versions)
