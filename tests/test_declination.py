"""Declination that follows the vehicle, with the World Magnetic Model as fallback: the simulator's
real field at home, a recording with and without COMPASS_DEC, the estimators' smooth re-reference."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from gcs.core.comparison import errors_against
from gcs.core.declination import decimal_year, wmm_declination
from gcs.core.estimation import GainChange
from gcs.core.estimators import registry
from gcs.mavlink.sampling import MessageInputs
from gcs.mavlink.tlog import tlog_record
from gcs.sessions.sources import open_source
from gcs.sim import Home, SimVehicle
from gcs.sim.sensors import SIM_DATE, SensorFaults, home_declination
from tests.synthetic import static

#: 2026-06-01 00:00 UTC: the wall clock the synthetic recordings are stamped with.
WALL0 = 1_780_272_000.0
D = math.radians


def test_wmm_matches_noaa_at_the_sim_home_and_canberra():
    # NOAA's own wmm-calculator 1.4.4 gives -8.8086° (Bogotá) and 12.6943° (Canberra) on 2026-11-24
    assert math.degrees(wmm_declination(4.6383, -74.0840, 2556.0, 2026.9)) == pytest.approx(-8.8086, abs=0.01)
    assert math.degrees(wmm_declination(-35.363261, 149.165230, 584.0, 2026.9)) == pytest.approx(12.6943, abs=0.01)
    assert decimal_year(WALL0) == pytest.approx(2026.413, abs=0.001)


def test_sim_field_uses_the_wmm_declination_at_home():
    sim = SimVehicle(profile="pixhawk")
    assert sim.faults.declination == pytest.approx(wmm_declination(4.6383, -74.0840, 2556.0, SIM_DATE))
    assert sim.params["COMPASS_DEC"] == pytest.approx(sim.faults.declination, abs=1e-6)
    canberra = SimVehicle(profile="pixhawk", home=Home(-35.363261, 149.165230, 584.0))
    assert math.degrees(canberra.faults.declination) == pytest.approx(12.7, abs=0.1)
    silent = SimVehicle(profile="pixhawk", publish_declination=False)
    assert "COMPASS_DEC" not in silent.params and silent.faults.declination == pytest.approx(home_declination(Home()))


def record(path, publish: bool, duration: float = 60.0) -> SimVehicle:
    """The bench script on a Pixhawk, streams at 50 Hz, as a .tlog with a 2026 wall clock; the ground
    station asks for COMPASS_DEC at 1 s, as the Station does at connect. No hard-iron offset: it
    turns the heading by ~1° (a compass calibration matter), which would hide the declination's part."""
    faults = SensorFaults(mag_hard_iron=(0.0, 0.0, 0.0))
    sim = SimVehicle(profile="pixhawk", script="bench", seed=3, faults=faults, publish_declination=publish)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    sim.handle_bytes(gcs.request_data_stream_encode(1, 1, mavlink.MAV_DATA_STREAM_ALL, 50, 1).pack(gcs))
    out = bytearray()
    t = 0.0
    while t < duration:
        t += 0.02
        if abs(t - 1.0) < 0.01:
            sim.handle_bytes(gcs.param_request_read_encode(1, 1, b"COMPASS_DEC", -1).pack(gcs))
        for packet in sim.advance(t):
            out += tlog_record(int((WALL0 + t) * 1e6) & ~3, packet)
    path.write_bytes(bytes(out))
    return sim


def yaw_error_after_convergence(path, ignore_declination: bool = False) -> dict[str, float]:
    """Median |yaw error| (deg) of every ground estimator against SIMSTATE over the last 40 s: the
    heading offset (the RMS also holds the lag while the bench turns, which is not the declination)."""
    source = open_source(path)
    pipeline = source.new_pipeline()
    series: dict[str, list] = {}
    for item in source.inputs():
        if ignore_declination and isinstance(item, GainChange):
            continue  # what gcs did with no COMPASS_DEC: yaw against magnetic north
        for p in pipeline.feed(item):
            series.setdefault(p.source, []).append(p)
    truth = np.array([(p.t, p.roll, p.pitch, p.yaw) for p in series["truth"]])
    out = {}
    for name in registry.names():
        est = np.array([(p.t, p.roll, p.pitch, p.yaw) for p in series[name]])
        err = errors_against(est, truth[truth[:, 0] > 20.0])
        out[name] = float(np.median(np.abs(err[:, 3])))
    return out


@pytest.mark.slow
def test_recording_without_compass_dec_gives_true_yaw_from_the_wmm(tmp_path):
    sim = record(tmp_path / "no-dec.tlog", publish=False)
    inputs = MessageInputs()
    changes = [c for c in _inputs_of(tmp_path / "no-dec.tlog", inputs) if isinstance(c, GainChange)]
    assert inputs.declination_source.startswith("WMM at 4.63")
    assert len(changes) == 1 and changes[0].value == pytest.approx(sim.faults.declination, abs=D(0.3))
    with_wmm = yaw_error_after_convergence(tmp_path / "no-dec.tlog")
    print("yaw vs truth with the WMM", with_wmm)
    assert all(rms < 1.0 for rms in with_wmm.values()), with_wmm
    without = yaw_error_after_convergence(tmp_path / "no-dec.tlog", ignore_declination=True)
    print("yaw vs truth against magnetic north", without)
    assert all(rms > 7.0 for rms in without.values()), without  # the old behaviour: ~8.6° off


