"""Two senders with one system and component id, seen in their packets' sequence numbers.

Two vehicles left at one system id whose clocks are within boot_clock.REBOOT_JUMP of each other
(powered up together) never step the clock back far enough to show (gcs.runtime.boot_clock).
Their sequence numbers show them: each sender counts its own, so their interleaved packets step
back about as often as forward. One sender's numbers step back only when the network reorders
packets (rare, and never on a serial link) or when it restarts (once); the same packets arriving
twice (one vehicle heard through two routes into one port) step back too, and mix data as badly.
"""

from __future__ import annotations

from dataclasses import dataclass

#: This many steps back within WINDOW_S is two senders: two vehicles streaming even 10 Hz each
#: step back ~10 times a second, a reordering network a few times an hour.
STEPS_BACK = 20
WINDOW_S = 5.0


@dataclass
class SequenceWatch:
    interleaved: bool = False
    _window_start: float | None = None
    _count_at_start: int = 0

    def check(self, stepped_back: int, now: float) -> bool:
        """Look at the framer's running count of steps back for the sender (`stepped_back`) at
        host time `now` (monotonic s); True the first time the steps show two senders."""
        if self.interleaved:
            return False
        if self._window_start is None or now - self._window_start > WINDOW_S:
            self._window_start, self._count_at_start = now, stepped_back
            return False
        if stepped_back - self._count_at_start >= STEPS_BACK:
            self.interleaved = True
            return True
        return False
