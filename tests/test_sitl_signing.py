"""MAVLink 2 signing against the real ArduCopter SITL (../shared/sitl): `gcs signing setup` over
SERIAL0 (ArduPilot's secure channel 0, where it takes unsigned packets) gives it the key; from then
on the vehicle signs everything it sends, a station with the key is fully usable (streams by
SET_MESSAGE_INTERVAL, parameters), and a station with a wrong key accepts nothing and counts why;
`gcs signing setup --disable` switches signing off again."""

from __future__ import annotations

import asyncio
import hashlib
import sys

import pytest
from conftest import ROOT
from live import running_station, wait_for
from test_sitl_copter import sitl  # noqa: F401  (the fixture)

pytestmark = pytest.mark.slow

PASSPHRASE = "flight test 13"
#: The vehicle's packets a station with the wrong key refuses before it is looked at: ~2.5 s of the
#: SITL's unrequested stream (~800 packets/s), so its 1 Hz heartbeats are among them; a count, not a
#: time, so the stretch is the same however slowly a loaded machine runs the SITL
REFUSED = 2000


@pytest.mark.timeout(240)
def test_arducopter_keyed_by_gcs_signing_setup_then_usable_only_with_the_key(sitl):  # noqa: F811
    connect = f"tcp:127.0.0.1:{sitl}"

    async def setup(*extra: str) -> tuple[int | None, str, str]:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "gcs", "signing", "setup", "--connect", connect, "--signing-key", PASSPHRASE,
            "--timeout", "60", *extra, cwd=ROOT,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out, err = await asyncio.wait_for(proc.communicate(), 120)
        return proc.returncode, out.decode(), err.decode()

    rc, out, err = asyncio.run(setup())
    assert rc == 0, (out, err)
    assert "signing set up; its heartbeats are signed with this key" in out

    async def with_key(key: bytes | None, right: bool):
        async with running_station(connect, estimate=False, signing_key=key) as station:
            if not right:  # a stretch of the vehicle's packets, each refused: the link never connects
                refused = station.link.signing.counters.rejected
                await wait_for(lambda: sum(refused.values()) >= REFUSED, 60, f"{REFUSED} packets refused")
                return station.publish(), None
            assert await station.link.wait_connected(20)
            await wait_for(lambda: station.link.stats.rates().get("ATTITUDE", 0) > 30, 30, "ATTITUDE streaming")
            value = (await station.params.read("SCHED_LOOP_RATE")).value
            return station.publish(), value

    good, loop_rate = asyncio.run(with_key(hashlib.sha256(PASSPHRASE.encode()).digest(), right=True))
    assert loop_rate == 400
    assert good.link.signing.good > 100 and good.link.signing.rejected == {}
    assert good.streams.messages["ATTITUDE"].method == "SET_MESSAGE_INTERVAL"

    wrong, nothing = asyncio.run(with_key(hashlib.sha256(b"not the key").digest(), right=False))
    print(f"\nwrong key: {wrong.link.signing}")
    assert nothing is None and wrong.vehicle.heartbeats == 0 and wrong.link.stats.counts == {}
    assert wrong.link.signing.good == 0 and wrong.link.signing.rejected.get("bad signature", 0) >= 3

    # the all-zero key with a zero timestamp: ArduPilot stops signing (with the current time as the
    # timestamp, as --disable sent before, it signed with the zero key and the command timed out)
    rc, out, err = asyncio.run(setup("--disable"))
    assert rc == 0, (out, err)
    assert "signing switched off (its heartbeats are unsigned)" in out
    unsigned, loop_rate = asyncio.run(with_key(None, right=True))
    assert loop_rate == 400 and unsigned.link.signing is None
