"""The autopilot's long messages arrive whole: over MAVLink 2 ArduPilot sends a text longer than
STATUSTEXT's 50 characters as chunks of one id (here the simulator refusing a rate as ArduPlane
does, "Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE" in two). The vehicle
panel (/api/status) and the session's event log show the one line, never its two pieces."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, served_api, wait_for

from gcs.mavlink.statustext import CHUNK_CHARS, WAIT_S, StatusTextJoiner

REFUSAL = "Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE"


def test_a_chunked_statustext_reaches_the_page_and_the_event_log_as_one_line(udp_port):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", interval_limits={"RAW_IMU": 40.0}),
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
            served_api(station) as api,
        ):
            await wait_for(lambda: station.streams.requested, 30, "stream requests")

            def refusal_shown() -> bool:
                return any("ID 27" in m.text for m in station.publish().vehicle.messages)

            await wait_for(refusal_shown, 30, "the vehicle's refusal of 50 Hz RAW_IMU")
            status = (await api.get("/api/status")).json()
            return status["vehicle"]["messages"], [
                e.data["text"] for e in station.events.recent if e.kind == "statustext"
            ]

    shown, recorded = asyncio.run(scenario())
    texts = [m["text"] for m in shown]
    assert REFUSAL in texts, texts
    assert REFUSAL in recorded, recorded
    pieces = [t for t in texts + recorded if t != REFUSAL and (t in REFUSAL)]
    assert not pieces, pieces


def test_a_text_without_a_short_last_chunk_is_given_out_after_the_wait_and_a_lost_chunk_keeps_the_rest():
    """A text of exactly 100 characters has no short chunk to end it; a chunk may be lost."""
    joiner = StatusTextJoiner()
    exact = "x" * CHUNK_CHARS
    assert joiner.add(6, exact, 7, 0, now=10.0) == []
    assert joiner.add(6, exact, 7, 1, now=10.1) == []
    assert joiner.expire(10.1 + WAIT_S / 2) == []
    assert joiner.expire(10.0 + WAIT_S + 0.01) == [(6, exact * 2)]
    assert joiner.add(4, "a" * CHUNK_CHARS, 8, 0, now=20.0) == []
    # chunk 1 of text 8 lost: its first chunk comes out when chunk 2 arrives, which starts anew
    assert joiner.add(4, "b" * CHUNK_CHARS, 8, 2, now=20.1) == [(4, "a" * CHUNK_CHARS)]
    assert joiner.add(6, "short", 0, 0, now=20.2) == [(4, "b" * CHUNK_CHARS), (6, "short")]
