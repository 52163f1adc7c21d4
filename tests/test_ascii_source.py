"""Seed 000's firmware as a source: its `pitch,yaw,roll` lines over a real pseudo-terminal, with
2 % of them damaged, through an ascii: link into the Station, the dashboard's API, the session
on disk and a replay of that session."""

from __future__ import annotations

import asyncio
import math
import time

import httpx
import numpy as np
import pytest
from live import wait_for

from gcs.mavlink.ascii import SEED000, AsciiAttitudeDecoder, AsciiFormat
from gcs.runtime.station import Station, StationConfig
from gcs.server.dashboard import DashboardServer
from gcs.sessions.contents import open_contents, replayed_attitude
from gcs.sim import SimVehicle
from gcs.sim.ascii import AsciiFirmware


def test_decoder_reads_seed000_lines_in_any_chunking_and_counts_bad_ones():
    clock = iter(np.arange(0.0, 10.0, 0.1))
    decoder = AsciiAttitudeDecoder(SEED000, clock=lambda: float(next(clock)))
    stream = b"10.00,-20.50,30.25\r\n12.3,4\r\nnan,1,2\r\n1,2,x\r\n1e40,0,0\r\n" + b"9" * 300 + b"\n-1.5,2,3\r\n"
    messages = [m for k in range(0, len(stream), 7) for m in decoder.feed(stream[k : k + 7])]
    attitudes = [m for m in messages if m.get_type() == "ATTITUDE"]
    assert [(round(math.degrees(m.pitch), 2), round(math.degrees(m.yaw), 2), round(math.degrees(m.roll), 2))
            for m in attitudes] == [(10.0, -20.5, 30.25), (-1.5, 2.0, 3.0)]  # fmt: skip
    assert decoder.counters.malformed == 5 and decoder.counters.packets == 2
    assert [m.get_type() for m in messages].count("HEARTBEAT") == 1  # one a second of stream
    assert attitudes[0].get_msgbuf()  # packed: the recorder writes it to the tlog as it is
    other = AsciiAttitudeDecoder(AsciiFormat.parse("roll,-,pitch,yaw", "rad"))
    (att,) = [m for m in other.feed(b"0.1,99,0.2,0.3\n") if m.get_type() == "ATTITUDE"]
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.1, 0.2, 0.3))
    with pytest.raises(ValueError, match="roll, pitch and yaw"):
        AsciiFormat.parse("pitch,yaw")


@pytest.mark.timeout(900)  # a cold numba cache compiles the kernels first (see _scenario)
def test_seed000_ascii_stream_over_pty_is_plotted_recorded_and_replayed(tmp_path):
    asyncio.run(_scenario(tmp_path))


async def _scenario(tmp_path):
    pty = tmp_path / "apm25"
    firmware = AsciiFirmware(SimVehicle(profile="apm25", script="bench", speed=2.0), rate_hz=25.0, malformed=0.02)
    served = asyncio.create_task(firmware.run(f"pty:{pty}"))
    await wait_for(pty.exists, 10, "the pseudo-terminal")
    station = Station(StationConfig(connect=f"ascii:{pty}", sessions_dir=str(tmp_path / "sessions"), record=True))
    await station.start()
    # lines printed before the station opened the port are not read (the pty has no reader yet)
    await wait_for(lambda: station.link.stats.framing.packets > 0, 20, "the first line", poll=0.01)
    early = firmware.lines, firmware.damaged
    server = DashboardServer(station, port=0, viser=False)
    await server.start()
    try:
        stats = station.link.stats.framing
        # 10 vehicle seconds: the bench script has turned to roll -30° and held it
        await wait_for(lambda: stats.packets >= 250 and stats.malformed >= 2, 60, "250 good lines and bad ones")
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api:
            # on a cold numba cache the estimation starts once its kernels are compiled (minutes on a
            # loaded machine; what arrives meanwhile waits): the history fills then
            deadline = time.monotonic() + 600
            while "onboard" not in (
                history := (await api.get("/api/history", params={"seconds": 60})).json()["points"]
            ):
                assert time.monotonic() < deadline, "no onboard history"
                await asyncio.sleep(0.2)
            status = (await api.get("/api/status")).json()
        t, roll, pitch, yaw = history["onboard"]
        assert len(t) >= 200 and min(roll) < -28.0  # plotted: the dashboard's store has the stream
        assert status["link"]["state"] == "connected" and status["link"]["malformed"] >= 2
        assert station.link.stats.packets_out == 0  # nothing written to a device that reads no MAVLink
        # and nothing asked of it: no stream shows as requested (each was, "via REQUEST_DATA_STREAM")
        assert status["link"]["stream_method"] is None and status["link"]["streams"] == {}, status["link"]
        served.cancel()
        await asyncio.gather(served, return_exceptions=True)
        # every line printed since the port was opened (and not refused by a full port buffer, which
        # a loaded machine's stalled reader can cause) is either read or counted as malformed
        printed, damaged = firmware.lines - firmware.lost, firmware.damaged - firmware.lost_damaged
        await wait_for(lambda: stats.packets + stats.malformed >= printed - early[0], 10, "the last lines")
        assert 0 <= printed - (stats.packets + stats.malformed) <= early[0]
        assert damaged - early[1] <= stats.malformed <= damaged
        assert 0.005 < firmware.damaged / firmware.lines < 0.05
        session = station.recorder.session.folder
    finally:
        served.cancel()
        await server.stop()
        await station.stop()
    contents = open_contents(session)
    recorded = contents.series("onboard")[:, :4]
    assert len(recorded) == stats.packets
    replayed = replayed_attitude(contents.source)  # decoded again from the session's tlog
    onboard = replayed.filter(replayed["source"].to_numpy(zero_copy_only=False) == "onboard")
    again = np.column_stack([onboard[c].to_numpy() for c in ("t", "roll", "pitch", "yaw")])
    np.testing.assert_array_equal(again, recorded)
