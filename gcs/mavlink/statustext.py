"""MAVLink 2's long STATUSTEXT: ArduPilot and PX4 send a text longer than the 50-character field as
chunks of one nonzero `id`, numbered by `chunk_seq`, the last one shorter than the field. A ground
station shows and records the whole line, as Mission Planner and QGroundControl do, never its
pieces ("... too fast. Increas" and "e SCHED_LOOP_RATE" as two messages)."""

from __future__ import annotations

from dataclasses import dataclass

#: STATUSTEXT.text length: a chunk this long may be continued in the next one (same id).
CHUNK_CHARS = 50
#: A text whose end never came (its last chunk lost, or a text of exactly 50·n characters, which
#: has no short chunk to end it) is given out as it stands after this many seconds.
WAIT_S = 1.0


@dataclass
class _Partial:
    text_id: int
    severity: int
    started: float
    chunks: list[str]


class StatusTextJoiner:
    """Joins the chunks of one vehicle's STATUSTEXT into whole texts. `add` and `expire` return
    the texts completed, as (severity, text), in the order the vehicle sent them."""

    def __init__(self) -> None:
        self._partial: _Partial | None = None

    def add(self, severity: int, text: str, text_id: int, chunk_seq: int, now: float) -> list[tuple[int, str]]:
        """One STATUSTEXT (`text` without its NUL padding; `text_id` 0: a text of one message)."""
        done = self.expire(now)
        partial = self._partial
        if partial is not None and (text_id != partial.text_id or chunk_seq != len(partial.chunks)):
            done.append(self._release())  # another text began, or a chunk was lost: keep what came
        if not text_id:
            return [*done, (severity, text)]
        if self._partial is None:
            self._partial = _Partial(text_id, severity, now, [])
        self._partial.chunks.append(text)
        if len(text) < CHUNK_CHARS:
            done.append(self._release())
        return done

    def expire(self, now: float) -> list[tuple[int, str]]:
        """The unfinished text, once it has waited WAIT_S for its next chunk."""
        if self._partial is not None and now - self._partial.started > WAIT_S:
            return [self._release()]
        return []

    def _release(self) -> tuple[int, str]:
        assert self._partial is not None
        partial, self._partial = self._partial, None
        return partial.severity, "".join(partial.chunks)
