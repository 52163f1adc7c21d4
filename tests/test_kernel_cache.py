"""The compiled kernels' disk cache is keyed by the sources they depend on: an edit anywhere
under gcs.core (not only in the kernel's own file, which is all numba checks) gets a fresh cache."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numba

from gcs.core.estimators import jit


def test_cache_folder_is_named_after_the_core_sources():
    assert Path(numba.config.CACHE_DIR).name == jit.source_hash()


def test_an_edit_to_a_called_module_changes_the_cache_folder(tmp_path):
    core = tmp_path / "core"
    shutil.copytree(jit.CORE, core, ignore=shutil.ignore_patterns("__pycache__"))
    before = jit.source_hash(core)
    assert before == jit.source_hash()
    rotation = core / "rotation.py"
    rotation.write_text(rotation.read_text() + "\n# edited\n")
    assert jit.source_hash(core) != before


def test_pruning_keeps_recent_folders_of_other_sources(tmp_path):
    """Two checkouts sharing one cache base must not delete each other's kernels at every start."""
    now = 1_000_000_000.0
    ours, recent, stale = (tmp_path / name for name in ("ours", "other-recent", "other-stale"))
    for folder, age in ((ours, 30 * 86400.0), (recent, 3600.0), (stale, 8 * 86400.0)):
        folder.mkdir()
        (folder / "kernel.nbi").write_bytes(b"index")
        os.utime(folder, (now - age, now - age))
    jit.prune(tmp_path, "ours", now)
    assert ours.is_dir() and recent.is_dir()
    assert not stale.exists()
