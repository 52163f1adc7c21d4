"""Which code made a file (gcs.provenance): the commit is asked of git without a lock in the
checkout. A real repository and a real git, in a process under a file size limit."""

from __future__ import annotations

import os
import resource
import subprocess
import sys


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (1, 1))  # any write past a byte: EFBIG, git's SIGXFSZ


def test_asking_git_for_the_commit_leaves_no_lock_in_the_checkout(tmp_path):
    """Every gcs command run from a checkout asks git for its commit; `git status` refreshed the
    index under index.lock, so a git killed meanwhile (here by a file size limit, as
    tests/test_params_files.py's full-disk save did to this checkout) left the lock behind and the
    engineer's next `git commit` failed with "Another git process seems to be running" (found by
    the audit). With git's GIT_OPTIONAL_LOCKS=0 the query takes no lock."""
    repo = tmp_path / "checkout"
    repo.mkdir()

    def git(*argv: str) -> str:
        return subprocess.run(["git", *argv], cwd=repo, check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    (repo / "flight.py").write_text("gains = 1\n")
    git("add", "flight.py")
    git("-c", "user.name=audit", "-c", "user.email=audit@example.org", "commit", "-qm", "one")
    os.utime(repo / "flight.py", ns=(1, 1))  # its stat no longer the index's: git status refreshes it
    code = f"from pathlib import Path; from gcs.provenance import git_commit; print(git_commit(Path({str(repo)!r})))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, preexec_fn=_limited)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == git("rev-parse", "HEAD")  # the same content: not dirty
    assert not (repo / ".git" / "index.lock").exists()
