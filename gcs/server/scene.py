"""The viser side of the dashboard: the 3-D pose view and the gain panel.

**Display frame.** viser draws z up, so earth NED and body FRD are both turned 180° about x (NWU, FLU),
which maps a quaternion (w, x, y, z) to (w, x, −y, −z) (`display_wxyz`); seen from above, north is +x.
The scene: a ground grid, the vehicle at the onboard attitude (solid, body axes) and one translucent
ghost per estimator at the same origin, so a disagreement shows as a split; `PoseView.update` runs
on the event loop (viser handles are thread-safe) at most 30 Hz (less with many viewers), only
while a viewer is connected and after new attitudes came (gcs.server.pose_refresh), and moves only
what visibly turned.
The panel, minimized at start so it does not cover the scene (hidden in a phone's frame): every
estimator's gains as read-only text in their own units, following the gain events (viser has no
authentication: changes are made on the page).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import numpy as np
import viser
from viser._messages import RunJavascriptMessage

from gcs.core.estimation import AttitudePoint
from gcs.core.rotation import euler_to_quat
from gcs.runtime.event_loop import loops_made_fast
from gcs.runtime.events import Event
from gcs.runtime.facade import StationFacade
from gcs.server.colors import COLORS, OTHER
from gcs.server.guard import FrontDoor, Refusal
from gcs.server.viser_door import guarded_viser

GHOST_OPACITY = 0.35


#: Style for viser's own page. With software WebGL (a laptop without GPU drivers, headless
#: Chromium) viser shows a notice over the top third of the view until closed, on every load; the
#: page says it under the view instead (dashboard.js). In a frame narrower than viser's mobile
#: breakpoint (Mantine's xs, 36em: the dashboard's 3-D view on a phone) viser's panel is a bottom
#: sheet over the scene, open at start; the page has the gains and the controls, so it goes.
#: tests/test_layout.py measures what is left inside the frame.
EMBEDDED_STYLE = """
.mantine-Notifications-root { display: none !important; }
@media (max-width: 36em) { .mantine-Paper-root[style*="position: fixed"] { display: none !important; } }
"""
#: Mounts EMBEDDED_STYLE in the document of every client, once (viser replays the message to each
#: client that connects). Until 2026-12-05 the style was panel HTML (`gui.add_html`), which viser
#: mounts only while its panel is open: on a laptop-sized frame, with the panel minimized, the
#: software-WebGL notice stayed.
STYLE_SCRIPT = f"""
if (!document.getElementById("gcs-style")) {{
  const style = document.createElement("style");
  style.id = "gcs-style";
  style.textContent = {json.dumps(EMBEDDED_STYLE)};
  document.head.appendChild(style);
}}
"""


class LocalViserServer(viser.ViserServer):
    """viser, kept on this network: its share button asks viser's relay for a public URL to the
    view, and any client may send that request (viser has no authentication). At the field there
    is no internet, and nobody but the operator may publish the view, so the button is hidden and the
    request refused. Its port has the dashboard's front door (`door`, default: the dashboard's
    on `host` with no other origin), and a message size (gcs.server.viser_door)."""

    def __init__(
        self,
        host: str,
        port: int,
        door: FrontDoor | None = None,
        on_refused: Callable[[Refusal], None] | None = None,
    ) -> None:
        # viser's thread makes its loop and starts its server before this returns
        with loops_made_fast(), guarded_viser(door or FrontDoor.of(host, framed=True), on_refused):
            super().__init__(host=host, port=port, verbose=False, label="gcs pose")
        self.gui.configure_theme(show_share_button=False, show_logo=False)
        # The page's gain panel is the control: viser's panel starts minimized to its title bar, so
        # it never covers the vehicle (at 600 px and wider); narrower, it is hidden (EMBEDDED_STYLE).
        self.gui.main_panel.minimize()
        # viser's way to run a script on its page (it sends plotly.js so); kept for new clients
        self._websock_server.queue_message(RunJavascriptMessage(source=STYLE_SCRIPT))

    def request_share_url(self, verbose: bool = True) -> str | None:
        return None


def display_wxyz(q) -> tuple[float, float, float, float]:
    """Body FRD→NED quaternion (w, x, y, z) as the FLU→NWU rotation viser draws."""
    return float(q[0]), float(q[1]), -float(q[2]), -float(q[3])


def add_ground(server: viser.ViserServer, width: float = 4.0, height: float = 4.0, y: float = 0.0) -> None:
    """The grid (width along north, height along west, centred at y west; re-added as a fleet
    grows), north and the lights."""
    # No shadow maps: with software WebGL (no GPU driver; headless Chromium) every frame of the
    # view is paid in CPU the plots and the station need (bench.page_fps). The image-based
    # lighting stays: without it the colours that tell the estimators apart turn near black.
    server.scene.configure_default_lights(cast_shadow=False)
    server.scene.add_grid("/grid", width=width, height=height, cell_size=0.25, position=(0.0, y, -0.6))
    server.scene.add_frame("/ground/nwu", axes_length=0.4, axes_radius=0.01)
    server.scene.add_label("/ground/north", "N", position=(2.1, 0.0, 0.0))
    server.initial_camera.position = (-2.2, -2.2, 1.4)
    server.initial_camera.look_at = (0.0, 0.0, 0.0)


def add_vehicle(
    server: viser.ViserServer, path: str, color: tuple[int, int, int], opacity: float | None, axes_length: float
) -> viser.FrameHandle:
    """A quadcopter-like body under a frame `path`: fuselage, two arms, a nose marker, body axes."""
    frame = server.scene.add_frame(path, axes_length=axes_length, axes_radius=0.012)
    server.scene.add_box(f"{path}/fuselage", color=color, dimensions=(0.7, 0.16, 0.08), opacity=opacity)
    for k, angle in enumerate((math.pi / 4, -math.pi / 4)):
        server.scene.add_box(
            f"{path}/arm{k}",
            color=color,
            dimensions=(0.9, 0.04, 0.03),
            opacity=opacity,
            wxyz=(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)),
        )
    server.scene.add_icosphere(
        f"{path}/nose", radius=0.06, color=(250, 200, 0), opacity=opacity, position=(0.38, 0.0, 0.0)
    )
    return frame


def turned(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Angle (rad) of the rotation between two unit quaternions (w, x, y, z)."""
    return 2.0 * math.acos(min(1.0, abs(sum(p * q for p, q in zip(a, b, strict=True)))))


