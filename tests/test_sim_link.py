"""The simulated vehicle on real pipes: a pseudo-terminal and a UDP socket; and `gcs sim`."""

from __future__ import annotations

import asyncio
import errno
import os
import socket
import subprocess
import sys
import time

import pytest

from gcs.commands.sim import parse_faults
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.sim import SimVehicle
from gcs.transport.pipes import make_transport


async def read_messages(fd: int, kinds: set[str], timeout: float = 30.0) -> list:
    """Read a non-blocking serial fd until every kind in `kinds` has arrived."""
    parser = mavlink.MAVLink(None)
    seen, got = set(), []
    deadline = time.monotonic() + timeout
    while not kinds <= seen and time.monotonic() < deadline:
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            await asyncio.sleep(0.01)
            continue
        for m in parser.parse_buffer(data) or []:
            seen.add(m.get_type())
            got.append(m)
    assert kinds <= seen, f"only got {seen}"
    return got


def slave_vanished(fd: int) -> bool:
    """True when reading the pty slave reports a hang-up (EIO or end of file), not just no data."""
    for _ in range(100):  # drain what the vehicle wrote before it closed
        try:
            if not os.read(fd, 4096):
                return True
        except BlockingIOError:
            return False
        except OSError as exc:
            return exc.errno == errno.EIO
    return False


def test_pty_serves_mavlink_vanishes_on_close_and_is_recreated(tmp_path):
    path = str(tmp_path / "ttySIM")

    async def scenario():
        for _attempt in range(2):  # the second run recreates the port at the same path
            sim = SimVehicle(profile="apm25", speed=5.0)
            task = asyncio.create_task(sim.run(f"pty:{path}"))
            deadline = time.monotonic() + 30
            while not os.path.islink(path):
                assert time.monotonic() < deadline, f"no pty at {path}"
                await asyncio.sleep(0.01)
            fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            try:
                await read_messages(fd, {"HEARTBEAT"})
                request = mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_RAW_SENSORS, 10, 1)
                os.write(fd, Encoder(255, 190, mavlink1=True).encode(request))
                await read_messages(fd, {"RAW_IMU"})
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
                assert not os.path.lexists(path)
                assert slave_vanished(fd)  # the "USB cable" is out: EIO on the slave
            finally:
                os.close(fd)

    asyncio.run(scenario())


def test_udp_smoke_vehicle_talks_to_a_ground_station_socket():
    async def scenario():
        received: list[bytes] = []
        gcs_side = make_transport("udpin:127.0.0.1:0")
        await gcs_side.open(received.append)
        sim = SimVehicle(profile="pixhawk", speed=4.0)
        task = asyncio.create_task(sim.run(f"udpout:127.0.0.1:{gcs_side.local_port}"))
        parser = mavlink.MAVLink(None)
        kinds: set[str] = set()
        requested = False
        deadline = time.monotonic() + 30  # a bound on a loaded machine: the loop ends at ATTITUDE
        while "ATTITUDE" not in kinds and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
            for data in received:
                kinds |= {m.get_type() for m in parser.parse_buffer(data) or []}
            received.clear()
            if "HEARTBEAT" in kinds and not requested:  # replies go back to the vehicle's socket
                command = mavlink.MAVLink_command_long_message(
                    1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE, 20000, 0, 0, 0, 0, 0
                )
                gcs_side.write(Encoder(255, 190).encode(command))
                requested = True
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        gcs_side.close()
        return kinds

    kinds = asyncio.run(scenario())
    assert {"HEARTBEAT", "COMMAND_ACK", "ATTITUDE"} <= kinds


def test_fault_options_parse_and_reject_nonsense():
    faults, drop, clamp = parse_faults(
        ["gyro_noise=0.01", "mag_hard_iron=0.1,0,-0.1", "param_drop=0.2", "param_clamp.ATC_RAT_RLL_P=0.5"]
    )
    assert faults.gyro_noise == 0.01 and faults.mag_hard_iron == (0.1, 0.0, -0.1)
    assert drop == 0.2 and clamp == {"ATC_RAT_RLL_P": 0.5}
    perfect, _, _ = parse_faults(["perfect=1", "vibration=0.5"])
    assert perfect.accel_noise == 0 and perfect.vibration == 0.5
    for bad in ("gyro_noise", "warp_drive=1", "param_drop=2", "mag_hard_iron=1,2"):
        with pytest.raises(ValueError, match="--fault"):
            parse_faults([bad])


def test_gcs_sim_command_prints_where_it_serves_and_stops_on_ctrl_c(tmp_path):
    path = tmp_path / "ttyCLI"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs", "sim", "--profile", "px4", "--script", "quad", "--link", f"pty:{path}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()  # printed once the link is open, i.e. the symlink made
        assert "px4" in line and f"pty:{path}" in line
        assert path.is_symlink()
        proc.send_signal(2)  # SIGINT, as Ctrl-C
        # A loaded machine can take seconds to start the interpreter's shutdown; the deadline
        # only bounds a hang.
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:  # an assertion above failed or it hung: never leak a `gcs sim`
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert not path.exists()


