"""A real, independent MAVLink client (MAVSDK 4, native library) reads attitude from the
simulated vehicle through a gcs `--out` forward."""

from __future__ import annotations

import asyncio
import math

from conftest import free_port
from live import running_sim, running_station, wait_for


def test_mavsdk_reads_attitude_through_forward_output(udp_port):
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    out_port = free_port()

    async def scenario():
        connect = f"udpin:127.0.0.1:{udp_port}"
        async with running_station(connect, outputs=[f"udpout:127.0.0.1:{out_port}"]) as station:
            onboard = station.bus.subscribe("onboard", types=["ATTITUDE"], maxlen=100_000)
            async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"):
                assert await station.link.wait_connected(10)
                cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
                async with Mavsdk(cfg) as mav:
                    await mav.add_any_connection(f"udpin://127.0.0.1:{out_port}")
                    system = await mav.first_autopilot(timeout_s=15.0)
                    telemetry = TelemetryAsync(system)
                    seen = []
                    async for euler in telemetry.subscribe_attitude_euler():
                        seen.append((euler.roll_deg, euler.pitch_deg, euler.yaw_deg))
                        if len(seen) >= 50:
                            break
                await wait_for(lambda: station.outputs[0].packets_in > 0, 5, "packets back from MAVSDK")
            return seen, onboard.drain(), station.outputs[0].snapshot()

    seen, onboard, out_status = asyncio.run(asyncio.wait_for(scenario(), 60))
    assert len(seen) == 50
    assert out_status.packets_out > 100 and out_status.packets_in > 0
    # Every angle MAVSDK reported is one the vehicle actually sent.
    sent = {(round(math.degrees(m.msg.roll), 3), round(math.degrees(m.msg.pitch), 3)) for m in onboard}
    matched = sum((round(r, 3), round(p, 3)) in sent for r, p, _ in seen)
    assert matched >= 45, f"only {matched} of 50 MAVSDK attitudes match packets the vehicle sent"
    assert len(set(seen)) > 10  # a live, changing attitude, not one repeated value
