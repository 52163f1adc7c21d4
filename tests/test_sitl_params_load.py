"""`gcs params load` of a full table saved from the real ArduCopter SITL (../shared/sitl, 1354
parameters) after its counters moved on: the read-only and volatile parameters are skipped with a
note each and keep the vehicle's values; `--profile arducopter-4` writes the one changed gain."""

from __future__ import annotations

import asyncio
import re
import sys

import pytest
from conftest import ROOT
from test_sitl_copter import sitl  # noqa: F401  (the fixture)

from gcs.mavlink import param_files

pytestmark = pytest.mark.slow


async def _gcs(*args: str) -> tuple[int | None, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "gcs", "params", *args, cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 180)
    return proc.returncode, out.decode(), err.decode()


@pytest.mark.timeout(400)
def test_full_sitl_table_loads_back_without_touching_counters_or_sensor_ids(sitl, tmp_path):  # noqa: F811
    link = ["--connect", f"tcp:127.0.0.1:{sitl}"]  # params record only with --record
    saved, edited = tmp_path / "copter.param", tmp_path / "edited.param"

    async def scenario():
        rc, out, err = await _gcs("save", str(saved), *link)
        assert rc == 0, err
        table = param_files.load(saved)
        volatile = sorted(name for name in table if param_files.not_loadable(name))
        text = saved.read_text()
        gain = table["ATC_RAT_RLL_P"]
        changed = {"STAT_RUNTIME": table["STAT_RUNTIME"] + 5000, "STAT_BOOTCNT": table["STAT_BOOTCNT"] + 7,
                   "INS_ACC_ID": 1, "FORMAT_VERSION": table["FORMAT_VERSION"] - 1,
                   "ATC_RAT_RLL_P": round(gain + 0.01, 4)}  # fmt: skip
        for name, value in changed.items():
            text, n = re.subn(rf"^{name},.*$", f"{name},{value:g}", text, flags=re.M)
            assert n == 1, name
        edited.write_text(text)
        rc, out, err = await _gcs("load", str(edited), "--profile", "arducopter-4", *link)
        assert rc == 0, (out, err)
        rc_get, after, err_get = await _gcs("get", *changed, *link)
        assert rc_get == 0, err_get
        return table, volatile, out, {line.split()[0]: float(line.split()[1]) for line in after.splitlines()}

    table, volatile, out, after = asyncio.run(scenario())
    print(f"{len(table)} parameters, {len(volatile)} not loadable: {', '.join(volatile)}")
    assert len(table) > 1000 and {"STAT_RUNTIME", "STAT_BOOTCNT", "INS_ACC_ID", "FORMAT_VERSION"} <= set(volatile)
    assert "wrote 1 of 1 parameters, each verified" in out
    for name in ("STAT_RUNTIME", "STAT_BOOTCNT", "INS_ACC_ID", "FORMAT_VERSION"):
        assert f"skipped {name} (file " in out, name
    assert after["ATC_RAT_RLL_P"] == pytest.approx(table["ATC_RAT_RLL_P"] + 0.01, rel=1e-5)
    # the file's INS_ACC_ID (1) was not written; the vehicle's own may still change (SITL sets it once its
    # simulated IMU is up, which can be after the first download)
    assert after["INS_ACC_ID"] != 1 and after["FORMAT_VERSION"] == table["FORMAT_VERSION"]
    assert after["STAT_BOOTCNT"] == table["STAT_BOOTCNT"]
    assert after["STAT_RUNTIME"] < table["STAT_RUNTIME"] + 5000  # kept counting from the vehicle's value
