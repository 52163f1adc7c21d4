"""The viser side of the dashboard: the 3-D pose view and the gain panel.

**Display frame.** viser draws z up, so earth NED and body FRD are both turned 180° about x (NWU, FLU),
which maps a quaternion (w, x, y, z) to (w, x, −y, −z) (`display_wxyz`); seen from above, north is +x.
The scene: a ground grid, the vehicle at the onboard attitude (solid, body axes) and one translucent
ghost per estimator at the same origin, so a disagreement shows as a split; `PoseView.update` runs at
about 30 Hz on the event loop (viser handles are thread-safe). The panel: one slider per declared gain
(log10 for wide ranges, see gcs.server.gains) and a reset per estimator, following the gain events.
viser callbacks run on viser's threads and hop to the event loop with call_soon_threadsafe; viser has
no authentication, so the panel is read-only when the server needs a token.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import numpy as np
import viser

from gcs.core.estimation import AttitudePoint
from gcs.core.rotation import euler_to_quat
from gcs.runtime.events import Event
from gcs.runtime.facade import StationFacade
from gcs.server.colors import COLORS, OTHER
from gcs.server.sliders import slider_spec

GHOST_OPACITY = 0.35


def display_wxyz(q) -> tuple[float, float, float, float]:
    """Body FRD→NED quaternion (w, x, y, z) as the FLU→NWU rotation viser draws."""
    return float(q[0]), float(q[1]), -float(q[2]), -float(q[3])


def add_ground(server: viser.ViserServer) -> None:
    server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25, position=(0.0, 0.0, -0.6))
    server.scene.add_frame("/ground/nwu", axes_length=0.4, axes_radius=0.01)
    server.scene.add_label("/ground/north", "N", position=(2.1, 0.0, 0.0))
    server.initial_camera.position = (-2.2, -2.2, 1.4)
    server.initial_camera.look_at = (0.0, 0.0, 0.0)


def add_vehicle(
    server: viser.ViserServer, name: str, color: tuple[int, int, int], opacity: float | None, axes_length: float
) -> viser.FrameHandle:
    """A quadcopter-like body under a frame /name: fuselage, two arms, a nose marker, body axes."""
    frame = server.scene.add_frame(f"/{name}", axes_length=axes_length, axes_radius=0.012)
    server.scene.add_box(f"/{name}/fuselage", color=color, dimensions=(0.7, 0.16, 0.08), opacity=opacity)
    for k, angle in enumerate((math.pi / 4, -math.pi / 4)):
        server.scene.add_box(
            f"/{name}/arm{k}",
            color=color,
            dimensions=(0.9, 0.04, 0.03),
            opacity=opacity,
            wxyz=(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)),
        )
    server.scene.add_icosphere(
        f"/{name}/nose", radius=0.06, color=(250, 200, 0), opacity=opacity, position=(0.38, 0.0, 0.0)
    )
    return frame


class PoseView:
    """The onboard vehicle and a ghost per estimator, updated from the pipeline's latest output."""

    def __init__(self, server: viser.ViserServer, estimators: list[str]) -> None:
        add_ground(server)
        self.onboard = add_vehicle(server, "onboard", COLORS["onboard"], None, axes_length=0.5)
        self.ghosts = {
            name: add_vehicle(server, f"ghost_{name}", COLORS.get(name, OTHER), GHOST_OPACITY, axes_length=0.35)
            for name in estimators
        }

    def update(self, latest: dict[str, AttitudePoint], quaternions: dict[str, np.ndarray]) -> None:
        onboard = latest.get("onboard")
        if onboard is not None:
            self.onboard.wxyz = display_wxyz(euler_to_quat(onboard.roll, onboard.pitch, onboard.yaw))
        for name, ghost in self.ghosts.items():
            if name in latest:
                ghost.wxyz = display_wxyz(quaternions[name])


class GainPanel:
    """viser sliders for every declared gain, driving the Station's gain commands on the event
    loop. Read-only (no handlers at all, since viser does not enforce `disabled`) when the server
    needs a token."""

    def __init__(
        self, server: viser.ViserServer, station: StationFacade, loop: asyncio.AbstractEventLoop, editable: bool
    ) -> None:
        self.station = station
        self.loop = loop
        self.sliders: dict[tuple[str, str], tuple[viser.GuiSliderHandle[float], str]] = {}
        self._reflecting = False
        with server.gui.add_folder("Estimator gains"):
            if not editable:
                server.gui.add_markdown("Read-only here: this server needs a token, change gains on the page.")
            for name in station.estimator_names():
                est = station.estimator(name)
                with server.gui.add_folder(name, expand_by_default=False):
                    for gain in est.gains.declarations.values():
                        self._add_slider(server, name, gain, est, editable)
                    reset = server.gui.add_button(f"reset {name} to {est.DEFAULT_PRESET}", disabled=not editable)
                    if editable:
                        reset.on_click(self._on_reset(name))

    def _add_slider(self, server, estimator: str, gain, est, editable: bool) -> None:
        spec = slider_spec(gain, est.gains.presets)
        label = (
            f"{gain.name} (log₁₀ {gain.unit})"
            if spec.scale == "log"
            else f"{gain.name} ({gain.unit})"
            if gain.unit
            else gain.name
        )
        slider = server.gui.add_slider(
            label,
            min=spec.lo,
            max=spec.hi,
            step=spec.step,
            initial_value=self._position(spec.scale, spec.lo, spec.hi, est.gains[gain.name]),
            hint=f"{gain.meaning} [{gain.min:g} … {gain.max:g} {gain.unit}]",
            disabled=not editable,
        )
        self.sliders[(estimator, gain.name)] = (slider, spec.scale)
        if editable:
            slider.on_update(self._on_slider(estimator, gain.name, slider, spec.scale))

    @staticmethod
    def _position(scale: str, lo: float, hi: float, value: float) -> float:
        if scale == "log":
            return min(hi, max(lo, math.log10(value))) if value > 0 else lo
        return value

    def _on_slider(self, estimator: str, gain: str, slider, scale: str) -> Callable:
        def changed(_event) -> None:
            if self._reflecting:
                return
            value = 10**slider.value if scale == "log" else slider.value
            self.loop.call_soon_threadsafe(self._apply, estimator, gain, value)

        return changed

    def _apply(self, estimator: str, gain: str, value: float) -> None:
        """Apply a slider position (clamped: 10**log10(max) may round past max), unless it only
        echoes the current value."""
        gains = self.station.estimator(estimator).gains
        declared = gains.declarations[gain]
        value = min(declared.max, max(declared.min, value))
        if not math.isclose(gains[gain], value, rel_tol=1e-9, abs_tol=1e-15):
            self.station.set_gain(estimator, gain, value, "viser")

    def _on_reset(self, estimator: str) -> Callable:
        def clicked(_event) -> None:
            self.loop.call_soon_threadsafe(self.station.reset_gains, estimator, None, "viser")

        return clicked

    def reflect(self, event: Event) -> None:
        """Move a slider to a gain value changed elsewhere (event-log listener, event loop)."""
        if event.kind != "gain":
            return
        entry = self.sliders.get((event.data["estimator"], event.data["gain"]))
        if entry is None:
            return
        slider, scale = entry
        self._reflecting = True
        try:
            position = self._position(scale, slider.min, slider.max, event.data["new"])
            slider.value = position  # type: ignore[misc]  # viser's stub marks it read-only; the handle sets it
        finally:
            self._reflecting = False
