"""The 3-D view of every vehicle: each vehicle's pose view (gcs.server.scene) side by side,
SPACING m apart towards the west, each labelled with its system id once there are two, and a
gain folder per vehicle, named the same way.

One scene for every viewer, not the one selected on the page: viser's scene is shared by its
clients and knows nothing of the page's selector, and an engineer flying two vehicles wants both
in sight (the page's selector picks whose plots and panels). One vehicle: the scene as before."""

from __future__ import annotations

from dataclasses import dataclass

import viser

from gcs.core.estimation import AttitudePoint
from gcs.runtime.facade import FleetFacade, StationFacade, VehicleFacade
from gcs.runtime.signal import Signal
from gcs.server.scene import GainTable, PoseView, add_ground

#: Metres between two vehicles' bodies in the scene.
SPACING = 2.5


@dataclass
class VehicleView:
    station: StationFacade
    pose: PoseView
    gains: GainTable
    root: str
    label: viser.LabelHandle | None = None


class FleetScene:
    def __init__(self, server: viser.ViserServer, first: StationFacade, fleet: FleetFacade | None) -> None:
        self.server, self.fleet = server, fleet
        self.views: list[VehicleView] = []
        #: any vehicle's new attitudes (its station's points), so the view is redrawn only then
        self.arrived: Signal[[list[AttitudePoint]]] = Signal()
        self._add(first)
        if fleet is not None:
            fleet.vehicle_added.connect(self._vehicle_added)

    def update(self) -> None:
        """Every vehicle's bodies to its latest attitudes (the pose loop, event loop), in one
        `atomic` block: viser sends a drawing's bodies to each viewer in one window, together,
        whatever the fleet's size."""
        with self.server.atomic():
            for view in self.views:
                view.pose.update(*view.station.latest_attitudes())

    def _vehicle_added(self, entry: VehicleFacade) -> None:
        if all(view.station is not entry.station for view in self.views):  # not the first core binding
            self._add(entry.station)
        self._name_vehicles()

    def _add(self, station: StationFacade) -> None:
        k = len(self.views)
        root = f"/vehicle{k}"
        self.server.scene.add_frame(root, show_axes=False, position=(0.0, -SPACING * k, 0.0))
        gains = GainTable(self.server, station)
        station.events.recorded.connect(gains.reflect)
        station.points.connect(self.arrived.emit)
        self.views.append(VehicleView(station, PoseView(self.server, station.estimator_names(), root), gains, root))
        add_ground(self.server, height=4.0 + SPACING * k, y=-SPACING * k / 2)

    def _name_vehicles(self) -> None:
        """Label each body and gain folder with its vehicle's sysid (from the second vehicle on)."""
        if self.fleet is None or len(self.views) < 2:
            return
        for entry in self.fleet.vehicles():
            view = next((v for v in self.views if v.station is entry.station), None)
            if view is None or entry.sysid is None:
                continue
            name = f"sysid {entry.sysid}"
            if view.label is None:
                view.label = self.server.scene.add_label(f"{view.root}/name", name, position=(0.0, 0.0, 0.7))
            view.label.text = name
            view.gains.folder.label = f"Estimator gains, {name}"
