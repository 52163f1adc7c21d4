"""`gcs params load` of a full saved table against the simulated Pixhawk (ArduCopter 4.x table,
real UDP, the real CLI in a process): the read-only and volatile parameters that differ (STAT_*,
INS_ACC_ID, FORMAT_VERSION) are skipped with a note each and stay as the vehicle has them, and
`--profile` writes the profile's tunables and notes the rest instead of refusing the file."""

from __future__ import annotations

import asyncio

import pytest
from conftest import free_port
from live import running_sim
from test_params_files import _gcs

from gcs.mavlink import param_files
from gcs.mavlink.params import float32

#: A file from another flight day: counters moved on, one gain and one non-tunable changed.
EDITS = (
    ("STAT_RUNTIME,86400", "STAT_RUNTIME,1000"),
    ("STAT_BOOTCNT,12", "STAT_BOOTCNT,3"),
    ("INS_ACC_ID,2753028", "INS_ACC_ID,1"),
    ("FORMAT_VERSION,120", "FORMAT_VERSION,100"),
    ("ATC_RAT_RLL_P,0.135", "ATC_RAT_RLL_P,0.145"),
    ("ANGLE_MAX,3000", "ANGLE_MAX,4500"),
    ("SYSID_THISMAV,1", "SYSID_THISMAV,2"),  # the file is another vehicle's
)


def test_not_loadable_names_ardupilots_read_only_and_volatile_parameters():
    for name in ("STAT_RUNTIME", "STAT_BOOTCNT", "STAT_FLTTIME", "FORMAT_VERSION", "INS_ACC_ID", "INS_GYR2_ID",
                 "COMPASS_DEV_ID3", "BARO1_DEVID", "GND_ABS_PRESS", "ARSPD_OFFSET", "CMD_TOTAL",
                 "SYSID_THISMAV", "MAV_SYSID", "MAV_SYS_ID"):  # fmt: skip
        assert param_files.not_loadable(name), name
    for name in ("ATC_RAT_RLL_P", "INS_ACCOFFS_X", "COMPASS_DEC", "STATUS", "SERIAL1_BAUD", "INS_ACC_IDX"):
        assert param_files.not_loadable(name) is None, name


def test_full_file_load_skips_counters_and_profile_load_writes_only_tunables(tmp_path):
    saved, edited = tmp_path / "vehicle.param", tmp_path / "edited.param"

    async def scenario():
        port = free_port()
        link = ["--connect", f"udpin:127.0.0.1:{port}"]  # params record only with --record
        async with running_sim(f"udpout:127.0.0.1:{port}", profile="pixhawk") as sim:
            before = sim.params.as_dict()
            param_files.save(saved, before)  # as `gcs params save` writes it (test_params_files)
            text = saved.read_text()
            for old, new in EDITS:
                assert f"\n{old}\n" in text, old
                text = text.replace(f"\n{old}\n", f"\n{new}\n")
            edited.write_text(text)

            rc, out, err = await _gcs("load", str(edited), "--profile", "arducopter-4", *link)
            assert rc == 0, err
            assert "wrote 1 of 1 parameters, each verified; skipped 6" in out
            assert "skipped STAT_RUNTIME (file 1000, vehicle 86400): statistics the vehicle keeps (read-only)" in out
            assert "skipped INS_ACC_ID (file 1, vehicle 2753028): sensor id" in out
            assert "skipped ANGLE_MAX (file 4500, vehicle 3000): not in the tuning profile arducopter-4" in out
            after_profile = sim.params.as_dict()
            assert after_profile["ATC_RAT_RLL_P"] == float32(0.145)
            assert {k: v for k, v in after_profile.items() if k != "ATC_RAT_RLL_P"} == {
                k: v for k, v in before.items() if k != "ATC_RAT_RLL_P"
            }

            rc, out, err = await _gcs("load", str(edited), *link)
            assert rc == 0, err
            assert "wrote 1 of 1 parameters, each verified; skipped 5" in out  # ANGLE_MAX now written
            for name in ("STAT_RUNTIME", "STAT_BOOTCNT", "INS_ACC_ID", "FORMAT_VERSION"):
                assert f"skipped {name} " in out
            assert "skipped SYSID_THISMAV (file 2, vehicle 1): the vehicle's own system id" in out
            after = sim.params.as_dict()
            assert after["ANGLE_MAX"] == 4500
            for name in ("STAT_RUNTIME", "STAT_BOOTCNT", "INS_ACC_ID", "FORMAT_VERSION", "SYSID_THISMAV"):
                assert after[name] == before[name], name

    asyncio.run(asyncio.wait_for(scenario(), 180))


@pytest.mark.parametrize("name", ["STAT_RUNTIME", "ATC_RAT_RLL_P"])
def test_skip_is_by_name_not_by_value(name):
    changes = [param_files.Difference(name, 1.0, 2.0)]
    write, skipped = param_files.split_loadable(changes)
    assert (len(write), len(skipped)) == ((0, 1) if name.startswith("STAT_") else (1, 0))
