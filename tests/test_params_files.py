""".param files (Mission Planner / MAVProxy format), diffs, and `gcs params` end to end against
the simulator over UDP."""

from __future__ import annotations

import asyncio
import resource
import subprocess
import sys

import pytest
from conftest import LOGS, ROOT, free_port
from live import running_sim

from gcs.commands.cli import main
from gcs.mavlink import param_files
from gcs.mavlink.param_files import ParamFileError
from gcs.mavlink.params import float32


def test_both_formats_comments_and_round_trip(tmp_path):
    text = "# saved by Mission Planner\nRATE_RLL_P,0.15\nRATE_PIT_P , 0.16 # pitch\n\nSTB_RLL_P\t4.5\nFRAME 1\n"
    values = param_files.parse(text, "t.param")
    assert values == {"RATE_RLL_P": 0.15, "RATE_PIT_P": 0.16, "STB_RLL_P": 4.5, "FRAME": 1.0}
    vehicle = {"RATE_RLL_P": float32(0.135), "LOG_BITMASK": 830, "COMPASS_DEC": float32(-0.13)}
    path = param_files.save(tmp_path / "v.param", vehicle, comment="from the vehicle")
    assert path.read_text() == "# from the vehicle\nCOMPASS_DEC,-0.13\nLOG_BITMASK,830\nRATE_RLL_P,0.135\n"
    assert {k: float32(v) for k, v in param_files.load(path).items()} == vehicle  # exact after float32


@pytest.mark.parametrize(
    "text,message",
    [
        ("RATE_RLL_P,abc", r"t.param:1: RATE_RLL_P: 'abc' is not a number"),
        ("A,1\nB\n", r"t.param:2: expected NAME,VALUE or NAME VALUE, got 'B'"),
        ("A,1\nA,2\n", r"t.param:2: A already set on line 1"),
        ("A_NAME_LONGER_THAN_16,1", r"t.param:1: 'A_NAME_LONGER_THAN_16' is not a parameter name"),
        ("A,1,2", r"t.param:1: expected NAME,VALUE"),
    ],
)
def test_bad_lines_are_named(text, message):
    with pytest.raises(ParamFileError, match=message):
        param_files.parse(text, "t.param")


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ParamFileError, match=r"cannot read .*nope.param"):
        param_files.load(tmp_path / "nope.param")


def test_cli_errors_are_one_line_saying_error(tmp_path, capsys):
    """As every other command says it: `gcs params ACTION: error: ...`, naming the file."""
    there = tmp_path / "there.param"
    there.write_text("ATC_RAT_RLL_P,0.135\n")
    assert main(["params", "diff", str(tmp_path / "missing.param"), str(there)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("gcs params diff: error: ") and "missing.param" in line, line


def test_diff_compares_as_the_vehicle_stores_values():
    a = {"A": 0.15, "B": 1.0, "C": 2.0}
    b = {"A": float32(0.15), "B": 1.5, "D": 3.0}
    differences = param_files.diff(a, b)
    assert [d.as_dict() for d in differences] == [
        {"name": "B", "a": 1.0, "b": 1.5},
        {"name": "C", "a": 2.0, "b": None},
        {"name": "D", "a": None, "b": 3.0},
    ]
    assert param_files.format_diff(differences).split("\n")[2].split() == ["C", "2", "(missing)"]


async def _gcs(*args: str, file_size_limit: int | None = None) -> tuple[int, str, str]:
    """`gcs params ARGS` in its own process; with `file_size_limit`, no file it writes may grow past
    that many bytes (RLIMIT_FSIZE: the write fails with EFBIG, as on a full disk)."""

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))

    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "gcs",
        "params",
        *args,
        cwd=ROOT,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        preexec_fn=None if file_size_limit is None else limited,
    )
    out, err = await asyncio.wait_for(proc.communicate(), 60)
    return proc.returncode, out.decode(), err.decode()


