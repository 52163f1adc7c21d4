"""Sensor models of the simulated vehicle: what its IMU, compass, barometer and GPS read.

Each model turns the truth (gcs.sim.motion.Truth) into a noisy SI reading with the errors named
in `SensorFaults`. Noise comes from a seeded numpy Generator drawn in blocks (one numpy call per
few thousand samples, plain floats per sample), so the same seed gives the same readings and a
400 Hz sample costs microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from gcs.core.declination import wmm_declination
from gcs.core.rotation import vec3
from gcs.sim.motion import Truth

#: Metres per degree of latitude on a spherical earth (WGS-84 equatorial radius), for the
#: flat-earth NED → lat/lon used over the few hundred metres a script covers.
EARTH_RADIUS = 6378137.0


@dataclass
class SensorFaults:
    """Sensor errors and the magnetic field they measure. Every error term set to 0 gives perfect
    sensors (`SensorFaults.perfect()`); the field geometry is not an error and stays.

    Noise values are per-sample standard deviations at whatever rate the sample is taken (the
    firmware sends one instantaneous sample per message, so this is what a ground station sees).
    """

    gyro_noise: float = 0.002
    """Gyro white noise, σ per sample per axis, rad/s."""
    gyro_bias: float = 0.005
    """Initial gyro bias, σ per axis of the seeded draw, rad/s (residual after boot calibration)."""
    gyro_bias_walk: float = 1e-4
    """Gyro bias random walk, rad/s/√s (bias σ grows as this × √t)."""
    accel_noise: float = 0.05
    """Accelerometer white noise, σ per sample per axis, m/s²."""
    vibration: float = 0.3
    """Motor vibration amplitude on the accelerometer, m/s² (sinusoid, phase differs per axis)."""
    vibration_freq: float = 95.0
    """Motor vibration frequency, Hz (aliases into the sampled stream like real vibration)."""
    mag_noise: float = 0.002
    """Magnetometer white noise, σ per sample per axis, gauss."""
    mag_hard_iron: tuple[float, float, float] = (0.01, -0.005, 0.01)
    """Uncompensated hard-iron offset added in body FRD, gauss."""
    declination: float | None = None
    """Magnetic declination, rad, east of true north positive. None: the World Magnetic Model's at
    the vehicle's home on `SIM_DATE` (`home_declination`; −8.65° at the default home near Bogotá)."""
    inclination: float = 0.55
    """Magnetic inclination (dip), rad, positive when the field points down (about 31°)."""
    field_strength: float = 0.33
    """Earth field magnitude, gauss."""
    baro_noise: float = 3.0
    """Barometer white noise, σ, Pa."""
    gps_pos_noise: float = 0.5
    """GPS position white noise, σ per fix per axis, m."""
    gps_vel_noise: float = 0.1
    """GPS velocity white noise, σ per fix per axis, m/s."""

    ERROR_TERMS = (
        "gyro_noise",
        "gyro_bias",
        "gyro_bias_walk",
        "accel_noise",
        "vibration",
        "mag_noise",
        "mag_hard_iron",
        "baro_noise",
        "gps_pos_noise",
        "gps_vel_noise",
    )

    @classmethod
    def perfect(cls, **overrides) -> SensorFaults:
        """Error-free sensors (same field geometry); keyword overrides switch single faults on."""
        zero = {name: (0.0, 0.0, 0.0) if name == "mag_hard_iron" else 0.0 for name in cls.ERROR_TERMS}
        return cls(**{**zero, **overrides})

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    def earth_field(self) -> tuple[float, float, float]:
        """Earth magnetic field in NED, gauss: horizontal part along the declination azimuth."""
        horizontal = self.field_strength * math.cos(self.inclination)
        declination = self.declination if self.declination is not None else home_declination(Home())
        return (
            horizontal * math.cos(declination),
            horizontal * math.sin(declination),
            self.field_strength * math.sin(self.inclination),
        )


class Normals:
    """Standard normal draws from a seeded Generator, fetched a block at a time."""

    BLOCK = 4096

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self._buffer: list[float] = []
        self._next = 0

    def draw(self) -> float:
        if self._next >= len(self._buffer):
            self._buffer = self.rng.standard_normal(self.BLOCK).tolist()
            self._next = 0
        value = self._buffer[self._next]
        self._next += 1
        return value

    def uniform(self) -> float:
        """A uniform draw in [0, 1) from the same stream (Φ of a normal)."""
        return 0.5 * (1.0 + math.erf(self.draw() / math.sqrt(2.0)))


@dataclass(frozen=True, slots=True)
class ImuReading:
    """One IMU + compass sample: t s, gyro rad/s, accel m/s² (specific force), mag gauss; FRD."""

    t: float
    gyro: tuple[float, float, float]
    accel: tuple[float, float, float]
    mag: tuple[float, float, float]


