"""`--baud 0` on a serial port: termios' B0 is no rate but "hang up" (DTR dropped, which resets an
APM 2.5 on USB). It was taken as a rate: the port opened and the command listened to nothing,
exit 1 with "no heartbeat yet", instead of one line naming the option."""

from __future__ import annotations

import os
import pty
import subprocess
import sys


def test_baud_zero_is_refused_in_one_line_naming_the_option(tmp_path):
    master, slave = pty.openpty()
    port = tmp_path / "ttyUSB0"
    port.symlink_to(os.ttyname(slave))
    try:
        for command in (["status", "--duration", "1"], ["params", "get", "ATC_RAT_RLL_P"]):
            done = subprocess.run(
                [sys.executable, "-m", "gcs", *command, "--connect", str(port), "--baud", "0"],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            assert done.returncode == 2, done.stdout + done.stderr
            assert done.stderr.count("\n") == 1 and done.stderr.startswith("gcs "), done.stderr
            assert done.stderr.endswith(
                ": --baud 0: give a rate such as 57600, or 'auto' (0 would hang up the serial line)\n"
            ), done.stderr
    finally:
        os.close(master)
        os.close(slave)
