"""The built-in simulated vehicle: scripted motion with known truth, realistic sensors, and the
link behaviour of an APM 2.5, a Pixhawk (ArduPilot 4.x) or a PX4 autopilot.

    sim = SimVehicle(profile="apm25", script="bench", seed=0)
    await sim.run("udpout:127.0.0.1:14550")      # or tcpin:…, pty:/path
    packets = sim.advance(10.0)                   # deterministic, no I/O: tests and soak runs
"""

from gcs.sim.motion import Truth
from gcs.sim.sensors import Home, SensorFaults
from gcs.sim.vehicle import SimVehicle

__all__ = ["SimVehicle", "SensorFaults", "Truth", "Home"]
