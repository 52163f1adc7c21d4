"""Shared fixtures: paths to the real data in ../shared/data, the hop flight in both DataFlash
generations and as a tlog without IMU, free ports."""

from __future__ import annotations

import functools
import http.server
import socket
import threading
from pathlib import Path

import pytest
from dataflash_writer import hop_in_both_formats

from gcs.core.estimators import registry
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.sampling import IMU_TYPES
from gcs.mavlink.tlog import read_tlog_records
from gcs.sim.dataflash import DataflashWriter
from gcs.transport.address import free_port

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DATA = SHARED / "data"
LOGS = DATA / "logs"
ARTIFACTS = ROOT / "test-artifacts"


@pytest.fixture(scope="session", autouse=True)
def compiled_estimators() -> None:
    """Compile the estimators' kernels (or load them from numba's disk cache) once, before any
    test: on a fresh clone that takes tens of seconds, which would otherwise land inside the first
    live test's deadlines (a live station estimates only once its kernels are ready)."""
    registry.warm()


@pytest.fixture
def udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


@pytest.fixture
def tcp_port() -> int:
    return free_port(socket.SOCK_STREAM)


@pytest.fixture(scope="session")
def logs_dir() -> Path:
    if not LOGS.is_dir():
        pytest.fail(f"real recordings missing: {LOGS} (shared/ must sit beside the project)")
    return LOGS


@pytest.fixture(scope="session")
def hop_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, DataflashWriter]:
    """The SITL hop flight as an ArduCopter 3.2 log (old.bin, TimeMS) and a current one
    (new.bin, TimeUS) in a folder, and the old log's writer (where each record ends)."""
    folder = tmp_path_factory.mktemp("hop")
    old, new = hop_in_both_formats(str(LOGS / "arducopter-sitl-hop.BIN"))
    (folder / "old.bin").write_bytes(old.bytes())
    (folder / "new.bin").write_bytes(new.bytes())
    return folder, old


@pytest.fixture(scope="session")
def artifacts_dir() -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


@pytest.fixture(scope="session")
def hop_without_imu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The hop's tlog with every IMU message left out (88 s of everything else), records as they were."""
    path = tmp_path_factory.mktemp("no-imu") / "no-imu.tlog"
    decoder, kept = MavlinkDecoder(), []
    for _, usec, packet in read_tlog_records(LOGS / "arducopter-sitl-hop.tlog").records():
        if not {kind for _, kind, _, _ in decoder.frames(packet, final=True)} & set(IMU_TYPES):
            kept.append(usec.to_bytes(8, "big") + packet)
    path.write_bytes(b"".join(kept))
    return path


@pytest.fixture
def attacker_site(tmp_path):
    """A plain static server on another loopback port: another origin."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    handler.log_message = lambda *args: None  # type: ignore[attr-defined]
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield tmp_path, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
