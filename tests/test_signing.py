"""MAVLink 2 signing both ways over real UDP: the simulator checks with pymavlink's own signing
(as ArduPilot would), the station with gcs.mavlink.signing. With the key the signed vehicle is
fully usable; with a wrong key nothing is accepted and the rejections are counted; unsigned
packets are refused when signing is required, accepted and counted when optional; a pymavlink
client behind `--out` verifies the vehicle's original signatures; `gcs signing setup` keys a vehicle
and `--disable` switches its signing off."""

from __future__ import annotations

import asyncio
import hashlib
import socket
import sys

import pytest
from conftest import ROOT, free_port
from live import running_sim, running_station, wait_for
from pymavlink import mavutil

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.signing import Signing, SigningKeyError, key_from_file, key_from_passphrase, parse_key

KEY = hashlib.sha256(b"flight test 13").digest()
WRONG = hashlib.sha256(b"another vehicle").digest()


def _arm(sysid: int = 1) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_command_long_message(sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)


def _frame(packet: bytes) -> tuple[bytes, str]:
    """The packet and its type, as the link's framing gives them to the check."""
    ((packet, msg_type, _, _),) = MavlinkDecoder().frames(packet, final=True)
    return packet, msg_type


def test_keys_from_passphrase_and_files(tmp_path):
    assert key_from_passphrase("flight test 13") == KEY
    raw, text, bad = tmp_path / "raw.key", tmp_path / "hex.key", tmp_path / "bad.key"
    raw.write_bytes(KEY)
    text.write_text(KEY.hex() + "\n")
    bad.write_bytes(b"short")
    assert key_from_file(raw) == key_from_file(text) == parse_key(str(raw)) == KEY
    assert parse_key("flight test 13") == KEY  # not a file: a passphrase
    with pytest.raises(SigningKeyError, match="32 bytes or 64 hex digits"):
        key_from_file(bad)


def test_check_accepts_pymavlink_signatures_and_refuses_unsigned_forged_and_replayed():
    signer = Encoder(1, 1)
    Signing(KEY).sign_with(signer)
    first, second = signer.encode(_arm()), signer.encode(_arm())
    check = Signing(KEY)
    assert check.check(*_frame(first)) is None and check.check(*_frame(second)) is None
    assert check.check(*_frame(first)) == "old timestamp"  # replayed
    forged = bytearray(second)
    forged[-1] ^= 0xFF
    assert check.check(*_frame(bytes(forged))) == "bad signature"
    assert check.check(*_frame(Encoder(1, 1).encode(_arm()))) == "unsigned"
    radio = Encoder(51, 68).encode(mavlink.MAVLink_radio_status_message(200, 190, 50, 10, 5, 0, 0))
    assert check.check(*_frame(radio)) is None  # a SiK radio cannot sign its RADIO_STATUS
    assert check.counters.good == 2 and check.counters.radio_unsigned == 1
    assert check.counters.rejected == {"old timestamp": 1, "bad signature": 1, "unsigned": 1}
    optional = Signing(KEY, required=False)
    assert optional.check(*_frame(Encoder(1, 1).encode(_arm()))) is None
    assert optional.counters.accepted_unsigned == {"unsigned": 1}
    assert Signing(WRONG).check(*_frame(signer.encode(_arm()))) == "bad signature"


def test_signed_vehicle_with_the_key_is_fully_usable_and_refuses_an_unsigned_command(udp_port):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=KEY) as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False, signing_key=KEY) as station,
        ):
            assert await station.link.wait_connected(15)
            await wait_for(lambda: station.link.stats.rates().get("ATTITUDE", 0) > 40, 30, "ATTITUDE at 50 Hz")
            table = await station.params.download(60)
            assert {name: p.value for name, p in table.items()} == pytest.approx(sim.params.as_dict())
            assert sim.signature_rejected == 0
            # An unsigned ARM (a client that does not sign, sent on through the link): refused.
            station.link.send_raw(Encoder(255, 190).encode(_arm()))
            await wait_for(lambda: sim.signature_rejected >= 1, 5, "the vehicle refusing the unsigned command")
            assert not sim.armed
            station.link.send(_arm())  # the same command, signed by the station
            await wait_for(lambda: sim.armed, 5, "the vehicle arming on the signed command")
            return station.publish(), len(table)

    snapshot, count = asyncio.run(scenario())
    signing = snapshot.link.signing
    assert signing is not None and signing.required
    assert signing.good > 500 and signing.rejected == {} and signing.accepted_unsigned == {}
    assert snapshot.streams.messages["ATTITUDE"].method == "SET_MESSAGE_INTERVAL"
    assert count > 500


