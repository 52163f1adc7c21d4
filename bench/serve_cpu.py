"""CPU of `gcs serve` per 1000 msg/s, and the loss-free knee, against a bare pymavlink loop (and
MAVProxy when it is installed) on the same stream, in one run.

Stream (bench.serve_cpu sender, its own process, over UDP to 127.0.0.1): PX4-like, HIGHRES_IMU
400 : ATTITUDE 100 : GPS_RAW_INT 5 : HEARTBEAT 1, scaled to the total rate asked for (vehicle
time advances at the scaled rate too), paced every 5 ms; the vehicle turns at YAW_RATE (until
2026-12-04's sixth session it stood still, and the 3-D view had nothing to draw).
- ours: `gcs serve` (3 estimators, recording to a temporary folder, the 3-D view) with 5 pages'
  traffic: 5 clients polling what the page polls (`GET /api/status` and `GET /api/estimates` every
  second, `GET /api/vehicles` every 2 s; until 2026-12-04's tenth session only the status), 5
  `/ws/live` WebSocket clients (bench.ws_clients) and, as each page's iframe, 5 viewers of the 3-D
  view on viser's WebSocket (bench.viser_clients; GCS_BENCH_3D=0 leaves them out, as the figures
  before 2026-12-04's sixth session did), each kind in its own process. GCS_BENCH_PAGES=N: N pages
  (default 5; 0: nobody watching, the station's own work alone).
  `view_windows_per_viewer_s`: the windows of viser messages each viewer received a second (one
  per drawing: at most 20 for 5 viewers since the seventh session's drawing budget,
  gcs.server.pose_refresh, 30 before; ~16 since the ninth session's 15 ms frames, the turns the
  drawings land on).
- baseline `pymavlink`: a bare receive loop (socket recv + `MAVLink.parse_buffer` + `get_type`).
- baseline `MAVProxy` (`mavproxy.py` from $GCS_BENCH_MAVPROXY, else PATH; not a dependency of
  gcs: `python -m venv /tmp/mavproxy-venv && /tmp/mavproxy-venv/bin/pip install MAVProxy`):
  `mavproxy.py --master udpin:... --daemon --non-interactive` with its default logging (mav.tlog);
  what it received is counted from the raw log it writes (mav.tlog.raw).
CPU: psutil user+system time of the receiving process over MEASURE_S s after WARMUP_S, per
1000 msg/s sent; the median of ROUNDS alternating rounds of the three receivers; for ours also
its main thread alone (`ours_main_thread_pct`: the event loop). Ours and the bare loop again at
SLOPE_RATE in each round: the line through the two rates splits each one's CPU into µs per message
and a fixed part (% of a core whatever arrives: the turns, the pages), which shows what the ratio at
CPU_RATE is made of. Ours again with one page and with none at CPU_RATE in each round,
against the same rounds' PAGES pages: fewer pages should cost no more (until 2026-12-05 one page
cost 1.6× five: its frames, and so the link's reads, came every 4 ms).
Knee: the highest rate of RATES at which the receiver counted every packet sent.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import psutil

from gcs.transport.address import free_port

WARMUP_S = 8.0
MEASURE_S = 10.0
RATES = (1_000, 2_000, 5_000, 10_000, 20_000)
CPU_RATE = 1_000
#: a second rate the CPU is measured at, ours and bare: the two rates split each receiver's CPU into
#: what each message costs (the slope) and what it costs whatever arrives (the turns, the pages)
SLOPE_RATE = 5_000
#: alternating rounds of the CPU figures (GCS_BENCH_ROUNDS)
ROUNDS = int(os.environ.get("GCS_BENCH_ROUNDS", "3"))
#: dashboard pages (GCS_BENCH_PAGES; 0: `gcs serve` estimating and recording with nobody watching,
#: to see what the pages cost against the station's own work)
PAGES = int(os.environ.get("GCS_BENCH_PAGES", "5"))
#: what each page asks for, and every how many seconds: dashboard.js's pollStatus, vehicles.js's
#: vehicle list
PAGE_POLLS = (("/api/status", 1), ("/api/estimates", 1), ("/api/vehicles", 2))
#: each page's 3-D view too (a real page's iframe); GCS_BENCH_3D=0: the pages' plots and status only
VIEWS_3D = os.environ.get("GCS_BENCH_3D", "1") != "0"
MIX = (("HIGHRES_IMU", 400), ("ATTITUDE", 100), ("GPS_RAW_INT", 5), ("HEARTBEAT", 1))
#: rad/s the bench vehicle turns about its vertical axis
YAW_RATE = 0.5


def stream_message(name: str, us: int) -> Any:
    """One message of the mix at vehicle time `us` (µs): a level vehicle turning at YAW_RATE, its
    gyro, accelerometer, magnetometer and attitude agreeing (a still one left the 3-D view
    nothing to draw, and the estimators' outputs never moved)."""
    from gcs.mavlink.dialect import mavlink

    yaw = 0.3 + YAW_RATE * us / 1e6
    if name == "HIGHRES_IMU":  # the earth field (0.21, 0.02, 0.42) gauss seen from the turned body
        c, s = math.cos(yaw), math.sin(yaw)
        mag_x, mag_y = c * 0.21 + s * 0.02, -s * 0.21 + c * 0.02
        return mavlink.MAVLink_highres_imu_message(
            us, 0.05, -0.03, -9.8, 0.01, -0.02, YAW_RATE, mag_x, mag_y, 0.42, 1000.0, 0.0, 0.0, 25.0, 0x1FFF, 0
        )
    if name == "ATTITUDE":
        return mavlink.MAVLink_attitude_message(
            us // 1000, 0.01, -0.02, math.remainder(yaw, math.tau), 0.01, -0.02, YAW_RATE
        )
    if name == "GPS_RAW_INT":
        return mavlink.MAVLink_gps_raw_int_message(us, 3, 523000000, 134000000, 50000, 100, 100, 500, 9000, 12)
    return mavlink.MAVLink_heartbeat_message(2, 12, 81, 0, 4, 3)


def packets(rate: int, seconds: float) -> list[tuple[float, bytes]]:
    """(send time from start, packet) for `seconds` of the mix at `rate` msg/s in all."""
    from gcs.mavlink.dialect import Encoder

    enc = Encoder(1, 1)
    scale = rate / sum(hz for _, hz in MIX)
    out: list[tuple[float, bytes]] = []
    for name, hz in MIX:
        period = 1.0 / (hz * scale)
        for k in range(int(seconds / period)):
            us = int(k * 1e6 / hz)  # the vehicle's own clock at the mix's nominal rate
            out.append((k * period, enc.encode(stream_message(name, us))))
    out.sort(key=lambda p: p[0])
    return out


def send(port: int, rate: int, seconds: float) -> int:
    """Send the stream; returns the packets sent."""
    stream = packets(rate, seconds)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    start = time.monotonic()
    i = 0
    while i < len(stream):
        now = time.monotonic() - start
        while i < len(stream) and stream[i][0] <= now:
            sock.sendto(stream[i][1], ("127.0.0.1", port))
            i += 1
        time.sleep(0.005)
    return len(stream)


def bare_loop(port: int, seconds: float) -> None:
    """The baseline receiver: prints the packets it parsed."""
    from pymavlink.dialects.v20 import common

    mav = common.MAVLink(None)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(0.5)
    n, deadline = 0, time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        for m in mav.parse_buffer(data) or ():
            m.get_type()
            n += 1
    print(n, flush=True)


def cpu_of(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    total = t.user + t.system
    for child in proc.children(recursive=True):
        try:
            c = child.cpu_times()
            total += c.user + c.system
        except psutil.NoSuchProcess:
            pass
    return total


def run_sender(port: int, rate: int, seconds: float) -> subprocess.Popen:
    code = f"from bench.serve_cpu import send; print(send({port}, {rate}, {seconds}))"
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)


def http_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def pollers(base: str, seconds: float, pages: int = PAGES) -> subprocess.Popen:
    """`pages` clients asking for what a dashboard page polls (PAGE_POLLS), in one process."""
    code = (
        "import time, threading, urllib.request\n"
        f"end = time.monotonic() + {seconds}\n"
        "def poll():\n"
        "    k = 0\n"
        "    while time.monotonic() < end:\n"
        f"        for path, every in {PAGE_POLLS!r}:\n"
        f"            if k % every == 0: urllib.request.urlopen({base!r} + path, timeout=10).read()\n"
        "        k += 1; time.sleep(1.0)\n"
        f"ts = [threading.Thread(target=poll) for _ in range({pages})]\n"
        "[t.start() for t in ts]; [t.join() for t in ts]\n"
    )
    return subprocess.Popen([sys.executable, "-c", code])


def wait_until_serving(base: str, timeout: float = 120) -> None:
    """Until `gcs serve` at base answers GET /api/status."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            http_json(f"{base}/api/status")
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def serve(rate: int, seconds: float, measure: bool, pages: int = PAGES) -> dict:
    port, http = free_port(), free_port()
    with tempfile.TemporaryDirectory() as tmp:
        # GCS_BENCH_PROFILE=FILE: the server under cProfile, written at its clean stop
        profile = ["-m", "cProfile", "-o", os.environ["GCS_BENCH_PROFILE"]] if "GCS_BENCH_PROFILE" in os.environ else []
        server = subprocess.Popen(
            [sys.executable, *profile, "-m", "gcs", "serve", "--connect", f"udpin:127.0.0.1:{port}",
             "--port", str(http), "--record-dir", tmp, "--token", "bench"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        proc = psutil.Process(server.pid)
        base = f"http://127.0.0.1:{http}"
        wait_until_serving(base)
        time.sleep(2.0)  # the estimators' kernels load
        helpers = []
        if pages:
            helpers.append(pollers(base, seconds + 2, pages))
            live_url = f"ws://127.0.0.1:{http}/ws/live"
            clients = [sys.executable, "-m", "bench.ws_clients", live_url, str(pages), str(seconds)]
            helpers.append(subprocess.Popen(clients, stdout=subprocess.DEVNULL))
        views = None
        if VIEWS_3D and pages:
            viser_url = f"ws://127.0.0.1:{http_json(f'{base}/api/status')['viser_port']}"
            views = subprocess.Popen(
                [sys.executable, "-m", "bench.viser_clients", viser_url, str(pages), str(seconds)],
                stdout=subprocess.PIPE,
                text=True,
            )
        sender = run_sender(port, rate, seconds)
        result = measure_cpu(proc, sender, seconds) if measure else {}
        sent = int(sender.communicate()[0])
        for h in helpers:
            h.wait(30)
        # the 3-D view's drawings each viewer got per second (messages: one window of viser's each)
        view_hz = [m / seconds for m, _ in json.loads(views.communicate(timeout=30)[0])] if views else []
        server.send_signal(signal.SIGINT)  # as Ctrl-C: a clean stop (and a profile written)
        server.wait(60)
        received = vehicle_packets_recorded(tmp)
    return {**result, "sent": sent, "received": received, "view_hz": view_hz}


def vehicle_packets_recorded(record_dir: str) -> int:
    """The sender's packets (system 1) in the session `gcs serve` recorded: what it received. The
    status's link.packets is the vehicle's own count, which leaves out what came before its first
    heartbeat (3 packets of this stream), and would read as a loss."""
    from gcs.mavlink.tlog import read_tlog_records
    from gcs.sessions import layout

    (session,) = [folder for folder in Path(record_dir).iterdir() if layout.is_session(folder)]
    return sum(1 for _, raw in read_tlog_records(session / layout.TLOG) if raw[3 if raw[0] == 0xFE else 5] == 1)


def main_thread_cpu(proc: psutil.Process) -> float:
    """CPU seconds of the process's main thread (the station's event loop in `gcs serve`)."""
    return next((t.user_time + t.system_time for t in proc.threads() if t.id == proc.pid), 0.0)


def measure_cpu(proc: psutil.Process, sender: subprocess.Popen, seconds: float) -> dict:
    """Core fraction of the receiver (with its children) over the measured window, and of its
    main thread alone."""
    time.sleep(min(WARMUP_S, seconds / 3))
    c0, m0, t0 = cpu_of(proc), main_thread_cpu(proc), time.monotonic()
    time.sleep(min(MEASURE_S, seconds / 2))
    c1, m1, t1 = cpu_of(proc), main_thread_cpu(proc), time.monotonic()
    return {"cpu": (c1 - c0) / (t1 - t0), "main_thread_cpu": (m1 - m0) / (t1 - t0)}


def bare(rate: int, seconds: float, measure: bool) -> dict:
    port = free_port()
    code = f"from bench.serve_cpu import bare_loop; bare_loop({port}, {seconds + 3})"
    receiver = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    time.sleep(1.5)
    sender = run_sender(port, rate, seconds)
    result = measure_cpu(psutil.Process(receiver.pid), sender, seconds) if measure else {}
    sent = int(sender.communicate()[0])
    received = int(receiver.communicate()[0])
    return {**result, "sent": sent, "received": received}


def mavproxy_exe() -> str | None:
    return os.environ.get("GCS_BENCH_MAVPROXY") or shutil.which("mavproxy.py")


def mavproxy(rate: int, seconds: float, measure: bool = True) -> dict:
    from pymavlink.dialects.v20 import common

    exe = mavproxy_exe()
    assert exe is not None
    port = free_port()
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.Popen(
            [exe, f"--master=udpin:127.0.0.1:{port}", "--daemon", "--non-interactive", f"--state-basedir={tmp}"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, cwd=tmp,
        )  # fmt: skip
        time.sleep(5.0)
        sender = run_sender(port, rate, seconds)
        result = measure_cpu(psutil.Process(proc.pid), sender, seconds) if measure else {}
        sent = int(sender.communicate()[0])
        time.sleep(1.0)
        proc.terminate()
        proc.wait(30)
        raw = os.path.join(tmp, "mav.tlog.raw")
        with open(raw, "rb") as f:
            received = len(common.MAVLink(None).parse_buffer(f.read()) or ())
    return {**result, "sent": sent, "received": received}


def cpu_rounds(seconds: float, rounds: int) -> dict[str, list[float]]:
    """Core fraction of each receiver in `rounds` alternating rounds (ours, bare, MAVProxy when
    installed): one 10 s window swings by ±30 % on a shared machine, so each figure is the median
    of its rounds, and each ratio the median of the rounds' own ratios."""
    cpu: dict[str, list[float]] = {
        "serve": [], "serve_main": [], "pymavlink": [], "MAVProxy": [], "view_hz": [],
        "serve_slope_rate": [], "pymavlink_slope_rate": [], "serve_one_page": [], "serve_no_page": [],
    }  # fmt: skip
    for _ in range(rounds):
        served = serve(CPU_RATE, seconds, True)
        cpu["serve"].append(served["cpu"])
        cpu["serve_main"].append(served["main_thread_cpu"])
        cpu["view_hz"] += served["view_hz"]
        cpu["pymavlink"].append(bare(CPU_RATE, seconds, True)["cpu"])
        if mavproxy_exe():
            cpu["MAVProxy"].append(mavproxy(CPU_RATE, seconds)["cpu"])
        cpu["serve_slope_rate"].append(serve(SLOPE_RATE, seconds, True)["cpu"])
        cpu["pymavlink_slope_rate"].append(bare(SLOPE_RATE, seconds, True)["cpu"])
        cpu["serve_one_page"].append(serve(CPU_RATE, seconds, True, pages=1)["cpu"])
        cpu["serve_no_page"].append(serve(CPU_RATE, seconds, True, pages=0)["cpu"])
    return cpu


