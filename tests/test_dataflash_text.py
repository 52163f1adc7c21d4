"""DataFlash text logs (.log: an APM 2.5's CLI dump, Mission Planner's conversion) replay,
estimate, report and export as the .bin they were converted from; damage is named by line."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymavlink.DFReader import DFReader_binary

from gcs.commands.cli import main


def as_text(binary: Path, text: Path) -> None:
    """The .bin's records as text lines, the way Mission Planner writes a .log: FMT lines, then
    each record's type and its values as DFReader gives them (c/C/e/E and L scaled)."""
    log = DFReader_binary(str(binary))
    lines = []
    while (m := log.recv_msg()) is not None:
        if m.get_type() == "FMT":
            lines.append(f"FMT, {m.Type}, {m.Length}, {m.Name}, {m.Format}, {m.Columns}")
        else:
            lines.append(", ".join([m.get_type(), *(str(getattr(m, c)) for c in m.get_fieldnames())]))
    text.write_text("\n".join(lines) + "\n")


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def apm25_log(hop_logs, tmp_path_factory) -> tuple[Path, Path]:
    """The hop flight as ArduCopter 3.2 logged it (TimeMS), as .bin and as its text .log."""
    folder, _ = hop_logs
    text = tmp_path_factory.mktemp("text") / "apm25.log"
    as_text(folder / "old.bin", text)
    return folder / "old.bin", text


def test_a_text_log_replays_as_its_binary_log(apm25_log, capsys):
    """`gcs replay flight.log` said "cannot replay '.log'": an APM 2.5's logs, as its CLI dump
    and Mission Planner leave them, could not be looked at."""
    binary, text = apm25_log
    code, from_binary, _ = _run(["replay", "--fast", str(binary)], capsys)
    assert code == 0
    code, from_text, err = _run(["replay", "--fast", str(text)], capsys)
    assert code == 0, err
    assert from_text.splitlines()[:-1] == from_binary.splitlines()[:-1]  # the table; the timing line differs
    assert len(from_text.splitlines()) > 4 and "damage" not in err


def test_a_text_log_estimates_reports_and_exports_as_its_binary_log(apm25_log, tmp_path, capsys):
    binary, text = apm25_log
    for name, log in (("bin", binary), ("log", text)):
        assert main(["estimate", str(log), "-e", "dcm", "--out", str(tmp_path / f"{name}.csv")]) == 0
        assert main(["export", str(log), "--out", str(tmp_path / f"{name}-export.csv")]) == 0
        assert main(["report", str(log), "--out", str(tmp_path / f"{name}.html")]) == 0
    assert (tmp_path / "log.csv").read_text() == (tmp_path / "bin.csv").read_text()
    assert (tmp_path / "log-export.csv").read_text() == (tmp_path / "bin-export.csv").read_text()
    capsys.readouterr()


def test_damage_in_a_text_log_is_named_by_line_and_the_rest_is_used(apm25_log, tmp_path, capsys):
    _, text = apm25_log
    lines = text.read_text().splitlines()
    imu = [k for k, line in enumerate(lines) if line.startswith("IMU,")]
    garbled, cut = imu[10], imu[-1]
    lines[garbled] = lines[garbled].replace(",", ", x", 3)  # a value that is no number
    damaged = tmp_path / "damaged.log"
    damaged.write_text(
        "\n".join(lines[:garbled] + [lines[garbled]] + lines[garbled + 1 : cut]) + "\n" + lines[cut][:20]
    )
    code, out, err = _run(["replay", "--fast", str(damaged)], capsys)
    assert code == 0, err
    assert f"damage: {damaged}: line {garbled + 1}: IMU: a value is no number of its FMT" in err
    assert "(1 more damaged places)" in err  # the last line, cut
    assert len(out.splitlines()) > 4


@pytest.mark.parametrize(
    "content, expected",
    [
        (b"", "line 1: not a DataFlash text log (no FMT line"),
        (b"2026-12-06 12:00:00 some other program's log\n", "line 1: not a DataFlash text log (no FMT line"),
        (b"FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n", "line 1: no IMU records of instance 0 (none)"),
    ],
)
def test_a_log_that_is_no_dataflash_text_log_is_one_line(tmp_path, capsys, content, expected):
    path = tmp_path / "other.log"
    path.write_bytes(content)
    for argv in (["replay", "--fast", str(path)], ["estimate", str(path), "-e", "dcm", "--out", str(tmp_path / "x")]):
        code, _, err = _run(argv, capsys)
        assert code == 2 and expected in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


def apm2_dump(binary: Path, text: Path, records: int = 200) -> None:
    """The first IMU and ATT records of a real .bin as the CLI log dump of APM 2.x firmware printed
    them before logs carried FMT lines (ArduCopter 2.x Log.pde: the firmware banner and free RAM,
    then "RAW, " six floats, gyro rad/s and accel m/s², printed with two decimals, "ATT, " the
    centidegree integers; neither with a time), ending with the packet count."""
    log = DFReader_binary(str(binary))
    lines = ["", "ArduCopter V2.8.1", "Free RAM: 1024"]
    while len(lines) < records + 3 and (m := log.recv_match(type=["IMU", "ATT"])) is not None:
        if m.get_type() == "IMU":
            values = [m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ]
            lines.append("RAW, " + "".join(f"{v:.2f}, " for v in values) + " ")
        else:
            angles = [m.DesRoll, m.Roll, m.DesPitch, m.Pitch, m.DesYaw, m.Yaw]
            lines.append("ATT, " + ", ".join(str(round(a * 100)) for a in angles))
    lines.append(f"Number of packets read: {records}")
    text.write_text("\n".join(lines) + "\n")


def test_a_log_of_firmware_before_fmt_lines_is_refused_naming_what_it_lacks(logs_dir, tmp_path, capsys):
    """APM 2.x firmware's dump of fixed-format records (no FMT line, no time in its RAW and ATT
    records) was refused as "not a DataFlash text log", as if it were some other program's file.
    It is refused naming its first record and what is missing, and what to read instead."""
    path = tmp_path / "apm2.log"
    apm2_dump(logs_dir / "arducopter-sitl-hop.BIN", path)
    first = next(n for n, line in enumerate(path.read_text().splitlines(), start=1) if line.startswith("RAW, "))
    expected = (
        f"{path}: line {first}: RAW record of a log with no FMT lines (APM 2.x firmware's fixed formats, IMU "
        "records without time; no conversion adds them): cannot be read, use the flight's .tlog"
    )
    out = tmp_path / "x.csv"
    for argv in (["replay", "--fast", str(path)], ["estimate", str(path), "-e", "dcm", "--out", str(out)]):
        code, _, err = _run(argv, capsys)
        assert code == 2 and err.splitlines() == [f"gcs {argv[0]}: error: {expected}"], err
    assert not out.exists()
