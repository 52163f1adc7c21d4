"""The telemetry radio's budget on the live link: the radio's state, what each requested stream
costs against what the link carries, the rates predicted to fit before they are requested, and a
station that backs off when the radio's buffer fills instead of flooding it.

A radio is taken to be there once a RADIO_STATUS arrives from a radio's component
(MAV_COMP_ID_TELEMETRY_RADIO, 68: SiK, RFD900 and mLRS inject one a second as system 51). One from
any other component is counted and named in the event log once per sender, and changes nothing:
an autopilot does not forward its own radio's (ArduPilot's routing drops RADIO_STATUS), so it is
some other part's report (a companion's link, a second ground station) or a corrupt packet, and
the streams must not be capped for a radio this link does not have. Then:
1. predict: the wanted rates scaled so that streams + the other traffic fit BUDGET_SHARE of the
   link's capacity (gcs.mavlink.radio), split evenly between the vehicles heard on the link (two
   vehicles behind one radio each plan on half); those are requested (StreamRequester.rate_cap);
2. follow txbuf (percent of the radio's buffer free): below LOW_TXBUF the station lowers its fast
   streams by BACK_OFF and asks again, at most once per ADJUST_INTERVAL; after CALM_INTERVALS
   checks above HIGH_TXBUF it climbs back by STEP_UP towards the prediction, never above it nor,
   for CEILING_MEMORY, above BACK_OFF × the rate that last filled the buffer (no see-saw); after
   that long without a fill, straight back to the prediction;
3. no RADIO_STATUS for STATUS_TIMEOUT: the radio is gone (unplugged, or a stray RADIO_STATUS on a
   link with none) and the streams are requested as wanted again.
Every decision is written in `choice` and the event log, so the engineer sees what was chosen and why.
"""

from __future__ import annotations

import time
from dataclasses import replace

from gcs.mavlink.radio import RatePrediction, frame_bytes, link_capacity, predict, rates_at_scale, stream_costs
from gcs.runtime.events import EventLog
from gcs.runtime.link import Link
from gcs.runtime.snapshots import RadioSnapshot, RadioStatus, RadioStream
from gcs.runtime.streams import STREAM_GROUPS, StreamRequester

#: Share of the link's capacity the streams may plan on (the rest: parameters, commands, bursts).
BUDGET_SHARE = 0.8
LOW_TXBUF, HIGH_TXBUF = 50, 90
BACK_OFF, STEP_UP = 0.8, 1.25
ADJUST_INTERVAL = 3.0
CALM_INTERVALS = 2
#: How long the rate that filled the buffer caps the climb back (s): a burst (a log download,
#: a parameter download) must not keep the streams low for good.
CEILING_MEMORY = 60.0
#: Streams at or below this rate (Hz) keep it (GPS, barometer, health); faster ones go no lower.
KEEP_HZ = 5.0
#: A RADIO_STATUS older than this (s): the radio is taken to be gone.
STATUS_TIMEOUT = 5.0
#: MAV_COMP_ID_TELEMETRY_RADIO: the component a radio's own RADIO_STATUS comes from.
RADIO_COMPONENT = 68


