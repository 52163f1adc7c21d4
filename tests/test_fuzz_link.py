"""No input stops the station: a real `gcs serve` is fed, over real UDP, every message type of
the dialect with random payloads and with inf, NaN and extreme values in every field, beside a
simulated vehicle sending good data from the same system id (and a binary and a garbled frame
on the WebSocket). Then only good data.

Asserted: the estimators resume within 1 s of good data (their points advance with the vehicle
clock again; timed from the last hostile packet, against the autopilot's own attitude, which
shows when good data got through the station's backlog); every /api/status, /api/estimates and
/api/history answer and every WebSocket frame, during and after, is strict JSON; the link counts
what it refused; the server's RSS stays bounded; its stderr holds no traceback; every station part still runs."""

from __future__ import annotations

import asyncio
import math
import os
import random
import re
import socket
import struct
import subprocess
import sys
import time

import httpx
import psutil
import websockets
from live import running_sim, stop_process, wait_for
from pymavlink.dialects.v20 import all as dialect
from pymavlink.generator.mavcrc import x25crc

from gcs.core.strict_json import loads as strict_loads
from gcs.server import wire
from gcs.transport.address import free_port

SEED = 11
SYSID, COMPID = 1, 1  # the simulated vehicle's own
ROUNDS = 4  # passes over the whole dialect, each in every mode
MODES = ("random", "nonfinite", "extreme")
FLOAT_SPECIALS = (math.nan, math.inf, -math.inf)
FLOAT_EXTREMES = (3.4028234663852886e38, -3.4028234663852886e38, 1e-45, -0.0, 1e30, -1e30)
RESUME_LIMIT_S = 1.0
BACKLOG_LIMIT_S = 10.0
RSS_GROWTH_LIMIT_MB = 150.0  # after warm-up, through the fuzz and the recovery
RSS_LIMIT_MB = 1500.0
#: The stretch of good data only, after the estimators resumed: points each estimator made on the
#: vehicle clock (3 s at 5 Hz, the radio budget's floor: the fuzz's RADIO_STATUS packets held the
#: streams there until that radio was taken to be gone, 5-8 s after the fuzz, when the station took
#: any RADIO_STATUS for a radio's; they come from the vehicle's ids, no radio's, and are ignored
#: now), and rounds of the JSON and RSS checks and WebSocket frames meanwhile
GOOD_SAMPLES = 15
GOOD_POLLS = 5
ESTIMATION_INPUTS = ("RAW_IMU", "HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "ATTITUDE", "AHRS2", "SIMSTATE")
REFUSING_TYPES = {"ATTITUDE", "AHRS2", "SIMSTATE", "HIGHRES_IMU", "PARAM_VALUE"}


def test_fuzzed_link_never_stops_the_station(tmp_path):
    udp_port, http_port, viser_port = free_port(), free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    err_path = tmp_path / "serve.err"
    with open(err_path, "w") as err, open(tmp_path / "serve.out", "w") as out:
        server = subprocess.Popen(
            [sys.executable, "-m", "gcs", "serve", "--connect", f"udpin:127.0.0.1:{udp_port}", "--no-record"]
            + ["--port", str(http_port), "--viser-port", str(viser_port)],
            stdout=out,
            stderr=err,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:
            report = asyncio.run(asyncio.wait_for(scenario(udp_port, http_port, server.pid), 150))
        finally:
            stop_process(server, 20)
    stderr = err_path.read_text()
    print(f"\nfuzz report: {report}")
    assert "Traceback" not in stderr and "exception" not in stderr.lower(), stderr[-4000:]
    # within 1 s of good data reaching the station, which its own attitude marks; the station's
    # delay in working through the hostile backlog only has to be finite
    assert report["resume_s"] - report["onboard_resume_s"] < RESUME_LIMIT_S, report
    assert report["resume_s"] < BACKLOG_LIMIT_S, report
    assert report["rss_peak_mb"] < RSS_LIMIT_MB, report
    assert report["rss_peak_mb"] - report["rss_warm_mb"] < RSS_GROWTH_LIMIT_MB, report
    assert REFUSING_TYPES <= set(report["nonfinite_rejected"]), report
    assert report["failed_parts"] == [], report
    assert report["json_answers"] > 10 and report["ws_frames"] > 50, report  # the checks ran


def frame(msgid: int, payload: bytes, seq: int) -> bytes:
    """A MAVLink 2 packet with a valid CRC, whatever the payload holds."""
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq, SYSID, COMPID, msgid & 0xFFFF, msgid >> 16)
    crc = x25crc(header[1:] + payload)
    crc.accumulate([dialect.mavlink_map[msgid].crc_extra])
    return header + payload + struct.pack("<H", crc.crc)


def slots(fmt: str) -> list[tuple[str, int, int]]:
    """(struct code, offset, size) of each scalar in a payload format; a char array is one slot."""
    out, offset = [], 0
    for count, code in re.findall(r"(\d*)([a-zA-Z])", fmt.lstrip("<")):
        n = int(count or 1)
        size = struct.calcsize("<" + code)
        if code == "s":
            out.append((code, offset, n))
            offset += n
            continue
        for _ in range(n):
            out.append((code, offset, size))
            offset += size
    return out


def payload(cls, mode: str, rng: random.Random) -> bytes:
    """Random bytes; in "nonfinite" mode every float is inf or NaN, in "extreme" mode every number
    is at a limit of its type (and every float at float32's)."""
    data = bytearray(rng.randbytes(cls.unpacker.size))
    for code, offset, size in slots(cls.unpacker.format):
        if code in "fd" and mode != "random":
            value = rng.choice(FLOAT_SPECIALS if mode == "nonfinite" else FLOAT_EXTREMES)
            struct.pack_into("<" + code, data, offset, value)
        elif code in "bBhHiIqQ" and mode == "extreme":
            data[offset : offset + size] = rng.choice((b"\xff", b"\x00", b"\x7f", b"\x80")) * size
    if cls.msgname == "PARAM_VALUE" and mode != "random":
        data[-1] = dialect.MAV_PARAM_TYPE_REAL32  # param_type: a real value, which must be finite
    return bytes(data)


def hostile_packets(rng: random.Random) -> list[bytes]:
    packets = []
    for _ in range(ROUNDS):
        for msgid, cls in sorted(dialect.mavlink_map.items()):
            for mode in MODES:
                packets.append(frame(msgid, payload(cls, mode, rng), len(packets) & 0xFF))
    rng.shuffle(packets)
    # the last hostile packets are the estimators' own inputs, so good data starts right after them
    for name in (*ESTIMATION_INPUTS, "GPS_RAW_INT"):
        cls = dialect.mavlink_map[getattr(dialect, f"MAVLINK_MSG_ID_{name}")]
        for mode in MODES:
            packets.append(frame(cls.id, payload(cls, mode, rng), len(packets) & 0xFF))
    return packets


async def scenario(udp_port: int, http_port: int, pid: int) -> dict:
    report: dict = {"json_answers": 0, "ws_frames": 0}
    process = psutil.Process(pid)
    rss: list[float] = []
    frames: list[tuple[float, dict]] = []  # (arrival, frame)
    base = f"http://127.0.0.1:{http_port}"
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        await wait_for_server(api)
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad") as sim:
            names = await wait_estimating(api)
            async with websockets.connect(f"ws://127.0.0.1:{http_port}/ws/live", max_size=None) as ws:
                reader = asyncio.create_task(read_frames(ws, frames, report))

                def alive(predicate):
                    """predicate, failing at once when the reader or the poller has stopped."""

                    def check() -> bool:
                        for task in (poller, reader):
                            if task.done():
                                task.result()  # what it found wrong (non-strict JSON, an error status)
                                raise AssertionError(f"{task.get_coro().__name__} stopped: the server closed")
                        return predicate()

                    return check

                await ws.send(bytes(range(256)))  # hostile input on the WebSocket too: binary, then not JSON
                await ws.send("{not json")
                poller = asyncio.create_task(poll_json(api, report, rss, process))
                await wait_for(alive(lambda: len(rss) >= 3), 30, "RSS samples after warm-up")
                report["rss_warm_mb"] = round(max(rss), 1)

                sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                packets = hostile_packets(random.Random(SEED))
                for i in range(0, len(packets), 25):  # ~5000 packets/s: hostile, not a flood
                    for p in packets[i : i + 25]:
                        sender.sendto(p, ("127.0.0.1", udp_port))
                    await asyncio.sleep(0.005)
                sender.close()
                ended, t_end = time.monotonic(), sim.t
                report["hostile_packets"] = len(packets)
                # estimator points the hostile IMU messages made (their random times are off the
                # vehicle clock): the fuzz reached the estimators, it was not all refused upstream
                report["estimates_off_clock"] = sum(
                    sum(1 for t in cols[0] if not 0 <= t < t_end + 10)
                    for _, f in frames
                    for source, cols in f.get("points", {}).items()
                    if source in names
                )

                def resumed(sources: set[str]) -> float | None:
                    """Seconds from the last hostile packet to the first frame by which every one
                    of `sources` has a point on the vehicle clock again."""
                    seen = set()
                    for arrival, f in frames:
                        if arrival < ended:
                            continue
                        for source, cols in f.get("points", {}).items():
                            if source in sources and any(t_end < t < t_end + 10 for t in cols[0]):
                                seen.add(source)
                        if seen == sources:
                            return arrival - ended
                    return None

                await wait_for(alive(lambda: resumed(names) is not None), 30, "every estimator back on the clock")
                report["resume_s"] = round(resumed(names) or math.inf, 3)
                # the same for the autopilot's own attitude, which no estimator computes: the
                # station's delay in working through the hostile backlog, for comparison
                await wait_for(alive(lambda: resumed({"onboard"}) is not None), 30, "onboard back on the clock")
                report["onboard_resume_s"] = round(resumed({"onboard"}) or math.inf, 3)
                # good data only, a stretch of it counted in estimates, not seconds: JSON, RSS and
                # parts keep being checked meanwhile
                t_good, answers, ws_frames, good_from = sim.t, report["json_answers"], report["ws_frames"], len(frames)

                def estimated_since() -> int:
                    """The fewest points any estimator has on the vehicle clock after t_good."""
                    counts = dict.fromkeys(names, 0)
                    for _, f in frames[good_from:]:
                        for source, cols in f.get("points", {}).items():
                            if source in counts:
                                counts[source] += sum(1 for t in cols[0] if t_good < t < t_good + 120)
                    return min(counts.values())

                await wait_for(
                    alive(
                        lambda: (
                            estimated_since() >= GOOD_SAMPLES
                            and report["json_answers"] >= answers + 3 * GOOD_POLLS
                            and report["ws_frames"] >= ws_frames + GOOD_POLLS
                        )
                    ),
                    60,
                    f"{GOOD_SAMPLES} samples estimated by each estimator, {GOOD_POLLS} polls and frames",
                    poll=0.2,
                )
                report["good_stretch_s"] = round(sim.t - t_good, 2)  # of the vehicle's clock
                alive(lambda: True)()
                poller.cancel()
                reader.cancel()
                await asyncio.gather(poller, reader, return_exceptions=True)
        status = strict_loads((await api.get("/api/status")).content)
    report["rss_peak_mb"] = round(max(rss), 1)
    report["nonfinite_rejected"] = status["link"]["nonfinite_rejected"]
    report["refused_inputs"] = status["refused_inputs"]
    report["estimator_restarts"] = status["estimator_restarts"]
    report["failed_parts"] = [p for p in status["parts"] if p["state"] != "running"]
    return report


async def wait_for_server(api: httpx.AsyncClient) -> None:
    deadline = time.monotonic() + 60
    while True:
        try:
            if (await api.get("/api/status")).status_code == 200:
                return
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, "gcs serve did not answer within 60 s"
        await asyncio.sleep(0.2)


async def wait_estimating(api: httpx.AsyncClient) -> set[str]:
    """The estimator names, once each has a latest attitude."""
    deadline = time.monotonic() + 60
    while True:
        status = strict_loads((await api.get("/api/status")).content)
        names = set(status["estimators"])
        sources = strict_loads((await api.get("/api/estimates")).content)["sources"]
        if names and names <= set(sources):
            return names
        assert time.monotonic() < deadline, f"estimators never produced an attitude: {sources}"
        await asyncio.sleep(0.2)


async def read_frames(ws, frames: list, report: dict) -> None:
    """Every frame as {"points": {source: [t...]}} or the control message; a NaN or an infinity
    (a JSON token or a float in a binary frame) raises: the task's exception fails the test."""
    async for message in ws:
        report["ws_frames"] += 1
        arrival = time.monotonic()
        if isinstance(message, str):
            frames.append((arrival, strict_loads(message)))
            continue
        for f in wire.decode(message):
            if isinstance(f, wire.PointsFrame):
                f = {"points": {source: [list(cols[0])] for source, cols in f.points.items()}}
            frames.append((arrival, f))


async def poll_json(api: httpx.AsyncClient, report: dict, rss: list, process: psutil.Process) -> None:
    while True:
        for path in ("/api/status", "/api/estimates", "/api/history?seconds=5"):
            answer = await api.get(path)
            assert answer.status_code == 200, (path, answer.status_code, answer.text[:500])
            strict_loads(answer.content)
            report["json_answers"] += 1
        rss.append(process.memory_info().rss / 2**20)
        await asyncio.sleep(0.2)


def test_rest_answers_are_strict_json_even_for_values_no_model_declares():
    """FastAPI's own encoder cleans only the floats a response model declares; the app's
    response class cleans the rest (free-form health dicts, routes without a model)."""
    from gcs.server.app import StrictJSONResponse

    body = StrictJSONResponse({"health": {"innovation": math.inf}, "lag_s": math.nan}).body
    assert strict_loads(body) == {"health": {"innovation": None}, "lag_s": None, "nonfinite": 2}
