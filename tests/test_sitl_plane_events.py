"""The real ArduPlane SITL (../shared/sitl) armed and flown through mode changes, as a test day
starts: the session's event log (and so `gcs report`) says which mode the plane was in from the
first heartbeat and when it changed mode, armed and disarmed, in the order it happened. The
errors of a take-off or a turn are read against these; without them the report of a flight
through TAKEOFF, FBWA and RTL named no mode at all."""

from __future__ import annotations

import asyncio
import json

import pytest
from live import resend_until, running_station, wait_for
from test_sitl_copter import _command
from test_sitl_plane_streams import plane  # noqa: F401 (the fixture)

import gcs
from gcs.commands.cli import main
from gcs.mavlink.dialect import mavlink
from gcs.sessions import layout

pytestmark = pytest.mark.slow

#: ArduPlane's custom mode numbers.
MANUAL, FBWA = 0, 5


@pytest.mark.timeout(240)
def test_plane_mode_changes_and_arming_are_in_the_session_and_its_report(plane, tmp_path):  # noqa: F811
    record_dir = tmp_path / "sessions"

    async def scenario() -> None:
        async with running_station(
            f"tcp:127.0.0.1:{plane}", sessions_dir=str(record_dir), record=True, estimate=False
        ) as station:
            vehicle = station.vehicle
            # booted (INITIALISING, then MANUAL) and its RC input read, which sets the mode once more
            await wait_for(lambda: vehicle.mode == "MANUAL", 60, "MANUAL after the boot")
            await wait_for(lambda: any(m.text == "Throttle failsafe off" for m in vehicle.messages), 60, "RC input")
            await station.params.set("ARMING_CHECK", 0)

            def set_mode(mode: int) -> None:
                _command(station, mavlink.MAV_CMD_DO_SET_MODE, 1, mode)

            def arm(on: bool) -> None:
                _command(station, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, float(on))

            await resend_until(lambda: vehicle.custom_mode == FBWA, "FBWA", lambda: set_mode(FBWA))
            await resend_until(lambda: vehicle.armed, "arming", lambda: arm(True))
            await resend_until(lambda: not vehicle.armed, "disarming", lambda: arm(False))
            await resend_until(lambda: vehicle.custom_mode == MANUAL, "MANUAL", lambda: set_mode(MANUAL))

    asyncio.run(scenario())
    (folder,) = [p for p in record_dir.iterdir() if layout.is_session(p)]
    recorded = [json.loads(row) for row in gcs.open_session(folder).events["data"].to_pylist()]
    events = [e for e in recorded if e["kind"] == "vehicle" and e.get("event") in ("mode", "armed", "disarmed")]
    changes = [(e["event"], e["old"], e["new"]) if e["event"] == "mode" else (e["event"], e["mode"]) for e in events]
    modes = [(e["old"], e["new"]) for e in events if e["event"] == "mode"]
    assert modes and modes[0][0] is None and all(a[1] == b[0] for a, b in zip(modes, modes[1:])), modes  # one chain
    assert changes[-4:] == [
        ("mode", "MANUAL", "FBWA"),
        ("armed", "FBWA"),
        ("disarmed", "FBWA"),
        ("mode", "FBWA", "MANUAL"),
    ], changes
    report = tmp_path / "report.html"
    assert main(["report", str(folder), "--out", str(report)]) == 0
    assert "FBWA" in report.read_text()