class RadioGovernor:
    """Watches RADIO_STATUS on `link` and sets the rates `streams` requests (see module doc)."""

    def __init__(self, link: Link, streams: StreamRequester, events: EventLog, baud: int = 57600) -> None:
        self.link, self.streams, self.events = link, streams, events
        self.capacity_bps = link_capacity(baud)
        self.status: RadioStatus | None = None
        self._status_at: float | None = None
        self.wanted: dict[str, float] = {}
        self.prediction: RatePrediction | None = None
        self.scale = 1.0
        self.choice = "no radio seen (no RADIO_STATUS): streams as wanted"
        self._calm = 0
        self._ceiling = 1.0 / BACK_OFF  # the scale that last filled the buffer (none yet)
        self._ceiling_at = 0.0
        self._capping = False  # the requests were capped for a radio not yet seen gone
        #: RADIO_STATUS packets from another component than a radio's, by (sysid, compid)
        self.ignored: dict[tuple[int, int], int] = {}

    @property
    def budget_bps(self) -> float:
        """This vehicle's share of what the streams may plan on."""
        return self.capacity_bps * BUDGET_SHARE / self.link.sharing

    @property
    def present(self) -> bool:
        return self._status_at is not None and time.monotonic() - self._status_at < STATUS_TIMEOUT

    def _groups(self) -> dict[str, int] | None:
        return STREAM_GROUPS if self.streams.method == "REQUEST_DATA_STREAM" or self._mavlink() == 1 else None

    def _mavlink(self) -> int:
        return self.link.vehicle_mavlink or 2

    def cap(self, wanted: dict[str, float]) -> dict[str, float]:
        """The rates to request for `wanted` (StreamRequester.rate_cap): as wanted without a radio."""
        self.wanted = dict(wanted)
        if not self.present:
            return wanted
        self.prediction = self._predict()
        self.scale = max(min(self.scale, self.prediction.scale), self._lowest_scale())
        return rates_at_scale(wanted, self.scale, KEEP_HZ, whole_hz=self._groups() is not None)

    def _sent(self) -> dict[str, float]:
        """The wanted streams the vehicle sends (all of them until any arrives): one it never
        sends costs nothing."""
        achieved = self.link.stats.rates()
        return {name: hz for name, hz in self.wanted.items() if achieved.get(name, 0.0) > 0} or self.wanted

    def _predict(self) -> RatePrediction:
        """The rates that fit, from what the link carries now."""
        return predict(
            self._sent(), self._mavlink(), self.budget_bps, self._background_bps(), KEEP_HZ, groups=self._groups()
        )

    def _background_bps(self) -> float:
        """What the link carries besides the wanted streams (heartbeats, status, the radio's own)."""
        rates = self.link.stats.rates()
        streams = sum(rates.get(name, 0.0) * frame_bytes(name, self._mavlink()) for name in self.wanted)
        return max(self.link.stats.bytes_per_second() - streams, 0.0)

    async def run(self) -> None:
        sub = self.link.bus.subscribe("radio", types=["RADIO_STATUS"], maxlen=20)
        next_check = time.monotonic() + ADJUST_INTERVAL
        try:
            while True:
                item = await sub.get(timeout=ADJUST_INTERVAL)
                if item is not None and item.compid != RADIO_COMPONENT:
                    self._ignore(item.sysid, item.compid)
                elif item is not None:
                    first = not self.present
                    m = item.msg
                    self._status_at = time.monotonic()
                    self.status = RadioStatus(m.rssi, m.remrssi, m.noise, m.remnoise, m.txbuf, m.rxerrors, m.fixed, 0.0)
                    if first:
                        self.scale, self._ceiling, self._capping = 1.0, 1.0 / BACK_OFF, True
                        self._decide("radio found: requesting the rates predicted to fit")
                if time.monotonic() >= next_check:
                    next_check = time.monotonic() + ADJUST_INTERVAL
                    self._adjust()
        finally:
            sub.close()

    def _adjust(self) -> None:
        if self._capping and not self.present:
            self._capping, self.scale, self.prediction = False, 1.0, None
            self._decide(f"radio gone (no RADIO_STATUS for {STATUS_TIMEOUT:g} s): requesting the rates as wanted")
            return
        if not self.present or self.status is None or not self.wanted:
            return
        txbuf = self.status.txbuf
        self.prediction = self._predict()
        forgotten = time.monotonic() - self._ceiling_at > CEILING_MEMORY
        if forgotten:
            self._ceiling = 1.0 / BACK_OFF
        if txbuf < LOW_TXBUF:
            self._calm = 0
            if self.scale <= self._lowest_scale():  # nothing left to lower: say so, ask nothing
                self.choice = f"txbuf {txbuf} % free: the fast streams are at their floor ({KEEP_HZ:g} Hz)"
                return
            self._ceiling, self._ceiling_at = self.scale, time.monotonic()  # climb back only below it
            self.scale = max(self.scale * BACK_OFF, self._lowest_scale())
            self._decide(f"txbuf {txbuf} % free: lowered the fast streams to {self.scale:.0%} of wanted")
        elif txbuf > HIGH_TXBUF and self.scale < min(self.prediction.scale, self._ceiling * BACK_OFF):
            self._calm += 1
            if self._calm >= CALM_INTERVALS:
                self._calm = 0
                climb = self.prediction.scale if forgotten else self.scale * STEP_UP  # long calm: straight back
                self.scale = min(climb, self.prediction.scale, self._ceiling * BACK_OFF)
                self._decide(f"txbuf {txbuf} % free: raised the fast streams to {self.scale:.0%} of wanted")
        else:
            self._calm = 0

    def _lowest_scale(self) -> float:
        """Below this every fast stream is at KEEP_HZ already: lowering further changes nothing."""
        fastest = max(self.wanted.values(), default=KEEP_HZ)
        return min(KEEP_HZ / fastest, 1.0)

    def _ignore(self, sysid: int, compid: int) -> None:
        sender = (sysid, compid)
        self.ignored[sender] = self.ignored.get(sender, 0) + 1
        if self.ignored[sender] == 1:
            self.events.record(
                "radio",
                "station",
                ignored=f"RADIO_STATUS from system {sysid} component {compid}: "
                f"no radio (a radio reports as component {RADIO_COMPONENT})",
            )

    def _decide(self, why: str) -> None:
        self.choice = why
        self.events.record("radio", "station", choice=why, scale=round(self.scale, 3))
        self.streams.request_again()

    def snapshot(self) -> RadioSnapshot:
        status = self.status
        if status is not None and self._status_at is not None:
            status = replace(status, age_s=round(time.monotonic() - self._status_at, 2))
        achieved = self.link.stats.rates()
        predicted = self.prediction.rates if self.prediction is not None else self.wanted
        requested = self.streams.requested
        sent = self._sent()
        costs = stream_costs({n: hz for n, hz in requested.items() if n in sent}, self._mavlink(), self._groups())
        rows = {
            name: RadioStream(
                wanted_hz=hz,
                predicted_hz=predicted.get(name, 0.0),
                requested_hz=requested.get(name, 0.0),
                achieved_hz=round(achieved.get(name, 0.0), 2),
                cost_bps=costs.get(name, 0.0),
            )
            for name, hz in self.wanted.items()
        }
        return RadioSnapshot(
            present=self.present,
            status=status,
            capacity_bps=round(self.capacity_bps, 1),
            budget_bps=round(self.budget_bps, 1),
            shared_by=self.link.sharing,
            used_bps=round(self.link.stats.bytes_per_second(), 1),
            predicted_scale=self.prediction.scale if self.prediction is not None else 1.0,
            scale=round(self.scale, 3),
            choice=self.choice,
            streams=rows,
            ignored_status=sum(self.ignored.values()),
        )
