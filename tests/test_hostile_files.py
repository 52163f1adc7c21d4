"""Files are data, never programs. pymavlink's `mavlink_connection` treats a path containing
`/bin/` or ending in `.elf` as a device to run as a child process; FAT and exFAT sticks mount
every file executable. An executable script named like a log, given to every command that takes
a log (and to what-if through the workbench), must never run: each answers with one line."""

from __future__ import annotations

import pytest

from gcs.commands.cli import main
from gcs.logs.logfile import InputError
from gcs.sessions.workbench import load_source, what_if_view

SUFFIXES = (".tlog", ".bin", ".ulg", ".elf")


def planted(tmp_path, suffix: str):
    """An executable `.../bin/flight<suffix>` that leaves a marker file if it is ever run."""
    marker = tmp_path / "ran"
    folder = tmp_path / "bin"
    folder.mkdir(exist_ok=True)
    script = folder / f"flight{suffix}"
    script.write_text(f"#!/bin/sh\ntouch {marker}\n")
    script.chmod(0o755)
    return script, marker


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_an_executable_log_is_never_run_by_any_command(suffix, tmp_path, capsys):
    script, marker = planted(tmp_path, suffix)
    commands = {
        "estimate": ["estimate", "--estimator", "dcm", str(script), "--out", str(tmp_path / "out.csv")],
        "replay": ["replay", "--fast", str(script)],
        "report": ["report", str(script), "--out", str(tmp_path / "report.html")],
        "export": ["export", str(script), "--out", str(tmp_path / "export.csv")],
    }
    for name, argv in commands.items():
        code = main(argv)
        err = capsys.readouterr().err.strip()
        assert not marker.exists(), f"gcs {name} ran {script}"
        assert code == 2, (name, code, err)
        assert len(err.splitlines()) == 1 and str(script) in err and "Traceback" not in err, (name, err)
    for open_it in (lambda: load_source(script), lambda: what_if_view(script, "dcm", {})):
        with pytest.raises(InputError, match="flight"):
            open_it()
        assert not marker.exists(), f"the workbench ran {script}"
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "report.html").exists()
