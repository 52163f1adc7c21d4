"""The ground side of MAVLink's log download, as a pure state machine (no I/O, no clock: every
call is told `now`), so the rules can be tested packet by packet.

The vehicle (ArduPilot's AP_Logger_MAVLinkLogTransfer) answers LOG_REQUEST_DATA(id, ofs, count)
with LOG_DATA of 90 bytes from ofs until count bytes or the end of the log, and silently ignores
any further request while one is being sent. So one request is outstanding at a time: the first
asks for the whole log; when it ends (its last chunk arrives, or nothing arrives for
`idle_timeout`), the next asks for the first run of missing chunks (runs closer than `merge_gap`
chunks asked as one: a few chunks sent twice cost less than a round trip), until every chunk is
in. The wait for a lost last chunk adapts to the link: three times the smoothed time from a
request to its first chunk, between MIN_IDLE and `idle_timeout`. Every request starts on a 90-byte boundary, so a
chunk is identified by ofs // 90 and its length is known from the size in LOG_ENTRY.
"""

from __future__ import annotations

from dataclasses import dataclass

LOG_DATA_LEN = 90
#: LOG_REQUEST_DATA.count meaning "to the end of the log".
TO_END = 0xFFFFFFFF
#: Shortest wait for a request's last chunk (s).
MIN_IDLE = 0.1


@dataclass(frozen=True, slots=True)
class LogEntry:
    """One LOG_ENTRY: log id (1..), how many logs, the last id, UTC start (s, 0 unknown), bytes."""

    id: int
    num_logs: int
    last_log_num: int
    time_utc: int
    size: int


@dataclass(frozen=True, slots=True)
class DataRequest:
    """A LOG_REQUEST_DATA to send: bytes [ofs, ofs + count) of log `log_id`."""

    log_id: int
    ofs: int
    count: int


class LogListing:
    """LOG_ENTRY replies to one LOG_REQUEST_LIST, complete when ids 1..last_log_num are all in
    (or the vehicle says it has none: a single entry with id 0)."""

    def __init__(self) -> None:
        self.entries: dict[int, LogEntry] = {}
        self.last: int | None = None

    def add(self, entry: LogEntry) -> None:
        self.last = entry.last_log_num if entry.num_logs else 0
        if entry.id:
            self.entries[entry.id] = entry

    @property
    def complete(self) -> bool:
        return self.last is not None and all(i in self.entries for i in range(1, self.last + 1))

    def missing(self) -> list[int]:
        return [] if self.last is None else [i for i in range(1, self.last + 1) if i not in self.entries]

    def sorted(self) -> list[LogEntry]:
        return [self.entries[i] for i in sorted(self.entries)]


class LogTransfer:
    """Which chunks of one log are in, and what to ask for next.

    `data` holds the bytes received (zeros where missing); `have[k]` says chunk k is in. A resumed
    transfer starts from the `have` and `data` kept beside the partial file."""

    def __init__(
        self,
        entry: LogEntry,
        have: bytearray | None = None,
        data: bytearray | None = None,
        idle_timeout: float = 0.5,
        merge_gap: int = 16,
    ) -> None:
        self.entry = entry
        self.chunks = -(-entry.size // LOG_DATA_LEN)
        self.have = have if have is not None and len(have) == self.chunks else bytearray(self.chunks)
        self.data = data if data is not None and len(data) == entry.size else bytearray(entry.size)
        self.received = sum(self.have)  # chunks in
        self.idle_timeout, self.merge_gap = idle_timeout, merge_gap
        self.outstanding: DataRequest | None = None
        self.requests = 0  # LOG_REQUEST_DATA sent, the first included
        self._last_activity = 0.0
        self._sent_at: float | None = None  # when the outstanding request went, until its first chunk
        self.response_time: float | None = None  # smoothed request → first chunk (s)

    @property
    def complete(self) -> bool:
        return self.received == self.chunks

    @property
    def bytes_received(self) -> int:
        if self.complete:
            return self.entry.size
        last = self.chunks - 1
        short = self.entry.size - last * LOG_DATA_LEN  # the last chunk may be short
        return self.received * LOG_DATA_LEN - (LOG_DATA_LEN - short if self.have[last] else 0)

    @property
    def re_requests(self) -> int:
        """Requests after the first: missing chunks asked again, or a request that went unanswered."""
        return max(self.requests - 1, 0)

    def _chunk_len(self, k: int) -> int:
        return min(LOG_DATA_LEN, self.entry.size - k * LOG_DATA_LEN)

    def on_data(self, log_id: int, ofs: int, count: int, payload: bytes, now: float) -> bool:
        """One LOG_DATA; True if it brought a new chunk."""
        k, off_grid = divmod(ofs, LOG_DATA_LEN)
        if log_id != self.entry.id or off_grid or k >= self.chunks or count != self._chunk_len(k):
            return False  # another log's, or off the chunk grid
        self._last_activity = now
        if self._sent_at is not None:
            sample, self._sent_at = now - self._sent_at, None
            rt = self.response_time
            self.response_time = sample if rt is None else 0.8 * rt + 0.2 * sample
        request = self.outstanding
        if request is not None and ofs + count >= min(request.ofs + request.count, self.entry.size):
            self.outstanding = None  # the vehicle has sent the last chunk of this request
        if self.have[k]:
            return False  # a chunk that arrived twice
        self.have[k] = 1
        self.data[ofs : ofs + count] = payload[:count]
        self.received += 1
        return True

    def missing_runs(self) -> list[tuple[int, int]]:
        """Runs of missing chunks as (first, end) chunk indices, end exclusive."""
        runs: list[tuple[int, int]] = []
        k = 0
        while k < self.chunks:
            if self.have[k]:
                k += 1
                continue
            start = k
            while k < self.chunks and not self.have[k]:
                k += 1
            runs.append((start, k))
        return runs

    def next_request(self, now: float) -> DataRequest | None:
        """The request to send now, or None (one is outstanding and still answered, or done)."""
        if self.complete:
            self.outstanding = None
            return None
        if self.outstanding is not None and now - self._last_activity < self.wait_limit:
            return None
        if self.requests == 0 and self.received == 0:
            request = DataRequest(self.entry.id, 0, TO_END)
        else:
            runs = self.missing_runs()
            first, end = runs[0]
            for start, stop in runs[1:]:
                if start - end > self.merge_gap:
                    break
                end = stop
            ofs = first * LOG_DATA_LEN
            request = DataRequest(self.entry.id, ofs, min(end * LOG_DATA_LEN, self.entry.size) - ofs)
        self.outstanding = request
        self.requests += 1
        self._last_activity = self._sent_at = now
        return request

    @property
    def wait_limit(self) -> float:
        """How long an outstanding request may stay silent before it is taken as ended (s)."""
        if self.response_time is None:
            return self.idle_timeout
        return min(max(3 * self.response_time, MIN_IDLE), self.idle_timeout)
