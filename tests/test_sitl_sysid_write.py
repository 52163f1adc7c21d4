"""`gcs params set MAV_SYSID N` against the real ArduCopter SITL (../shared/sitl): ArduPilot takes
its new system id at once and echoes the write as that system. The station, following the old id,
reported "no echo after 3 writes; the value on the vehicle is unknown" (exit 1) for a write that
had worked, the one the page and `gcs status` advise when two vehicles share an id."""

from __future__ import annotations

import asyncio
import sys

import pytest
from conftest import ROOT
from test_sitl_copter import sitl  # noqa: F401  (the fixture)

pytestmark = pytest.mark.slow


async def _gcs(*args: str) -> tuple[int | None, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "gcs", *args, cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
    )
    out, err = await asyncio.wait_for(proc.communicate(), 120)
    return proc.returncode, out.decode(), err.decode()


@pytest.mark.timeout(300)
def test_writing_the_vehicles_own_system_id_is_verified_by_its_echo_as_the_new_system(sitl):  # noqa: F811
    link = ["--connect", f"tcp:127.0.0.1:{sitl}"]

    async def scenario():
        written = await _gcs("params", "set", "MAV_SYSID", "7", *link)
        heard = await _gcs("status", *link, "--duration", "3", "--json")
        return written, heard

    (rc, out, err), (_, status, _) = asyncio.run(scenario())
    assert rc == 0, err
    assert out.strip() == "MAV_SYSID: 1 -> 7 (verified)"
    assert '"sysid": 7' in status  # the vehicle does answer as system 7 now
