"""`gcs report` of a recorded session: its gain changes, notes and events are in the report, and
every source is drawn in the dashboard's colour (gcs.core.colors, the one table the page uses)."""

from __future__ import annotations

import asyncio
import base64
import io
import re

import numpy as np
from live import running_station, sim_process, wait_for
from matplotlib.image import imread

from gcs.commands.cli import main
from gcs.core.colors import COLORS, hex_color
from gcs.server.colors import colors_script


def record_session(udp_port: int, root) -> str:
    async def scenario() -> str:
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station,
            sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad", speed=2.0),
        ):
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 400, 90, "IMU samples")
            station.set_gain("dcm", "kp_rp", 0.35, "api:127.0.0.1")
            station.add_note("gusty, swapped props", "api:127.0.0.1")
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 800, 90, "more IMU samples")
            return str(station.recorder.session.folder)

    return asyncio.run(scenario())


def colour_pixels(data_uri: str, rgb: tuple[int, int, int]) -> int:
    image = imread(io.BytesIO(base64.b64decode(data_uri)), format="png")[:, :, :3]
    return int((np.abs(image * 255 - np.array(rgb)).max(axis=2) < 12).sum())


def test_report_of_a_session_has_its_events_notes_gain_changes_and_the_page_colours(udp_port, tmp_path, capsys):
    folder = record_session(udp_port, tmp_path / "sessions")
    out = tmp_path / "report.html"
    assert main(["report", folder, "--out", str(out)]) == 0
    page = out.read_text()
    gains = re.search(r"<table class='gain-changes'>(.*?)</table>", page).group(1)
    assert re.search(r"<td>dcm</td><td>kp_rp</td><td>[0-9.]+</td><td>0\.35</td><td>api:127\.0\.0\.1</td>", gains)
    notes = re.search(r"<table class='notes'>(.*?)</table>", page).group(1)
    assert "gusty, swapped props" in notes
    events = re.search(r"<table class='events'>(.*?)</table>", page).group(1)
    assert events.count("<tr>") > 3 and "<td>link</td>" in events and "<td>recording</td>" in events
    # The page's colours: the same table as /colors.js, in the legend and in the plotted lines.
    assert all(f'"{name}": "{hex_color(name)}"' in colors_script() for name in COLORS)
    for name in ("onboard", "dcm", "kf", "ekf"):
        assert f"background:{hex_color(name)}" in page
    attitude, errors = re.findall(r"<img src='data:image/png;base64,([A-Za-z0-9+/=]+)'>", page)[:2]
    for name in ("dcm", "kf", "ekf"):
        # > 20, not 50: the attitude lines lie on one another, and the more closely dcm follows the
        # others the more of its line kf's and ekf's cover (33-92 of its pixels show; 0 if it
        # were drawn in another colour)
        assert colour_pixels(attitude, COLORS[name]) > 20, name
        assert colour_pixels(errors, COLORS[name]) > 50, name
    # matplotlib's own cycle would draw the second estimator's error orange: no ahrs2 orange there
    assert colour_pixels(errors, COLORS["ahrs2"]) < 5