class PoseView:
    """The onboard vehicle and a ghost per estimator, updated from the pipeline's latest output;
    under the frame `root` (a fleet's vehicle, gcs.server.fleet_scene). A body is moved only once
    it turned by more than `MIN_TURN` since it was last drawn: every change keeps viser's client
    rendering for the next 250 ms, which with software WebGL costs half a core (bench.page_fps),
    so a vehicle at rest costs nothing to watch."""

    #: rad, below what the eye sees at the view's scale
    MIN_TURN = math.radians(0.2)

    def __init__(self, server: viser.ViserServer, estimators: list[str], root: str = "") -> None:
        self.onboard = add_vehicle(server, f"{root}/onboard", COLORS["onboard"], None, axes_length=0.5)
        self.ghosts = {
            name: add_vehicle(server, f"{root}/ghost_{name}", COLORS.get(name, OTHER), GHOST_OPACITY, axes_length=0.35)
            for name in estimators
        }
        self.drawn: dict[str, tuple[float, float, float, float]] = {}

    def update(self, latest: dict[str, AttitudePoint], quaternions: dict[str, np.ndarray]) -> None:
        onboard = latest.get("onboard")
        if onboard is not None:
            self._move("onboard", self.onboard, display_wxyz(euler_to_quat(onboard.roll, onboard.pitch, onboard.yaw)))
        for name, ghost in self.ghosts.items():
            if name in latest:
                self._move(name, ghost, display_wxyz(quaternions[name]))

    def _move(self, name: str, frame: viser.FrameHandle, wxyz: tuple[float, float, float, float]) -> None:
        drawn = self.drawn.get(name)
        if drawn is None or turned(drawn, wxyz) > self.MIN_TURN:
            frame.wxyz = self.drawn[name] = wxyz


class GainTable:
    """The estimators' gains in viser's panel, as text in their own units, following every gain
    event. Read-only by construction: viser has no authentication and does not enforce `disabled`,
    so the panel has no inputs at all; gains change on the page, which needs the token."""

    def __init__(self, server: viser.ViserServer, station: StationFacade) -> None:
        self.station = station
        self.tables: dict[str, viser.GuiMarkdownHandle] = {}
        with server.gui.add_folder("Estimator gains", expand_by_default=False) as self.folder:
            server.gui.add_markdown("Read-only here: change gains on the dashboard page.")
            for name in station.estimator_names():
                self.tables[name] = server.gui.add_markdown(self.table(name))

    def table(self, estimator: str) -> str:
        est = self.station.estimator(estimator)
        rows = [f"| {g.name} | {est.gains[g.name]:.4g} {g.unit} |" for g in est.gains.declarations.values()]
        return "\n".join([f"**{estimator}** ({est.preset})", "", "| gain | value |", "|---|---|", *rows])

    def reflect(self, event: Event) -> None:
        """Show a gain changed, or a reset to a preset, on the page or by a script (event-log
        listener, event loop)."""
        estimator = event.data.get("estimator")
        if event.kind in ("gain", "preset") and estimator in self.tables:
            self.tables[estimator].content = self.table(estimator)