def per_message_and_fixed(at_cpu_rate: list[float], at_slope_rate: list[float]) -> dict[str, float]:
    """A receiver's CPU as fixed + per message (the line through its medians at the two rates):
    µs of a core per message, and % of a core whatever arrives."""
    low, high = statistics.median(at_cpu_rate), statistics.median(at_slope_rate)
    per_message = (high - low) / (SLOPE_RATE - CPU_RATE)
    fixed = low - per_message * CPU_RATE
    return {"us_per_message": round(1e6 * per_message, 1), "fixed_core_pct": round(100 * fixed, 1)}


def main() -> list[dict]:
    seconds = WARMUP_S + MEASURE_S + 2.0
    cpu = cpu_rounds(seconds, ROUNDS)
    per_k = CPU_RATE / 1000

    def pct(values: list[float]) -> float:
        return round(100 * statistics.median(values) / per_k, 1)

    def ratio_of(ours: str, baseline: str) -> float:
        return round(statistics.median(o / b for o, b in zip(cpu[ours], cpu[baseline], strict=True)), 2)

    def ratio(baseline: str) -> float:
        return ratio_of("serve", baseline)

    rows = [
        {
            "benchmark": f"serve CPU per 1000 msg/s ({PAGES} pages: status polls + /ws/live"
            + (" + 3-D view)" if VIEWS_3D else ")"),
            "baseline": "bare pymavlink receive loop",
            "rounds": ROUNDS,
            "baseline_core_pct": pct(cpu["pymavlink"]),
            "ours_core_pct": pct(cpu["serve"]),
            "ours_core_pct_each": [round(100 * c / per_k, 1) for c in cpu["serve"]],
            # the event loop's thread (link, estimation, hub, pages); the rest: viser's thread,
            # the recording's writer
            "ours_main_thread_pct": pct(cpu["serve_main"]),
            "ratio": ratio("pymavlink"),
            "view_windows_per_viewer_s": round(statistics.median(cpu["view_hz"]), 1) if cpu["view_hz"] else None,
            "target": "≤ 15 % and ≤ 2× bare",
            "load_avg_1m": round(os.getloadavg()[0], 2),
        }
    ]
    if cpu["MAVProxy"]:
        row = {
            "baseline_core_pct": pct(cpu["MAVProxy"]),
            "ratio_ours_to_it": ratio("MAVProxy"),
            "target": "≤ 0.33",
        }
    else:
        row = {"note": "mavproxy.py not found (GCS_BENCH_MAVPROXY or PATH)"}
    rows.append({"benchmark": "MAVProxy CPU per 1000 msg/s", "baseline": "MAVProxy --daemon, default logging"} | row)
    ours = per_message_and_fixed(cpu["serve"], cpu["serve_slope_rate"])
    theirs = per_message_and_fixed(cpu["pymavlink"], cpu["pymavlink_slope_rate"])
    slope_k = SLOPE_RATE / 1000
    rows.append(
        {
            "benchmark": f"serve CPU per 1000 msg/s at {SLOPE_RATE} msg/s ({PAGES} pages), and split",
            "baseline": "bare pymavlink receive loop",
            "baseline_core_pct": round(100 * statistics.median(cpu["pymavlink_slope_rate"]) / slope_k, 1),
            "ours_core_pct": round(100 * statistics.median(cpu["serve_slope_rate"]) / slope_k, 1),
            "ratio": round(
                statistics.median(
                    o / b for o, b in zip(cpu["serve_slope_rate"], cpu["pymavlink_slope_rate"], strict=True)
                ),
                2,
            ),
            # the line through the two rates: per message (the slope) and whatever arrives
            "ours_us_per_message": ours["us_per_message"],
            "baseline_us_per_message": theirs["us_per_message"],
            "ours_fixed_core_pct": ours["fixed_core_pct"],
            "baseline_fixed_core_pct": theirs["fixed_core_pct"],
        }
    )
    rows.append(
        {
            "benchmark": "serve CPU per 1000 msg/s with one page, and with none",
            "baseline": f"the same with {PAGES} pages",
            "baseline_core_pct": pct(cpu["serve"]),
            "ours_core_pct": pct(cpu["serve_one_page"]),
            "ours_no_page_core_pct": pct(cpu["serve_no_page"]),
            "ratio": ratio_of("serve_one_page", "serve"),
            "ratio_no_page": ratio_of("serve_no_page", "serve"),
            "target": "≤ 1 (fewer pages cost no more)",
        }
    )
    runs = [("serve", serve), ("pymavlink", bare)]
    if mavproxy_exe():
        runs.append(("MAVProxy", mavproxy))
    for name, run in runs:
        knee = 0
        for rate in RATES:
            r = run(rate, 6.0, False)
            if r["received"] < r["sent"]:
                break
            knee = rate
        rows.append({"benchmark": f"loss-free knee, {name}", "ours_msg_s": knee, "rates_tried": list(RATES)})
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
