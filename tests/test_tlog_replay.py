"""Every real .tlog goes through the link code with zero decode errors, and the count per
message type equals what pymavlink's own reader counts in the same file."""

from __future__ import annotations

import asyncio
import json
from collections import Counter

import pytest
from pymavlink import mavutil

from gcs.runtime.link import Link, LinkState

TLOGS = ["arducopter-sitl-hop.tlog", "arduplane-sitl-vtol.tlog"]


def pymavlink_counts(path) -> Counter:
    conn = mavutil.mavlink_connection(str(path), dialect="all")
    counts: Counter = Counter()
    while (msg := conn.recv_match()) is not None:
        counts[msg.get_type()] += 1
    return counts


def replay_counts(path) -> Link:
    async def run() -> Link:
        link = Link(str(path), speed=0)
        await asyncio.wait_for(link.run(), 120)
        return link

    return asyncio.run(run())


@pytest.mark.parametrize("name", TLOGS)
def test_tlog_through_link_matches_pymavlink(logs_dir, name):
    path = logs_dir / name
    link = replay_counts(path)
    expected = pymavlink_counts(path)
    f = link.stats.framing
    assert (f.crc_errors, f.malformed, f.bytes_skipped, f.unknown) == (0, 0, 0, 0)
    assert "BAD_DATA" not in expected
    assert Counter(link.stats.counts) == expected
    assert sum(expected.values()) > 1000
    assert link.state in (LinkState.CONNECTED, LinkState.LOST)  # it saw the vehicle's heartbeat
    assert link.target_system is not None


def test_tlog_replay_is_paced_by_its_timestamps(logs_dir):
    """At --speed 40 the 88 s recording takes at least 2 s: paced by its timestamps, not dumped."""
    import time

    path = logs_dir / "arducopter-sitl-hop.tlog"

    async def run(speed: float) -> float:
        link = Link(str(path), speed=speed)
        t0 = time.monotonic()
        await asyncio.wait_for(link.run(), 60)
        return time.monotonic() - t0

    paced = asyncio.run(run(40.0))
    assert paced >= 88 / 40 * 0.9


def test_gcs_status_on_a_tlog_sends_nothing_to_the_file(logs_dir, capsys):
    """A replayed .tlog is no vehicle: `gcs status` on one sends it no stream requests, no
    heartbeats, no version request (it sent 18 packets in 5 s before, and listed the requests as
    unanswered), and says why no streams were requested; the file's packets are all read."""
    from gcs.commands.cli import main

    path = logs_dir / "arducopter-sitl-hop.tlog"
    assert main(["status", "--connect", str(path), "--speed", "10", "--duration", "3", "--json"]) == 0
    status = json.loads(capsys.readouterr().out)
    stats = status["link"]["stats"]
    assert stats["packets"] > 1000 and stats["counts"]["HEARTBEAT"] > 0
    assert (stats["packets_out"], stats["bytes_out"]) == (0, 0)
    assert status["streams"] == {"method": None, "requests_sent": 0, "messages": {}}
    assert main(["status", "--connect", str(path), "--speed", "10", "--duration", "1"]) == 0
    assert "streams    none requested: a replayed file is no vehicle" in capsys.readouterr().out.splitlines()


def test_a_damaged_timestamp_does_not_stop_a_tlog_played_as_a_link(logs_dir, tmp_path):
    """`gcs status --connect flight.tlog --speed N` (or serve): one flipped bit put a record 68e9 s
    ahead and the link waited for it for ever, half the file unread and the vehicle "lost" (found
    by the audit). The record is sent at once and the pacing goes on from it."""
    import time

    from gcs.mavlink.tlog import read_tlog_records

    source = logs_dir / "arducopter-sitl-hop.tlog"
    data = bytearray(source.read_bytes())
    offsets = [offset for offset, _, _ in read_tlog_records(source).records()]
    stamp = offsets[len(offsets) // 2] - 8  # the record's 8-byte big-endian µs before its packet
    data[stamp : stamp + 8] = (int.from_bytes(data[stamp : stamp + 8], "big") ^ (1 << 56)).to_bytes(8, "big")
    path = tmp_path / "flipped-stamp.tlog"
    path.write_bytes(bytes(data))

    async def run() -> tuple[Link, float]:
        link = Link(str(path), speed=40.0)
        t0 = time.monotonic()
        await asyncio.wait_for(link.run(), 60)
        return link, time.monotonic() - t0

    link, took = asyncio.run(run())
    assert sum(link.stats.counts.values()) == len(offsets)
    assert 88 / 40 * 0.9 <= took <= 10  # paced before the bad stamp and after it