@pytest.mark.slow
def test_the_vehicle_value_wins_over_the_wmm(tmp_path):
    sim = record(tmp_path / "dec.tlog", publish=True, duration=20.0)
    inputs = MessageInputs()
    changes = [c for c in _inputs_of(tmp_path / "dec.tlog", inputs) if isinstance(c, GainChange)]
    assert inputs.declination_source == "vehicle COMPASS_DEC"
    assert changes[-1].value == pytest.approx(sim.faults.declination, abs=1e-6)


def _inputs_of(path, inputs):
    from gcs.logs.tlog import read_tlog

    return list(read_tlog(str(path), inputs=inputs))


@pytest.mark.parametrize("name", ["dcm", "kf", "ekf"])
def test_a_declination_change_moves_yaw_smoothly_to_the_new_reference(name):
    """COMPASS_DEC arriving after GPS lock (12.7°): the yaw turns to it through the heading
    correction, without a jump, and settles on the new true-north yaw."""
    est = registry.create(name)
    samples = static(D(2), D(-3), D(40), rate=50.0, duration=60.0)
    yaws = []
    for k, s in enumerate(samples):
        if k == 500:  # 10 s in, converged on magnetic north
            est.set_gain("declination", D(12.7))
        est.update_imu(s)
        q = est.quaternion
        yaws.append(math.degrees(math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))))
    steps = np.abs(np.diff(yaws[500:]))
    assert yaws[499] == pytest.approx(40.0, abs=0.5)
    assert steps.max() < 2.0, f"{name} jumped {steps.max():.2f}° in one sample"
    assert yaws[-1] == pytest.approx(52.7, abs=0.5)


@pytest.mark.slow
def test_live_station_uses_the_wmm_records_it_and_replays_identically(tmp_path):
    """The real station on the real simulator (no COMPASS_DEC): the status says WMM, the session's
    event log records it, the station asked for the parameter again after GPS lock, and a replay
    of the recorded session gives the live comparison numbers exactly."""
    import asyncio
    import json

    from conftest import free_port
    from live import running_sim, running_station, wait_for

    from gcs.runtime.replay import ReplaySession
    from gcs.sessions import layout

    port = free_port()

    async def fly():
        async with running_station(f"udpin:127.0.0.1:{port}", sessions_dir=str(tmp_path), record=True) as station:
            inputs = station.estimation.inputs
            async with running_sim(
                f"udpout:127.0.0.1:{port}", profile="pixhawk", script="bench", speed=2.0, publish_declination=False
            ) as sim:
                await wait_for(lambda: inputs.declination_source.startswith("WMM"), 30, "the WMM declination")
                await wait_for(lambda: sim.received.get("PARAM_REQUEST_READ", 0) >= 4, 10, "asked again after lock")
                await wait_for(lambda: station.publish().estimation.declination_source.startswith("WMM"), 5, "status")
                expected = sim.faults.declination
            folder = station.recorder.session.folder
        return station.estimation.pipeline.summary(), folder, expected

    live, folder, expected = asyncio.run(fly())
    assert live["declination_rad"] == pytest.approx(expected, abs=D(0.3))
    events = [json.loads(line) for line in (folder / layout.EVENTS).read_text().splitlines()]
    recorded = [e for e in events if e["kind"] == "declination"]
    assert recorded and recorded[-1]["source"].startswith("WMM at 4.63")
    assert recorded[-1]["declination_rad"] == pytest.approx(live["declination_rad"])
    replay = ReplaySession(open_source(folder), speed=0)
    replay.run_to_end()
    offline = replay.pipeline.summary()
    assert offline["declination_rad"] == live["declination_rad"]
    for name in registry.names():
        a = json.dumps(live["estimators"][name]["comparison"], sort_keys=True)
        b = json.dumps(offline["estimators"][name]["comparison"], sort_keys=True)
        assert a == b, f"{name}: live and replay differ"


@pytest.mark.slow
def test_station_keeps_asking_until_the_vehicle_sets_its_declination():
    """ArduPilot sets COMPASS_DEC when it sets its home, seconds after the first 3D fix, and does
    not send it: a vehicle that answers 0 at the fix and sets its value later (without a word)
    has that value in the estimators a few seconds after, not the WMM's for the whole flight."""
    import asyncio

    from conftest import free_port
    from live import running_sim, running_station, wait_for

    port = free_port()

    async def fly() -> tuple[float | None, float]:
        async with running_station(f"udpin:127.0.0.1:{port}") as station:
            inputs = station.estimation.inputs
            async with running_sim(f"udpout:127.0.0.1:{port}", script="bench", speed=2.0) as sim:
                home_value = sim.params["COMPASS_DEC"]
                sim.params["COMPASS_DEC"] = 0.0  # a fresh ArduPilot before its home is set
                await wait_for(lambda: inputs.declination_source.startswith("WMM"), 30, "the WMM at the first fix")
                asked = sim.received.get("PARAM_REQUEST_READ", 0)
                sim.params["COMPASS_DEC"] = home_value + D(1.0)  # its home set: told to nobody
                await wait_for(lambda: inputs.declination_source == "vehicle COMPASS_DEC", 30, "the vehicle's value")
                assert sim.received.get("PARAM_REQUEST_READ", 0) > asked
                return inputs.declination, home_value + D(1.0)

    used, given = asyncio.run(fly())
    assert used == pytest.approx(given, abs=1e-6)
