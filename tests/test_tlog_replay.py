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
