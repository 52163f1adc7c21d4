"""The columnar replay source: the inputs it hands back are the ones it was built from, bit for
bit; a flight's arrays stay small per IMU sample; the chunked .tlog reader finds every record,
its offset and the damage, across chunk boundaries."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from gcs.core.estimation import GainChange
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample
from gcs.logs.input_table import InputTableBuilder
from gcs.logs.tlog import read_tlog
from gcs.mavlink import tlog
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime import replay
from gcs.runtime.replay import ReplaySession
from gcs.sessions.sources import open_source


def same(a, b) -> bool:
    """Field by field, arrays by value and dtype, None kept None."""
    if type(a) is not type(b):
        return False
    for name in a.__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray)):
                return False
            if x.dtype != y.dtype or not np.array_equal(x, y):
                return False
        elif x != y or type(x) is not type(y):
            return False
    return True


def test_inputs_come_back_bit_for_bit(logs_dir):
    originals = list(read_tlog(str(logs_dir / "arducopter-sitl-hop.tlog")))
    originals += [
        ImuSample(1.0, np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, -9.8]), None, "IMU[1]"),
        GpsSample(2.0, 52.5, 13.4, 40.0, 3.0, 1.0, None, 2, "GPS"),
        GpsSample(2.5, 52.5, 13.4, 40.0, 3.0, 1.0, np.array([1.0, 2.0, 0.5]), 3, "GPS"),
        GainChange(None, "declination", 0.07),
        GainChange("dcm", "kp_rp", 0.3),
        AttitudeSample(3.0, 0.1, -0.2, 3.1, "onboard"),
    ]
    kinds = {type(item) for item in originals}
    assert kinds == {ImuSample, GpsSample, AttitudeSample, GainChange}
    assert any(isinstance(i, ImuSample) and i.mag is not None for i in originals)
    builder = InputTableBuilder()
    for item in originals:
        builder.append(item)
    table = builder.build()
    assert len(table) == len(originals)
    back = list(table.inputs())
    assert all(same(a, b) for a, b in zip(originals, back))
    middle = len(originals) // 2
    assert all(same(a, b) for a, b in zip(originals[middle:], table.inputs(middle)))
    refs = table.references()
    onboard = [i for i in originals if isinstance(i, AttitudeSample) and i.source == "onboard"]
    assert np.array_equal(refs["onboard"], [(i.t, i.roll, i.pitch, i.yaw) for i in onboard])


def test_a_flight_is_held_in_a_few_bytes_per_record_and_input(logs_dir):
    source = open_source(logs_dir / "arducopter-sitl-hop.tlog")
    records, inputs = len(source.frames), len(source.table)
    assert source.table.imu_count > 2000 and records == sum(source.counts.values())
    # a record: t, packet offset, sent, input end (25 bytes); an input: at most an IMU row of
    # 10 float64 + kind + source code (83 bytes). As objects it was about 650 bytes per IMU sample.
    assert source.nbytes <= 25 * records + 83 * inputs
    assert source.frames.offset is not None


def test_packets_are_read_back_from_the_file(logs_dir):
    path = logs_dir / "arducopter-sitl-hop.tlog"
    source = open_source(path)
    reader = source.open_packets()
    packets = [packet for _, packet in tlog.read_tlog_records(path)]
    try:
        assert [reader.packet(i) for i in (0, 1, 2, len(packets) - 1)] == [
            packets[0],
            packets[1],
            packets[2],
            packets[-1],
        ]
    finally:
        reader.close()


@pytest.mark.parametrize("chunk", [64, 1 << 20])
def test_chunked_tlog_reader_finds_records_offsets_and_damage(tmp_path, monkeypatch, chunk):
    monkeypatch.setattr(tlog, "CHUNK", chunk)
    encoder = Encoder(1, 1)
    packets = [encoder.encode(mavlink.MAVLink_attitude_message(k, 0.1 * k, 0.0, 0.0, 0.0, 0.0, 0.0)) for k in range(40)]
    data, offsets = bytearray(), []
    for k, packet in enumerate(packets):
        if k == 17:
            data += b"\x00garbage\x00"  # 9 bytes that are no record
        offsets.append(len(data) + 8)
        data += tlog.tlog_record(1_000_000 * k, packet)
    data += tlog.tlog_record(99, packets[0])[:-4]  # cut mid-record
    path = tmp_path / "damaged.tlog"
    path.write_bytes(bytes(data))

    records = tlog.read_tlog_records(path)
    found = list(records.records())
    assert [packet for _, _, packet in found] == packets
    assert [offset for offset, _, _ in found] == offsets
    assert [usec for _, usec, _ in found] == [1_000_000 * k for k in range(40)]
    assert records.skipped == 9 and records.damage_offsets == [offsets[17] - 8 - 9]
    assert records.truncated_at == offsets[-1] + len(packets[-1])


def test_seek_yields_to_the_loop_and_lands_where_a_straight_replay_is(logs_dir, monkeypatch):
    monkeypatch.setattr(replay, "CHUNK", 100)  # inputs between two yields
    source = open_source(logs_dir / "arducopter-sitl-hop.BIN")

    async def seek_while_ticking() -> tuple[int, bool, ReplaySession]:
        session = ReplaySession(source, speed=0, estimators=["dcm"])
        seek = asyncio.create_task(session.seek(60.0))
        ticks, seen_seeking = 0, False
        while not seek.done():
            ticks += 1
            seen_seeking |= session.snapshot().seeking
            await asyncio.sleep(0)
        await seek
        return ticks, seen_seeking, session

    ticks, seen_seeking, seeked = asyncio.run(seek_while_ticking())
    assert ticks > 10 and seen_seeking  # the loop ran other work while the estimators were rebuilt
    assert not seeked.snapshot().seeking and 59.9 <= seeked.snapshot().position_s <= 60.1
    straight = ReplaySession(source, speed=0, estimators=["dcm"])
    while straight.position < seeked.position:
        straight.step()
    assert straight.pipeline.imu_samples == seeked.pipeline.imu_samples > 0
    assert np.array_equal(straight.pipeline.estimators["dcm"].quaternion, seeked.pipeline.estimators["dcm"].quaternion)
    assert seeked.step() == straight.step()
