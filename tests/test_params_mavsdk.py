"""A second, independent client (MAVSDK 4, native library) reads the vehicle's parameters through
a gcs `--out` forward while gcs tunes them, and sees the new values."""

from __future__ import annotations

import asyncio

import pytest
from conftest import free_port
from live import running_sim, running_station, wait_for

from gcs.runtime.tuning import open_session


@pytest.mark.parametrize("profile,gain,new", [("pixhawk", "ATC_RAT_RLL_P", 0.155), ("px4", "MC_ROLLRATE_P", 0.17)])
def test_mavsdk_sees_values_gcs_tunes(udp_port, profile, gain, new):
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.param import ParamAsync

    out_port = free_port()

    async def scenario():
        connect = f"udpin:127.0.0.1:{udp_port}"
        async with running_station(
            connect, outputs=[f"udpout:127.0.0.1:{out_port}"], estimate=False, request_streams=False
        ) as station:
            async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile=profile) as sim:
                assert await station.link.wait_connected(10)
                session = await open_session(station.params)
                cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
                async with Mavsdk(cfg) as mav:
                    await mav.add_any_connection(f"udpin://127.0.0.1:{out_port}")
                    param = ParamAsync(await mav.first_autopilot(timeout_s=15.0))
                    seen_before = await param.get_param_float(gain)
                    autostart = await param.get_param_int("SYS_AUTOSTART") if profile == "px4" else None
                    # gcs tunes while MAVSDK downloads the whole table
                    lists = sim.received.get("PARAM_REQUEST_LIST", 0)  # gcs's own download's
                    everything = asyncio.ensure_future(param.get_all_params())
                    await wait_for(
                        lambda: sim.received.get("PARAM_REQUEST_LIST", 0) > lists, 15, "MAVSDK's download asked for"
                    )
                    await session.set(gain, new, "test")
                    table = await everything
                    seen_after = await param.get_param_float(gain)
                return (
                    seen_before,
                    seen_after,
                    autostart,
                    sim.params[gain],
                    station.outputs[0].snapshot(),
                    table,
                    sim.params.as_dict(),
                )

    before, after, autostart, stored, out, table, truth = asyncio.run(asyncio.wait_for(scenario(), 90))
    mavsdk_values = {p.name: p.value for p in [*table.float_params, *table.int_params]}
    assert mavsdk_values.keys() == truth.keys()  # MAVSDK's full download, through the forward, is complete
    listed = mavsdk_values.pop(gain)  # old or new: the list and the write crossed
    assert listed == pytest.approx(before) or listed == pytest.approx(new)
    assert all(v == pytest.approx(truth[k]) for k, v in mavsdk_values.items())
    assert before == pytest.approx({"pixhawk": 0.135, "px4": 0.15}[profile])
    assert after == pytest.approx(new) and stored == pytest.approx(new)
    if profile == "px4":
        assert autostart == 4001  # MAVSDK decodes the bytewise INT32 the same way gcs does
    assert out.packets_in > 0
