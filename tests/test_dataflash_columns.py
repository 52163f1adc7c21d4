"""The DataFlash column reader (gcs.logs.dataflash_format + gcs.logs.dataflash) gives exactly the
samples pymavlink's DFReader gives (tests/dataflash_reference.py: the record-by-record reader it
replaced), field by field and bit for bit, in the input table too, on every shared .bin and on the
hop flight rewritten in the TimeMS and TimeUS generations of the format; a cut, garbled or
badly defined log is read up to the damage with one line naming the offset and the cause."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from conftest import DATA, LOGS
from dataflash_reference import DfreaderLog
from pymavlink.DFReader import DFReader_binary
from pyulog_reference import assert_same_samples
from test_dataflash_text import as_text

from gcs.commands.cli import main
from gcs.core.estimators import registry
from gcs.core.samples import GpsSample, ImuSample
from gcs.logs.dataflash import COLUMNS, DataflashLog
from gcs.logs.dataflash_format import field_text, read_dataflash, scaled
from gcs.logs.input_table import InputTable, InputTableBuilder
from gcs.logs.logfile import InputError
from gcs.runtime.replay import whole_table
from gcs.sessions.sources import ReplaySource, open_source, sample_frames
from gcs.sim.dataflash import NEW_FORMATS, DataflashWriter, e7, x100

SHARED_BINS = sorted(p for p in DATA.rglob("*") if p.suffix.lower() == ".bin")  # every one in ../shared/data
HOP = LOGS / "arducopter-sitl-hop.BIN"


def reference_table(samples: list) -> InputTable:
    table = InputTableBuilder()
    for sample in samples:
        table.append(sample)
    return table.build()


def assert_same_table(ours: InputTable, reference: InputTable) -> None:
    """Every array bit for bit (NaN where NaN), sources compared by name."""
    for name in ("kind", "imu", "gps", "attitude", "gain_estimator", "gain_value"):
        a, b = getattr(ours, name), getattr(reference, name)
        assert a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    for name in ("imu_source", "gps_source", "attitude_source", "gain_name"):
        a, b = getattr(ours, name), getattr(reference, name)
        assert [ours.names[c] for c in a.tolist()] == [reference.names[c] for c in b.tolist()], name


def assert_reads_like_dfreader(path, imu: int = 0) -> DataflashLog:
    reference = DfreaderLog(str(path), imu)
    expected = list(reference)
    reader = DataflashLog(str(path), imu)
    table = reader.columns()
    assert_same_samples(list(table.inputs()), expected)
    assert_same_table(table, reference_table(expected))
    assert dict(reader.counts) == dict(reference.counts)
    assert (reader.first_us, reader.last_us) == (reference.first_us, reference.last_us)
    assert reader.notes == reference.notes
    assert reader.declination.source == reference.declination.source
    return reader


def test_the_shared_logs_are_found():
    assert {p.name for p in SHARED_BINS} >= {"arducopter-sitl-hop.BIN", "ardupilot-fragment.bin"}


@pytest.mark.parametrize("path", SHARED_BINS, ids=lambda p: p.name)
def test_every_shared_bin_reads_as_dfreader_reads_it(path):
    reader = assert_reads_like_dfreader(path)
    assert reader.counts["IMU"] > 40 and reader.counts["GPS"] > 0 and reader.counts["MAG"] > 0


@pytest.mark.parametrize("imu", [0, 1])
@pytest.mark.parametrize("name", ["old.bin", "new.bin"], ids=["TimeMS", "TimeUS"])
def test_both_generations_read_as_dfreader_reads_them(hop_logs, name, imu):
    folder, _ = hop_logs
    reader = assert_reads_like_dfreader(folder / name, imu)
    assert reader.counts["IMU2" if name == "old.bin" and imu else "IMU"] == 2450
    assert reader.damage is None


def test_second_imu_of_the_fragment(tmp_path):
    """ArduCopter 3.3-3.5: TimeUS, yet the second IMU is its own type (IMU2)."""
    reader = assert_reads_like_dfreader(LOGS / "ardupilot-fragment.bin", imu=1)
    assert reader.counts["IMU2"] == 45


def record_starts(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of every record of an undamaged log: a 3-byte header (0xA3 0x95, type),
    the type's length from its FMT record (type 128: Type at byte 3, Length at byte 4)."""
    lengths, starts, pos = {128: 89}, [], 0
    while pos < len(data):
        assert data[pos : pos + 2] == b"\xa3\x95", pos
        kind = data[pos + 2]
        if kind == 128:
            lengths.setdefault(data[pos + 3], data[pos + 4])
        starts.append((pos, lengths[kind]))
        pos += lengths[kind]
    return starts