def test_wrong_key_nothing_accepted_and_rejections_counted(udp_port):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=KEY) as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False, signing_key=WRONG) as station,
        ):
            # a stretch of packets both ways, every one refused by the other side (3 of our 1 Hz
            # heartbeats by the vehicle), not a 4 s wait for a connection that must not come
            refused = station.link.signing.counters.rejected
            await wait_for(
                lambda: sim.signature_rejected >= 3 and refused.get("bad signature", 0) >= 4,
                30,
                "packets refused by each side",
            )
            return station.publish()

    snapshot = asyncio.run(scenario())
    signing = snapshot.link.signing
    assert signing is not None and signing.good == 0
    assert signing.rejected.get("bad signature", 0) >= 4  # the vehicle's heartbeats, at least
    assert snapshot.link.stats.counts == {} and snapshot.vehicle.heartbeats == 0  # framed, then refused
    assert snapshot.link.state != "connected"
    assert any("bad signature" in e.detail for e in snapshot.link.events)


@pytest.mark.parametrize("mode", ["required", "optional"])
def test_injected_unsigned_packets_refused_when_required_flagged_when_optional(udp_port, mode):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=KEY),
            running_station(
                f"udpin:127.0.0.1:{udp_port}", estimate=False, signing_key=KEY, signing_required=mode == "required"
            ) as station,
        ):
            assert await station.link.wait_connected(15)
            packets = [Encoder(1, 1).encode(_arm(255)) for _ in range(5)]
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as intruder:
                for packet in packets:
                    intruder.sendto(packet, ("127.0.0.1", udp_port))
            counters = station.link.signing.counters
            await wait_for(lambda: sum({**counters.rejected, **counters.accepted_unsigned}.values()) >= 5, 5, "5")
            return station.publish()

    snapshot = asyncio.run(scenario())
    signing, counts = snapshot.link.signing, snapshot.link.stats.counts
    if mode == "required":
        assert signing.rejected == {"unsigned": 5} and "COMMAND_LONG" not in counts
    else:
        assert signing.accepted_unsigned == {"unsigned": 5} and counts["COMMAND_LONG"] == 5
    assert signing.good > 10


def test_pymavlink_client_behind_out_verifies_the_vehicles_original_signatures(udp_port):
    out_port = free_port()

    async def scenario():
        client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{out_port}", dialect="all")
        try:
            async with (
                running_station(
                    f"udpin:127.0.0.1:{udp_port}",
                    estimate=False,
                    signing_key=KEY,
                    outputs=[f"udpout:127.0.0.1:{out_port}"],
                ) as station,
                running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=KEY),
            ):
                assert await station.link.wait_connected(15)
                seen: dict[str, int] = {}

                def read() -> bool:
                    while (msg := client.recv_match(blocking=False)) is not None:
                        seen[msg.get_type()] = seen.get(msg.get_type(), 0) + 1
                    return seen.get("HEARTBEAT", 0) >= 3 and seen.get("ATTITUDE", 0) >= 50

                # mavutil switches to its MAVLink 2 parser at the first MAVLink 2 packet: key that one
                await wait_for(lambda: client.recv_match(type="HEARTBEAT", blocking=False), 20, "a heartbeat")
                client.setup_signing(KEY, sign_outgoing=True)
                await wait_for(read, 20, "heartbeats and attitude at the client")
                return seen, client.mav.signing
        finally:
            client.close()

    seen, signing = asyncio.run(scenario())
    assert seen["HEARTBEAT"] >= 3 and "BAD_DATA" not in seen
    assert signing.goodsig_count >= 50 and signing.badsig_count == 0 and signing.unsigned_count == 0