def test_cli_save_set_diff_load_against_the_vehicle(tmp_path):
    saved, edited = tmp_path / "vehicle.param", tmp_path / "edited.param"

    async def scenario():
        port = free_port()
        link = ["--connect", f"udpin:127.0.0.1:{port}"]  # params record only with --record
        async with running_sim(f"udpout:127.0.0.1:{port}", profile="apm25", param_drop=0.1) as sim:
            before = sim.params.as_dict()
            rc, out, err = await _gcs("save", str(saved), *link)
            assert rc == 0, err
            assert f"saved {len(before)} parameters" in out
            assert {k: float32(v) for k, v in param_files.load(saved).items()} == before
            sim.param_drop = 0.0  # the lost-packet path is covered once; keep the rest quick

            rc, out, err = await _gcs("set", "RATE_RLL_P", "0.3", "--profile", "arducopter-3.2", *link)
            assert rc == 1 and "more than the largest step 0.02 allowed per write" in err
            assert sim.params.as_dict() == before
            rc, out, err = await _gcs("set", "RATE_RLL_P", "0.17", "--profile", "arducopter-3.2", *link)
            assert rc == 0, err
            assert out.strip() == "RATE_RLL_P: 0.15 -> 0.17 (verified)"

            rc, out, err = await _gcs("diff", str(saved), *link)
            assert rc == 0, err
            assert out.split("\n")[1].split() == ["RATE_RLL_P", "0.15", "0.17"] and len(out.split("\n")) == 3

            edited.write_text(saved.read_text().replace("AHRS_RP_P,0.2\n", "AHRS_RP_P,0.9\n"))
            rc, out, err = await _gcs("load", str(edited), "--profile", "arducopter-3.2", *link)
            assert rc == 1 and "AHRS_RP_P = 0.9 is outside the allowed range [0.1, 0.4]" in err
            assert "nothing written" in err and sim.params["RATE_RLL_P"] == pytest.approx(0.17)
            rc, out, err = await _gcs("load", str(saved), *link)
            assert rc == 0, err
            assert "wrote 1 of 1 parameters, each verified" in out
            assert sim.params.as_dict() == before

    asyncio.run(asyncio.wait_for(scenario(), 120))
    rc, out, _ = asyncio.run(_gcs("diff", str(saved), str(edited)))
    assert rc == 0 and out.split("\n")[1].split() == ["AHRS_RP_P", "0.2", "0.9"]


def test_a_save_that_fails_keeps_the_file_it_would_replace(tmp_path):
    """`gcs params save before.param` on a full disk (a file size limit here) wrote the file in
    place: it cut the engineer's earlier snapshot short at the limit and ended in a traceback
    (found by the audit). Now one line names the file, which keeps its old text."""
    snapshot = tmp_path / "before.param"
    earlier = "# yesterday's pre-flight values\n" + "".join(f"RATE_RLL_P{k},0.15\n" for k in range(200))
    snapshot.write_text(earlier)

    async def scenario():
        port = free_port()
        async with running_sim(f"udpout:127.0.0.1:{port}", profile="apm25"):
            return await _gcs("save", str(snapshot), "--connect", f"udpin:127.0.0.1:{port}", file_size_limit=1024)

    rc, out, err = asyncio.run(asyncio.wait_for(scenario(), 120))
    assert rc == 1 and err.strip().splitlines() == [
        f"gcs params save: error: {snapshot}: File too large (an earlier file is kept as it was)"
    ], err
    assert snapshot.read_text() == earlier and sorted(p.name for p in tmp_path.iterdir()) == ["before.param"]


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"ATC_RAT_RLL_P,nan\n", "bad.param:1: ATC_RAT_RLL_P: 'nan' is not a finite number"),
        (b"ATC_RAT_RLL_P 1e999\n", "bad.param:1: ATC_RAT_RLL_P: '1e999' is not a finite number"),
        (None, "bad.param:1: expected NAME,VALUE or NAME VALUE, got "),  # the hop's .BIN, renamed
    ],
)
def test_a_damaged_param_file_is_refused_in_one_short_line(content, expected, tmp_path):
    """Found by the audit: "nan", "inf" or 1e999 were read as values (diff showed nan, and a load
    wrote every other parameter before the vehicle refused that one), and a file that is no .param
    file at all was quoted whole: a .bin's first "line" is 639 characters of binary."""
    good, bad = tmp_path / "good.param", tmp_path / "bad.param"
    good.write_text("ATC_RAT_RLL_P,0.135\n")
    bad.write_bytes(content if content is not None else (LOGS / "arducopter-sitl-hop.BIN").read_bytes()[:4096])
    done = subprocess.run(
        [sys.executable, "-m", "gcs", "params", "diff", "good.param", "bad.param"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=60,
    )
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"gcs params diff: error: {expected}") and len(line) < 200, line
