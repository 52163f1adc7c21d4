"""A parameter download cut short by a serial port that vanished (a USB cable pulled, the radio's
FTDI unplugged) says so: the station's fetch (the page's progress) and `gcs params save` reported
"no PARAM_VALUE after 3 PARAM_REQUEST_LIST" or "parameter download incomplete (each asked 5
times): 380 of 501 missing, indices ...", seconds later, as if the vehicle had ignored the
requests. Now the download stops when the link goes and names it, with how far it got. The
built-in simulator on a real pseudo-terminal, closed in the middle of its parameter list."""

from __future__ import annotations

import asyncio
import sys

from conftest import ROOT
from live import running_sim, running_station, wait_for

PARAMS = 501  # the apm25 simulator's table, streamed at 250 a second: two seconds of download


def _gone(path) -> set[str]:
    return {f"{path} closed: the device is gone ({why})" for why in ("end of file", "Input/output error")}


def test_the_stations_parameter_fetch_names_the_lost_link(tmp_path):
    path = tmp_path / "ttyUSB-sim"

    async def scenario():
        async with running_station(str(path), estimate=False, request_streams=False) as station:
            params = station.params
            async with running_sim(f"pty:{path}", profile="apm25"):
                assert await station.link.wait_connected(10)
                assert station.start_param_download()
                await wait_for(lambda: params.progress().get("received", 0) > 100, 20, "a hundred parameters")
            await wait_for(lambda: params.progress()["state"] == "incomplete", 20, "the download to stop")
            return params.progress()

    progress = asyncio.run(scenario())
    received = progress["received"]
    assert 100 < received < PARAMS
    assert progress["error"] in {
        f"parameter download cut short: the link was lost ({why}); {received} of {PARAMS} received"
        for why in _gone(path)
    }


def test_gcs_params_save_names_the_lost_link(tmp_path):
    path = tmp_path / "ttyUSB-sim"

    async def scenario():
        async with running_sim(f"pty:{path}", profile="apm25") as sim:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gcs", "params", "save", str(tmp_path / "all.param"), "--connect", str(path),
                cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            server = sim.param_server  # its queue: the parameters the vehicle has yet to send

            def sent() -> int:
                return PARAMS - len(server._queue) if server.next_due is not None else 0

            await wait_for(lambda: sent() > 100, 60, "a hundred parameters sent")
        out, err = await asyncio.wait_for(proc.communicate(), 60)
        return proc.returncode, out.decode(), err.decode()

    rc, out, err = asyncio.run(scenario())
    assert rc == 1, (out, err)
    assert err.startswith("gcs params save: error: parameter download cut short: the link was lost ("), err
    assert any(f"({why}); " in err for why in _gone(path)), err
    assert err.count("\n") == 1  # one line
    assert not (tmp_path / "all.param").exists()