def _sim_serving(path) -> subprocess.Popen:
    """`gcs sim` serving pty:PATH, once it says so (the symlink is made by then)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs", "sim", "--link", f"pty:{path}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    line = proc.stdout.readline()
    if f"pty:{path}" not in line:  # it did not serve: never leak a `gcs sim`
        proc.kill()
        proc.communicate()
        pytest.fail(f"gcs sim did not serve pty:{path}: {line!r}")
    return proc


def _sim_refused(path) -> str:
    """stderr of a `gcs sim` on pty:PATH that must refuse it."""
    done = subprocess.run(
        [sys.executable, "-m", "gcs", "sim", "--link", f"pty:{path}"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    return done.stderr


def test_a_port_a_killed_vehicle_left_is_replaced_a_live_one_or_a_file_never(tmp_path):
    """`gcs sim` killed with SIGKILL leaves its link to a pseudo-terminal that is gone: the next
    one replaces it and serves. A link to a live vehicle's port and a regular file are refused,
    left as they were (a second vehicle took the first one's port over before)."""
    path = tmp_path / "ttyKILLED"
    first = _sim_serving(path)
    try:
        live_target = os.readlink(path)
        assert "which is open" in _sim_refused(path)
        assert os.readlink(path) == live_target
    finally:
        first.kill()  # SIGKILL: no clean-up
        first.communicate(timeout=60)
    assert path.is_symlink() and not path.exists()  # what it left: a link to a device that is gone
    second = _sim_serving(path)
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            asyncio.run(read_messages(fd, {"HEARTBEAT"}))
        finally:
            os.close(fd)
    finally:
        second.send_signal(2)
        second.communicate(timeout=60)
    assert not path.exists() and not path.is_symlink()  # a vehicle stopped cleanly takes its link away
    path.write_text("someone's file\n")
    assert "not a symlink" in _sim_refused(path)
    assert path.read_text() == "someone's file\n"


def test_gcs_sim_help_lists_profiles_scripts_links_and_faults():
    out = subprocess.run([sys.executable, "-m", "gcs", "sim", "--help"], capture_output=True, text=True).stdout
    for word in (
        "apm25",
        "pixhawk",
        "px4",
        "bench",
        "circuit",
        "quad",
        "udpout:",
        "tcpin:",
        "pty:",
        "gyro_noise",
        "param_drop",
        "param_clamp",
    ):
        assert word in out


def test_two_vehicles_feed_one_ground_station_port(udp_port):
    """The vehicle's udpout socket binds an ephemeral port: two vehicles can feed one GCS port."""

    async def scenario():
        sims = [SimVehicle(profile="px4", sysid=n) for n in (1, 2)]
        tasks = [asyncio.create_task(s.run(f"udpout:127.0.0.1:{udp_port}")) for s in sims]
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", udp_port))
        sock.setblocking(False)
        loop = asyncio.get_running_loop()
        systems = set()
        deadline = time.monotonic() + 30  # a bound on a loaded machine: the loop ends at both
        parser = mavlink.MAVLink(None)
        while systems != {1, 2} and time.monotonic() < deadline:
            try:
                data = await asyncio.wait_for(loop.sock_recv(sock, 4096), 0.5)
            except TimeoutError:
                continue
            systems |= {m.get_srcSystem() for m in parser.parse_buffer(data) or []}
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        sock.close()
        return systems

    assert asyncio.run(scenario()) == {1, 2}


def test_tcpin_serves_the_latest_client(tcp_port):
    async def scenario():
        sim = SimVehicle(profile="pixhawk", speed=4.0)
        task = asyncio.create_task(sim.run(f"tcpin:127.0.0.1:{tcp_port}"))
        deadline = time.monotonic() + 30
        while True:
            try:
                reader, writer = await asyncio.open_connection("127.0.0.1", tcp_port)
                break
            except OSError:
                assert time.monotonic() < deadline, "the simulator never listened"
                await asyncio.sleep(0.02)
        data = await asyncio.wait_for(reader.read(4096), 30)
        writer.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        return {m.get_type() for m in mavlink.MAVLink(None).parse_buffer(data) or []}

    assert "HEARTBEAT" in asyncio.run(scenario())


@pytest.mark.parametrize("link", ["bogus:1:2", "/dev/ttyUSB0"])
def test_gcs_sim_rejects_a_link_it_cannot_serve(link):
    done = subprocess.run(
        [sys.executable, "-m", "gcs", "sim", "--link", link], capture_output=True, text=True, timeout=20
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert link in done.stderr
