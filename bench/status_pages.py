"""Pages polling `GET /api/status`, each on its own keep-alive connection, timing every answer
twice: from just before the request's send to the kernel's receive time of the answer's last byte
(SO_TIMESTAMPNS: the server's doing and the loopback's microseconds), and to when the page's
thread got to it (adding the polling process's own wait for a core and for the GIL).

    python -m bench.status_pages URL PAGES PERIOD SECONDS

One thread per page in one process, plain sockets. A page has one request outstanding at a
time, so no later answer shares the kernel time of an earlier one. At the end one JSON object:
`server_ms` and `seen_ms` (every request's figure, ms), `requests` (each one's send and answer
times and the page's port, for bench.loop_trace), the process's CPU and run-queue wait (s).
"""

from __future__ import annotations

import json
import re
import socket
import sys
import threading
import time
import urllib.parse

from bench.sched import Sched, thread_sched
from bench.ws_readers import SO_TIMESTAMPNS, kernel_time, realtime_offset

Timing = tuple[float, float, float]  # sent, kernel receive, read (CLOCK_MONOTONIC s)


def get(sock: socket.socket, request: bytes, offset: float) -> Timing:
    """(sent, kernel receive of the last byte, read) of one request, CLOCK_MONOTONIC s."""
    sent = time.monotonic()
    sock.sendall(request)
    data, kernel, length = b"", None, None
    while length is None or len(data) < length:
        chunk, ancillary, _, _ = sock.recvmsg(65536, socket.CMSG_SPACE(16))
        if not chunk:
            raise ConnectionError("the server closed the connection")
        data += chunk
        kernel = kernel_time(ancillary) or kernel
        if length is None and b"\r\n\r\n" in data:
            head = data.partition(b"\r\n\r\n")[0]
            size = re.search(rb"(?im)^content-length:\s*(\d+)", head)
            if size is None:
                raise ConnectionError("an answer without Content-Length")
            length = len(head) + 4 + int(size.group(1))
    read = time.monotonic()
    return sent, read if kernel is None else kernel - offset, read


def page(url: str, period: float, end: float, offset: float, out: list[tuple[Timing, int]], cpu: list[Sched]) -> None:
    parts = urllib.parse.urlsplit(url)
    sock = socket.create_connection((parts.hostname, parts.port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    request = f"GET {parts.path} HTTP/1.1\r\nHost: {parts.netloc}\r\n\r\n".encode()
    port = sock.getsockname()[1]
    start = thread_sched()
    while time.monotonic() < end:
        sent, kernel, read = get(sock, request, offset)
        out.append(((sent, kernel, read), port))
        time.sleep(max(0.0, period - (time.monotonic() - sent)))
    cpu.append(thread_sched() - start)
    sock.close()


def main(url: str, pages: int, period: float, seconds: float) -> None:
    offset = realtime_offset()
    end = time.monotonic() + seconds
    got: list[tuple[Timing, int]] = []
    cpu: list[Sched] = []
    threads = [threading.Thread(target=page, args=(url, period, end, offset, got, cpu)) for _ in range(pages)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(
        json.dumps(
            {
                "server_ms": [1000 * (kernel - sent) for (sent, kernel, _), _ in got],
                "seen_ms": [1000 * (read - sent) for (sent, _, read), _ in got],
                # every request: sent, the answer in the socket (CLOCK_MONOTONIC s), the page's port
                "requests": [(sent, kernel, port) for (sent, kernel, _), port in got],
                "cpu_s": sum(s.cpu_s for s in cpu),
                "run_delay_s": sum(s.run_delay_s for s in cpu),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
