"""The recording's writer thread: a fault while encoding a flush's tables stops the recording
with its reason, after the flush's raw bytes reach the disk; it never ends silently while the
station still reads "recording" (which it did: the thread died on the exception, `failed` stayed
None, and the files stopped growing with no error anywhere)."""

from __future__ import annotations

import threading

from gcs.sessions.writer import TABLES, SessionWriter


def test_an_encoding_fault_stops_the_recording_with_its_reason_and_keeps_the_raw_bytes(tmp_path):
    reported: list[tuple[Exception, str]] = []
    stopped = threading.Event()
    encoded = threading.Event()
    appended = threading.Event()  # the second flush fails only once "during" waits in its buffer
    flushes = 0

    def on_error(exc: Exception, name: str) -> None:
        reported.append((exc, name))
        stopped.set()

    def tables() -> dict[str, bytes]:
        nonlocal flushes
        flushes += 1
        if flushes == 1:
            encoded.set()
            return {"attitude.arrows": b"first batch"}
        appended.wait(30)
        raise ValueError("could not convert 'x' to double")

    writer = SessionWriter(tmp_path, 0.05, on_error, sources=[tables])
    writer.append("telemetry.tlog", b"before ")
    writer.start()
    assert encoded.wait(30), "the first flush encoded its tables"
    writer.append("telemetry.tlog", b"during")
    appended.set()
    assert stopped.wait(30), "the encoding fault was reported"
    writer.close()

    assert len(reported) == 1, reported
    exc, name = reported[0]
    assert name == TABLES and isinstance(exc, ValueError), reported
    assert writer.failed is exc
    assert (tmp_path / "attitude.arrows").read_bytes() == b"first batch"
    # the raw bytes of the flush whose tables failed are on disk too; nothing after the stop
    assert (tmp_path / "telemetry.tlog").read_bytes() == b"before during"
    writer.append("telemetry.tlog", b" after")
    assert (tmp_path / "telemetry.tlog").read_bytes() == b"before during"