class ImuModel:
    """Gyro with white noise and a random-walk bias, accelerometer with noise and vibration,
    magnetometer with noise and hard iron. Samples must come in non-decreasing time."""

    def __init__(self, faults: SensorFaults, rng: np.random.Generator) -> None:
        self.faults = faults
        self.normals = Normals(rng)
        draw = self.normals.draw
        self.bias = [faults.gyro_bias * draw() for _ in range(3)]
        self.vibration_phase = [2 * math.pi * self.normals.uniform() for _ in range(3)]
        self._t = 0.0

    def sample(self, truth: Truth) -> ImuReading:
        f, draw = self.faults, self.normals.draw
        dt = truth.t - self._t
        self._t = truth.t
        if dt > 0 and f.gyro_bias_walk:
            step = f.gyro_bias_walk * math.sqrt(dt)
            self.bias = [b + step * draw() for b in self.bias]
        w = truth.omega_body
        gyro = vec3(float(w[i]) + self.bias[i] + f.gyro_noise * draw() for i in range(3))
        sf = truth.specific_force
        omega_t = 2 * math.pi * f.vibration_freq * truth.t
        accel = vec3(
            float(sf[i]) + f.vibration * math.sin(omega_t + self.vibration_phase[i]) + f.accel_noise * draw()
            for i in range(3)
        )
        field_body = truth.rotation.T @ np.array(f.earth_field())
        mag = vec3(float(field_body[i]) + f.mag_hard_iron[i] + f.mag_noise * draw() for i in range(3))
        return ImuReading(truth.t, gyro, accel, mag)


@dataclass(frozen=True, slots=True)
class Home:
    """Where NED (0, 0, 0) is: latitude/longitude in degrees, altitude m above mean sea level.
    Default: a field near Bogotá (the seed thesis), 2556 m MSL."""

    lat: float = 4.6383
    lon: float = -74.0840
    alt: float = 2556.0

    def lat_lon(self, north: float, east: float) -> tuple[float, float]:
        """Flat-earth latitude/longitude (degrees) of a point north/east metres from home."""
        lat = self.lat + math.degrees(north / EARTH_RADIUS)
        lon = self.lon + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(self.lat))))
        return lat, lon


#: The date (decimal year) the simulated magnetic field is taken at: fixed, so that the same seed
#: gives the same bytes on any day (a ground station dating the model by today's date differs
#: from it by the secular variation only, under 0.2°/year at the default home).
SIM_DATE = 2026.0


def home_declination(home: Home) -> float:
    """The World Magnetic Model's declination at home on SIM_DATE, rad (gcs.core.declination)."""
    return wmm_declination(home.lat, home.lon, home.alt, SIM_DATE)


@dataclass(frozen=True, slots=True)
class GpsFix:
    """One receiver fix: t s; lat/lon deg; alt m MSL; vel_ned m/s; ground speed m/s; course rad."""

    t: float
    lat: float
    lon: float
    alt: float
    vel_ned: tuple[float, float, float]
    ground_speed: float
    course: float


class GpsModel:
    """A receiver with white position and velocity noise around the truth."""

    def __init__(self, faults: SensorFaults, home: Home, rng: np.random.Generator) -> None:
        self.faults, self.home = faults, home
        self.normals = Normals(rng)

    def fix(self, truth: Truth) -> GpsFix:
        f, draw = self.faults, self.normals.draw
        p, v = truth.pos, truth.vel_ned
        north, east, down = (float(p[i]) + f.gps_pos_noise * draw() for i in range(3))
        vel = vec3(float(v[i]) + f.gps_vel_noise * draw() for i in range(3))
        lat, lon = self.home.lat_lon(north, east)
        speed = math.hypot(vel[0], vel[1])
        return GpsFix(truth.t, lat, lon, self.home.alt - down, vel, speed, math.atan2(vel[1], vel[0]))


class BaroModel:
    """Static pressure of the International Standard Atmosphere at the true altitude, with noise."""

    def __init__(self, faults: SensorFaults, home: Home, rng: np.random.Generator) -> None:
        self.faults, self.home = faults, home
        self.normals = Normals(rng)

    def pressure(self, truth: Truth) -> float:
        """Pa."""
        altitude = self.home.alt - float(truth.pos[2])
        return 101325.0 * (1 - 2.25577e-5 * altitude) ** 5.25588 + self.faults.baro_noise * self.normals.draw()

    def temperature(self, truth: Truth) -> float:
        """°C: ISA at the altitude."""
        return 15.0 - 0.0065 * (self.home.alt - float(truth.pos[2]))
