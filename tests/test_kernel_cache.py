"""The compiled kernels' disk cache is keyed by the sources they depend on: an edit anywhere
under gcs.core (not only in the kernel's own file, which is all numba checks) gets a fresh cache."""

from __future__ import annotations

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
