"""The DataFlash column reader (gcs.logs.dataflash_format + gcs.logs.dataflash) gives exactly the
samples pymavlink's DFReader gives (tests/dataflash_reference.py: the record-by-record reader it
replaced), field by field and bit for bit, in the input table too, on every shared .bin and on the
hop flight rewritten in the TimeMS and TimeUS generations of the format; a cut, garbled or
badly defined log is read up to the damage with one line naming the offset and the cause."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import LOGS
from dataflash_reference import DfreaderLog
from dataflash_writer import hop_in_both_formats
from pyulog_reference import assert_same_samples

from gcs.logs.dataflash import DataflashLog
from gcs.logs.input_table import InputTable, InputTableBuilder

SHARED_BINS = sorted(p for p in LOGS.iterdir() if p.suffix.lower() == ".bin")
HOP = LOGS / "arducopter-sitl-hop.BIN"


@pytest.fixture(scope="module")
def hop_logs(tmp_path_factory):
    """The hop flight as an ArduCopter 3.2 log (old.bin, TimeMS) and a current one (new.bin, TimeUS)."""
    folder = tmp_path_factory.mktemp("hop")
    old, new = hop_in_both_formats(str(HOP))
    (folder / "old.bin").write_bytes(old.bytes())
    (folder / "new.bin").write_bytes(new.bytes())
    return folder, old


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
