"""The vehicle's clock (time_boot_ms) as its messages give it: reboots, and two vehicles that send
as one system id.

A clock that goes back by more than REBOOT_JUMP is a reboot. But two vehicles with the same system
id (two SITLs or airframes left at the default MAV_SYSID / SYSID_THISMAV, one UDP port) interleave
two clocks: every message of the younger one would be a reboot, each re-requesting the streams
and restarting the plots, and their data mix in one session with no word of why. They show as a
step back followed soon (within TWO_CLOCKS_S, of the new clock and of the host's) by a step forward
to where the old clock had got to: a rebooted vehicle's new clock never jumps back up to its old
one (a silence after a reboot can end near the old clock's time only after as long a wait). Once two
senders are known (here, or by their sequence numbers: gcs.runtime.sequence_watch), no step is a
reboot any more, and the station says what to fix.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

#: The vehicle clock going back by more than this (s) is a reboot, not jitter or reordering.
REBOOT_JUMP = 1.0
#: A step forward this soon (s of the new clock and of the host's) after a step back, to within
#: this of the old clock, is the old clock going on: two clocks, not a reboot.
TWO_CLOCKS_S = 5.0


class Step(enum.Enum):
    """What one reading of the clock showed."""

    ON = "on"  # the clock going on (or the first reading)
    REBOOT = "reboot"
    TWO_CLOCKS = "two clocks"  # seen at this reading: the last step back was another vehicle's


@dataclass
class BootClock:
    reboots: int = 0
    #: two senders are known: by their clocks, or by their sequence numbers (`VehicleState`)
    two_senders: bool = False
    #: the reading before the latest, and the latest (s)
    previous: float | None = None
    last: float | None = None
    #: the host times (monotonic s) of those two readings
    previous_at: float | None = None
    last_at: float | None = None
    #: the clock before the last step back, the first reading after it, and its host time
    _before: float | None = None
    _after: float | None = None
    _stepped_back_at: float = 0.0

    def step(self, t: float, now: float) -> Step:
        """Take one reading of the clock (s), which arrived at host time `now` (monotonic s)."""
        last = self.previous = self.last
        self.last = t
        self.previous_at, self.last_at = self.last_at, now
        if self.two_senders or last is None:
            return Step.ON
        before, after = self._before, self._after
        if before is not None and after is not None and t > last + REBOOT_JUMP:
            soon = last - after < TWO_CLOCKS_S and now - self._stepped_back_at < TWO_CLOCKS_S
            if soon and abs(t - before) < TWO_CLOCKS_S:  # the old clock, going on
                self.two_senders = True
                self.reboots -= 1  # the step back was the other vehicle's clock
                return Step.TWO_CLOCKS
        if t < last - REBOOT_JUMP:
            self._before, self._after, self._stepped_back_at = last, t, now
            self.reboots += 1
            return Step.REBOOT
        return Step.ON