def test_gcs_signing_setup_keys_the_vehicle(udp_port, tmp_path):
    async def scenario():
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gcs", "signing", "setup", "--connect", f"udpin:127.0.0.1:{udp_port}",
                "--signing-key", "flight test 13", cwd=ROOT,
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            out, err = await asyncio.wait_for(proc.communicate(), 60)
            return proc.returncode, out.decode(), err.decode(), sim.signing_key

    rc, out, err, key = asyncio.run(scenario())
    assert rc == 0, err
    assert "signing set up; its heartbeats are signed with this key" in out
    assert key == KEY


def test_mavsdk_behind_out_still_sees_the_signed_vehicle(udp_port):
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    out_port = free_port()

    async def scenario():
        connect = f"udpin:127.0.0.1:{udp_port}"
        out = [f"udpout:127.0.0.1:{out_port}"]
        async with (
            running_station(connect, estimate=False, signing_key=KEY, outputs=out) as station,
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=KEY),
        ):
            assert await station.link.wait_connected(15)
            cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
            async with Mavsdk(cfg) as mav:
                await mav.add_any_connection(f"udpin://127.0.0.1:{out_port}")
                system = await mav.first_autopilot(timeout_s=15.0)
                seen = []
                async for euler in TelemetryAsync(system).subscribe_attitude_euler():
                    seen.append(euler.roll_deg)
                    if len(seen) >= 20:
                        break
            return seen, station.outputs[0].snapshot()

    seen, out_status = asyncio.run(asyncio.wait_for(scenario(), 60))
    assert len(seen) == 20 and out_status.packets_out > 50


async def _signing_setup(udp_port: int, *extra: str) -> tuple[int | None, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "gcs", "signing", "setup", "--connect", f"udpin:127.0.0.1:{udp_port}",
        "--signing-key", "flight test 13", *extra, cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 60)
    return proc.returncode, out.decode(), err.decode()


def test_gcs_signing_setup_refuses_a_mavlink1_vehicle(udp_port):
    async def scenario():
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="apm25") as sim:
            rc, _, err = await _signing_setup(udp_port)
            return rc, err, sim.received.get("SETUP_SIGNING", 0)

    rc, err, received = asyncio.run(scenario())
    assert rc == 1 and "speaks only MAVLink 1" in err and received == 0


def test_gcs_signing_setup_fails_when_the_vehicle_keeps_another_key(udp_port):
    """A vehicle already signing with another key refuses the unsigned SETUP_SIGNING: the check of
    its heartbeats says so instead of claiming success."""

    async def scenario():
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", signing_key=WRONG) as sim:
            rc, _, err = await _signing_setup(udp_port, "--timeout", "3")
            return rc, err, sim.signing_key

    rc, err, key = asyncio.run(scenario())
    assert rc == 1 and "vehicle 1 sent no heartbeat signed with this key within 3 s after SETUP_SIGNING" in err
    assert key == WRONG


def test_gcs_signing_setup_disable_sends_the_zero_key_with_a_zero_timestamp(udp_port):
    """SETUP_SIGNING stops signing only with the all-zero key and a zero timestamp; with any other
    timestamp ArduPilot (and the simulator, which follows it) signs with the zero key, and `--disable`
    waited in vain for unsigned heartbeats (it sent the current time)."""

    async def scenario():
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim:
            rc, out, err = await _signing_setup(udp_port, "--disable", "--timeout", "10")
            return rc, out, err, sim.signing_key, sim.received.get("SETUP_SIGNING", 0)

    rc, out, err, key, received = asyncio.run(scenario())
    assert rc == 0, err
    assert "vehicle 1: signing switched off (its heartbeats are unsigned)" in out
    assert key is None and received >= 1
