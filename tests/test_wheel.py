"""The wheel is the whole product: built from the checkout, installed into a fresh virtualenv
outside it, `gcs serve` runs from an empty folder with no npm on PATH, serves the page and every
asset it references, and live estimates of the simulated vehicle."""

from __future__ import annotations

import html.parser
import shutil
import subprocess
import sys
import time
import venv
from pathlib import Path

import httpx
import pytest
from conftest import free_port

ROOT = Path(__file__).resolve().parents[1]


class AssetLinks(html.parser.HTMLParser):
    """Every local src= and href= in a page."""

    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if name in ("src", "href") and value and not value.startswith(("data:", "http:", "https:", "#")):
                self.links.append(value)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """bin/ of a fresh virtualenv with only the wheel (and its dependencies) in it."""
    work = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(work / "dist")],
        check=True,
        capture_output=True,
    )
    (wheel,) = (work / "dist").glob("gcs-*.whl")
    venv.create(work / "venv", with_pip=True)
    bin_dir = work / "venv" / "bin"
    subprocess.run([bin_dir / "python", "-m", "pip", "install", "-q", str(wheel)], check=True, capture_output=True)
    return bin_dir


def wait_json(client: httpx.Client, path: str, ok, what: str, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            last = client.get(path)
            if last.status_code == 200 and ok(last.json()):
                return last.json()
        except httpx.TransportError:
            pass
        time.sleep(0.2)  # polling a server in another process: the condition is the deadline above
    raise AssertionError(f"timed out after {timeout} s waiting for {what}; last answer: {last and last.text[:300]}")


@pytest.mark.timeout(900)  # pip install with numba, then the first kernel compilation
def test_installed_wheel_serves_the_dashboard_with_no_checkout_and_no_npm(installed, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    env = {"PATH": str(installed), "HOME": str(tmp_path), "LANG": "C.UTF-8"}  # no npm, no node, no checkout
    assert shutil.which("npm", path=env["PATH"]) is None and shutil.which("node", path=env["PATH"]) is None
    udp, port = free_port(), free_port()
    sim = subprocess.Popen(
        [installed / "gcs", "sim", "--profile", "pixhawk", "--link", f"udpout:127.0.0.1:{udp}"],
        cwd=empty,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    serve = subprocess.Popen(
        [installed / "gcs", "serve", "--connect", f"udpin:127.0.0.1:{udp}", "--port", str(port), "--no-record"],
        cwd=empty,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as client:
            live = {"onboard", "truth", "dcm", "kf", "ekf"}
            # a fresh install compiles the estimators' kernels at its first start (cached afterwards)
            first = wait_json(
                client, "/api/estimates", lambda d: live <= set(d["sources"]), "every source", timeout=600.0
            )
            later = wait_json(
                client,
                "/api/estimates",
                lambda d: d["sources"]["dcm"]["t"] > first["sources"]["dcm"]["t"] + 1.0,
                "estimates moving on with the vehicle clock",
            )
            assert abs(later["sources"]["dcm"]["roll_deg"] - later["sources"]["truth"]["roll_deg"]) < 10
            page = client.get("/")
            assert page.status_code == 200 and "<html" in page.text.lower()
            links = AssetLinks()
            links.feed(page.text)
            assert {"/vendor/uplot/uPlot.iife.min.js", "/vendor/uplot/uPlot.min.css", "plots.js"} <= set(links.links)
            for link in links.links:
                asset = client.get(link if link.startswith("/") else f"/{link}")
                assert asset.status_code == 200 and asset.content, link
    finally:
        for process in (serve, sim):
            process.terminate()
        for process in (serve, sim):
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    site = subprocess.run(
        [installed / "python", "-c", "import gcs, os; print(os.path.dirname(gcs.__file__))"],
        env=env,
        cwd=empty,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(site).is_relative_to(installed.parent) and not Path(site).is_relative_to(ROOT)  # the wheel's code
    assert not list(empty.iterdir())  # --no-record: nothing written where it ran
    version = subprocess.run([installed / "gcs", "--version"], env=env, capture_output=True, text=True).stdout
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert version.startswith("gcs 0.") and head in version  # built from this checkout's commit