@pytest.mark.parametrize("where", [0.3, 0.999])
@pytest.mark.parametrize("inside", [1, 20])
def test_a_cut_log_reads_up_to_the_cut_record(hop_logs, tmp_path, where, inside, capsys):
    """Cut inside a record's header (1 of its 3 bytes) or body: the records before it are read
    exactly as DFReader reads them, and one line names the cut record's offset."""
    folder, _ = hop_logs
    data = (folder / "new.bin").read_bytes()
    starts = record_starts(data)
    at, length = starts[int(len(starts) * where)]
    path = tmp_path / "cut.bin"
    path.write_bytes(data[: at + inside])
    reader = assert_reads_like_dfreader(path)
    cause = f"log ends inside a record ({inside} of its {3 if inside < 3 else length} bytes)"
    assert reader.damage == f"{path}: offset {at}: {cause}; records up to there are used"
    assert main(["replay", str(path), "--fast"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if "damage" in line] == [f"damage: {reader.damage}"]


def test_a_garbled_header_is_skipped_as_dfreader_skips_it(hop_logs, tmp_path):
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    at, length = record_starts(bytes(data))[len(record_starts(bytes(data))) // 2]
    data[at : at + 2] = b"\x00\x00"
    path = tmp_path / "garbled.bin"
    path.write_bytes(bytes(data))
    reader = assert_reads_like_dfreader(path)
    assert (
        reader.damage == f"{path}: offset {at}: bad record header 0x0000; {length} bytes skipped up to the next record"
    )


def test_a_record_of_an_undefined_type_is_skipped_and_reading_goes_on(hop_logs, tmp_path):
    """DFReader stops at a type no FMT defined; this reader skips it up to the next record, so
    it reads what DFReader reads from the log without that record."""
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    starts = record_starts(bytes(data))
    at, length = next(s for s in starts[len(starts) // 2 :] if data[s[0] + 2] != 128)
    undefined = next(k for k in range(1, 128) if all(data[s + 2] != k for s, _ in starts))
    data[at + 2] = undefined
    path, without = tmp_path / "undefined.bin", tmp_path / "without.bin"
    path.write_bytes(bytes(data))
    without.write_bytes(bytes(data[:at] + data[at + length :]))
    reference = DfreaderLog(str(without))
    expected = list(reference)
    reader = DataflashLog(str(path))
    assert_same_samples(list(reader), expected)
    assert dict(reader.counts) == dict(reference.counts)
    cause = f"record of type {undefined}, which no FMT defined; {length} bytes skipped up to the next record"
    assert reader.damage == f"{path}: offset {at}: {cause}"


def test_padding_at_the_end_is_no_damage(hop_logs, tmp_path):
    """A block-based log ends in up to a page of erased bytes: not damage (DFReader's 528-byte rule)."""
    folder, _ = hop_logs
    path = tmp_path / "padded.bin"
    path.write_bytes((folder / "new.bin").read_bytes() + b"\xff" * 300)
    assert assert_reads_like_dfreader(path).damage is None


def fmt_record(data: bytes, name: bytes) -> int:
    """The offset of the FMT record defining `name` (its Name at bytes 5-8)."""
    return next(
        at for at, _ in record_starts(data) if data[at + 2] == 128 and data[at + 5 : at + 9] == name.ljust(4, b"\0")
    )


def test_a_bad_fmt_is_refused_and_its_records_not_read(hop_logs, tmp_path, capsys):
    """GPS's FMT with a format character no DataFlash logger writes: the GPS records are not
    decoded (the rest is), one line names the FMT's offset and why."""
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    at = fmt_record(bytes(data), b"GPS")
    data[at + 9 : at + 10] = b"?"  # the first format character (TimeUS's Q)
    path = tmp_path / "bad-fmt.bin"
    path.write_bytes(bytes(data))
    reader = DataflashLog(str(path))
    samples = list(reader)
    assert not any(isinstance(s, GpsSample) for s in samples)
    assert sum(isinstance(s, ImuSample) for s in samples) == 2450
    cause = f"FMT for type {data[at + 3]} refused (GPS has unknown format characters '?'); its records are not read"
    assert reader.damage == f"{path}: offset {at}: {cause}"
    assert reader.notes == [f"{path}: no GPS records: no GPS aiding"]


def test_a_bad_imu_fmt_is_a_clear_error_and_no_output(hop_logs, tmp_path, capsys):
    """IMU's FMT with a length its format does not have: nothing to estimate from; `gcs
    estimate` says so in one line naming the FMT's offset, exits 2 and writes no file."""
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    at = fmt_record(bytes(data), b"IMU")
    data[at + 4] += 1
    path = tmp_path / "bad-imu.bin"
    path.write_bytes(bytes(data))
    out = tmp_path / "out.csv"
    assert main(["estimate", str(path), "-e", "dcm", "-o", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"{path}: offset {at}: FMT for type " in err[0], err
    assert "refused (IMU records of 37 bytes where the format 'QBffffff' has 36)" in err[0]
    assert "no IMU records of instance 0" in err[0]
    assert not out.exists()


def test_replay_fast_estimates_as_from_dfreaders_samples():
    """whole_table (what `gcs replay --fast` prints) over the columns equals it over the input
    table of DFReader's samples, row for row; the frames are one per sample as before."""
    reference = DfreaderLog(str(HOP))
    built = reference.columns()
    source = open_source(HOP)
    assert source.frames.t.tolist() == sample_frames(built).t.tolist()
    assert source.frames.input_end.tolist() == sample_frames(built).input_end.tolist()
    expected = ReplaySource(str(HOP), "dataflash", sample_frames(built), built, dict(reference.counts), None)
    names = registry.names()
    assert whole_table(source, names, {}) == whole_table(expected, names, {})


@pytest.mark.parametrize("name", [*(p.name for p in SHARED_BINS), "old.bin", "new.bin"])
def test_every_field_of_the_wanted_records_is_dfreaders(hop_logs, name):
    """Every column of every record of the types the reader wants, as DFReader gives it: scaled
    (c/C/e/E, L) and plain numbers equal as float64, text equal."""
    path = hop_logs[0] / name if name in ("old.bin", "new.bin") else next(p for p in SHARED_BINS if p.name == name)
    contents = read_dataflash(str(path), COLUMNS)
    log = DFReader_binary(str(path))
    compared = 0
    for kind, rows in contents.records.items():
        fmt = contents.formats[kind]
        expected = []
        log.rewind()
        while (record := log.recv_match(type=kind)) is not None:
            expected.append(record)
        assert len(expected) == len(rows), kind
        for column, char in zip(fmt.columns, fmt.format, strict=True):
            theirs = [getattr(r, column) for r in expected]
            if char in "nNZ":
                assert [field_text(bytes(v)) for v in rows[column].tolist()] == theirs, (kind, column)
            else:
                ours = scaled(rows, fmt, column)
                assert np.array_equal(ours, np.array(theirs, dtype=np.float64), equal_nan=True), (kind, column)
            compared += len(rows)
    assert compared > 1000


def test_records_of_header_only_are_all_found(tmp_path):
    """A record is at least its 3-byte header: 200,000 such records are indexed, none lost where
    the index outgrows its first guess (32 bytes a record)."""
    writer = DataflashWriter()
    writer.define("TICK", "", "")
    for _ in range(200_000):
        writer.add("TICK")
    path = tmp_path / "ticks.bin"
    path.write_bytes(writer.bytes())
    contents = read_dataflash(str(path), {"TICK": ()})
    assert len(contents.records["TICK"]) == 200_000 and contents.damage == []
    assert contents.positions["TICK"].tolist() == list(range(2, 200_002))  # after the two FMT records


@pytest.mark.parametrize(
    ("kind", "columns", "lacking"),
    [("IMU", b"TimeUS,I,GyrX,GyrY,Gyr_,AccX,AccY,AccZ", "GyrZ"), ("PARM", b"TimeUS,Name,Valu", "Value")],
)
def test_a_type_without_the_columns_read_is_refused(hop_logs, tmp_path, kind, columns, lacking):
    """An FMT whose columns lack one the reader uses: refused like any bad FMT (an IMU one leaves
    nothing to estimate from: one clear line), never a traceback."""
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    at = fmt_record(bytes(data), kind.encode())
    if kind == "PARM":  # the fixture defines PARM but logs none: one COMPASS_DEC after the FMTs
        first = next(s for s, _ in record_starts(bytes(data)) if data[s + 2] != 128)
        data[first:first] = b"\xa3\x95" + bytes([data[at + 3]]) + struct.pack("<Q16sf", 0, b"COMPASS_DEC", 0.2)
        path = tmp_path / "with-parm.bin"
        path.write_bytes(bytes(data))
        reader = DataflashLog(str(path))
        reader.columns()
        assert reader.declination.source == "vehicle COMPASS_DEC" and reader.damage is None
    data[at + 25 : at + 89] = columns.ljust(64, b"\0")
    path = tmp_path / "lacking.bin"
    path.write_bytes(bytes(data))
    reader = DataflashLog(str(path))
    cause = f"{kind} has no {lacking} of the kind it must be (text or number)"
    if kind == "IMU":
        with pytest.raises(InputError, match=rf"offset {at}: FMT for type \d+ refused \({re.escape(cause)}\)"):
            reader.columns()
    else:
        reader.columns()
        assert reader.damage.startswith(f"{path}: offset {at}: FMT for type ") and cause in reader.damage
        assert reader.declination.source != "vehicle COMPASS_DEC"


def test_a_gps_course_that_is_no_number_gives_no_velocity(tmp_path):
    """A damaged GPS record whose course is infinite: the fix without a velocity (DFReader's
    reader stopped there on math.cos's ValueError)."""
    writer = DataflashWriter()
    for name in ("IMU", "GPS"):
        writer.define(name, *NEW_FORMATS[name])
    writer.add("IMU", 1_000_000, 0, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8)
    for course in (float("inf"), 90.0):
        writer.add("GPS", 2_000_000, 0, 3, 0, 0, 12, 90, e7(-35.0), e7(149.0), x100(584.0), 2.0, course, -0.5, 0.0)
    path = tmp_path / "inf.bin"
    path.write_bytes(writer.bytes())
    damaged, whole = (s for s in DataflashLog(str(path)) if isinstance(s, GpsSample))
    assert damaged.vel_ned is None and (damaged.lat, damaged.fix_type) == (-35.0, 3)
    np.testing.assert_allclose(whole.vel_ned, [0.0, 2.0, -0.5], atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_corrupted_logs_read_or_are_refused_in_one_line(tmp_path, seed):
    """300 random corruptions of the fragment (bytes changed, zeroed, cut out, the file cut, the
    FMT records hit): each reads to an input table or raises InputError; nothing else escapes."""
    rng = np.random.default_rng(seed)
    source = (LOGS / "ardupilot-fragment.bin").read_bytes()
    fmt_end = max(at + length for at, length in record_starts(source[:20_000]) if source[at + 2] == 128)
    path = tmp_path / "corrupt.bin"
    outcomes = {"read": 0, "refused": 0}
    for _ in range(75):
        data = bytearray(source)
        at = int(rng.integers(len(data)))
        match int(rng.integers(5)):
            case 0:
                data[at] = int(rng.integers(256))
            case 1:
                data[at : at + int(rng.integers(1, 2000))] = b""
            case 2:
                data[at : at + 500] = bytes(len(data[at : at + 500]))
            case 3:
                data = data[:at]
            case _:
                for where in rng.integers(fmt_end, size=3):
                    data[int(where)] = int(rng.integers(256))
        path.write_bytes(bytes(data))
        try:
            table = DataflashLog(str(path)).columns()
            list(table.inputs())
            outcomes["read"] += 1
        except InputError as exc:
            assert str(path) in str(exc) and "offset" in str(exc) and "\n" not in str(exc)
            outcomes["refused"] += 1
    assert outcomes["read"] > 0


def test_an_fmt_redefining_a_type_is_refused_and_the_first_holds(hop_logs, tmp_path):
    """A second FMT for IMU's type id, half way, with another layout: refused (DFReader would
    walk every IMU record with the new length from the start); the log reads as without it."""
    folder, _ = hop_logs
    data = (folder / "new.bin").read_bytes()
    imu_fmt = fmt_record(data, b"IMU")
    redefined = bytearray(data[imu_fmt : imu_fmt + 89])
    redefined[4] -= 4  # 4 bytes shorter
    redefined[9 : 9 + 16] = b"QBfffff".ljust(16, b"\0")
    at = record_starts(data)[len(record_starts(data)) // 2][0]
    path = tmp_path / "redefined.bin"
    path.write_bytes(data[:at] + bytes(redefined) + data[at:])
    reader = DataflashLog(str(path))
    assert_same_samples(list(reader), list(DataflashLog(str(folder / "new.bin"))))
    assert (
        reader.damage
        == f"{path}: offset {at}: FMT redefining type {data[imu_fmt + 3]} refused; its first definition holds"
    )


@pytest.mark.parametrize("suffix", [".bin", ".log"])
def test_two_types_holding_one_imu_instance_name_the_byte_offset_or_line(hop_logs, tmp_path, suffix, capsys):
    """IMU instance 0 logged half as IMU and half as IMU2 (a type defined as IMU is, with its `I`
    field): refused in one line naming where IMU2's first record is. It named the record's index
    among the file's records as its byte offset ("offset 4658" for a record at byte 149 951), in
    a text log too, whose places are lines."""
    folder, _ = hop_logs
    data = bytearray((folder / "new.bin").read_bytes())
    starts = record_starts(bytes(data))
    imu_fmt = fmt_record(bytes(data), b"IMU")
    unused = next(k for k in range(1, 128) if all(data[s + 2] != k for s, _ in starts))
    imu2 = bytearray(data[imu_fmt : imu_fmt + 89])
    imu2[3], imu2[5:9] = unused, b"IMU2"
    first = [k for k, (s, _) in enumerate(starts) if data[s + 2] == data[imu_fmt + 3] and data[s + 3 + 8] == 0]
    moved = first[len(first) // 2 :]
    for k in moved:
        data[starts[k][0] + 2] = unused
    binary = tmp_path / "imu2.bin"
    binary.write_bytes(bytes(imu2) + bytes(data))  # the new FMT first: every record one further on
    index, offset = moved[0] + 1, starts[moved[0]][0] + 89
    path = binary
    if suffix == ".log":
        path = tmp_path / "imu2.log"
        as_text(binary, path)
    out = tmp_path / "out.csv"
    assert main(["estimate", str(path), "-e", "dcm", "--out", str(out)]) == 2
    at = f"offset {offset}" if suffix == ".bin" else f"line {index + 1}"  # one record a line
    error = f"gcs estimate: error: {path}: {at}: IMU, IMU2 records hold the same instance"
    assert capsys.readouterr().err.splitlines() == [error]
    assert not out.exists()
