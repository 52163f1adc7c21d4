"""One vehicle's MAVLink messages → SI samples on its clock (the one place where a live stream
and a replayed .tlog become samples, so live and offline numbers come from identical input)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from operator import attrgetter

import numpy as np

from gcs.core.declination import WMM_EPOCH, VehicleDeclination, decimal_year
from gcs.core.estimation import EstimationInput, GainChange
from gcs.core.estimators.stepping import ImuRow
from gcs.core.samples import (
    REBOOT_CLOCK_JUMP,
    AttitudeSample,
    BaroSample,
    GpsSample,
    ImuSample,
    cdeg_to_rad,
    cdegc_to_degc,
    cm_to_m,
    degE7_to_deg,
    hpa_to_pa,
    mg_to_mps2,
    mgauss_to_gauss,
    mm_to_m,
    mrad_to_rads,
    ms_to_s,
    usec_to_s,
)
from gcs.mavlink.dialect import MAVLinkMessage, mavlink
from gcs.mavlink.imu_packets import IMU_AXES, ImuPacket
from gcs.mavlink.params import param_name

#: MAVLink's "unknown" marker for GPS_RAW_INT vel / cog (UINT16_MAX).
UINT16_UNKNOWN = 65535


def _imu_from_scaled_axes(t: float, axes: tuple[float, ...], source: str) -> ImuSample:
    """RAW_IMU and SCALED_IMU* share field names and units (ArduPilot fills RAW_IMU scaled);
    `axes`: their `IMU_AXES`."""
    row = _row_from_scaled_axes(t, axes)
    mag = np.array(row[7:10]) if row[10] else None
    return ImuSample(t, np.array(row[1:4]), np.array(row[4:7]), mag, source)


def _imu_from_highres_axes(t: float, axes: tuple[float, ...]) -> ImuSample:
    """HIGHRES_IMU (PX4): already SI — m/s², rad/s, gauss; `axes`: its `IMU_AXES` as Python floats
    (float64 arrays without asking for the type, which costs as much again as building them)."""
    return ImuSample(t, np.array(axes[3:6]), np.array(axes[0:3]), np.array(axes[6:9]), "HIGHRES_IMU")


def _row_from_scaled_axes(t: float, axes: tuple[float, ...]) -> ImuRow:
    """RAW_IMU / SCALED_IMU* axes as their ImuBatch row (SI units, no arrays): the one place their
    units are converted (`_imu_from_scaled_axes` builds its ImuSample from it)."""
    xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag = axes
    gyro = mrad_to_rads(xgyro), mrad_to_rads(ygyro), mrad_to_rads(zgyro)
    accel = mg_to_mps2(xacc), mg_to_mps2(yacc), mg_to_mps2(zacc)
    field = mgauss_to_gauss(xmag), mgauss_to_gauss(ymag), mgauss_to_gauss(zmag)
    if field[0] or field[1] or field[2]:  # an all-zero field means "no compass", not a zero field
        return (t, *gyro, *accel, *field, 1.0)
    return (t, *gyro, *accel, 0.0, 0.0, 0.0, 0.0)


def _row_from_highres_axes(t: float, axes: tuple[float, ...]) -> ImuRow:
    """`_imu_from_highres_axes` as its ImuBatch row: gyro, accel, the field (always there)."""
    xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag = axes
    return (t, xgyro, ygyro, zgyro, xacc, yacc, zacc, xmag, ymag, zmag, 1.0)


#: IMU packet type → its row
_ROWS: dict[str, Callable[[float, tuple[float, ...]], ImuRow]] = {
    "RAW_IMU": _row_from_scaled_axes,
    "SCALED_IMU": _row_from_scaled_axes,
    "SCALED_IMU2": _row_from_scaled_axes,
    "SCALED_IMU3": _row_from_scaled_axes,
    "HIGHRES_IMU": _row_from_highres_axes,
}

_AXES = attrgetter(*IMU_AXES)


def imu_from_raw_imu(msg: MAVLinkMessage) -> ImuSample:
    """RAW_IMU: time_usec since boot; accel mG, gyro mrad/s, mag mgauss (ArduPilot's scaled values)."""
    return _imu_from_scaled_axes(usec_to_s(msg.time_usec), _AXES(msg), msg.get_type())


def imu_from_scaled_imu(msg: MAVLinkMessage) -> ImuSample:
    """SCALED_IMU / SCALED_IMU2 / SCALED_IMU3: time_boot_ms; same units as RAW_IMU."""
    return _imu_from_scaled_axes(ms_to_s(msg.time_boot_ms), _AXES(msg), msg.get_type())


def imu_from_highres_imu(msg: MAVLinkMessage) -> ImuSample:
    """HIGHRES_IMU (PX4): time_usec since boot."""
    return _imu_from_highres_axes(usec_to_s(msg.time_usec), tuple(map(float, _AXES(msg))))


def imu_from_packet(packet: ImuPacket) -> ImuSample:
    """The sample of an IMU message read from its bytes (gcs.mavlink.imu_packets): the same
    conversions as from the decoded message."""
    if packet.type == "HIGHRES_IMU":
        return _imu_from_highres_axes(packet.t, packet.axes)
    return _imu_from_scaled_axes(packet.t, packet.axes, packet.type)


def gps_from_gps_raw_int(msg: MAVLinkMessage) -> GpsSample:
    """GPS_RAW_INT: lat/lon degE7, alt mm, vel cm/s, cog cdeg (65535 = unknown), time_usec.

    The NED velocity is built from ground speed and course (GPS_RAW_INT has no vertical speed,
    so vd = 0); it is None when either is unknown.
    """
    speed = math.nan if msg.vel == UINT16_UNKNOWN else cm_to_m(msg.vel)
    course = math.nan if msg.cog == UINT16_UNKNOWN else cdeg_to_rad(msg.cog)
    vel_ned = None
    if math.isfinite(speed) and math.isfinite(course):
        vel_ned = np.array([speed * math.cos(course), speed * math.sin(course), 0.0])
    return GpsSample(
        usec_to_s(msg.time_usec),
        degE7_to_deg(msg.lat),
        degE7_to_deg(msg.lon),
        mm_to_m(msg.alt),
        speed,
        course,
        vel_ned,
        int(msg.fix_type),
        "GPS_RAW_INT",
    )


def baro_from_scaled_pressure(msg: MAVLinkMessage) -> BaroSample:
    """SCALED_PRESSURE*: press_abs hPa, temperature cdegC, time_boot_ms."""
    return BaroSample(
        ms_to_s(msg.time_boot_ms), hpa_to_pa(msg.press_abs), cdegc_to_degc(msg.temperature), msg.get_type()
    )


#: IMU message type → converter.
_IMU_CONVERTERS: dict[str, Callable[[MAVLinkMessage], ImuSample]] = {
    "RAW_IMU": imu_from_raw_imu,
    "SCALED_IMU": imu_from_scaled_imu,
    "SCALED_IMU2": imu_from_scaled_imu,
    "SCALED_IMU3": imu_from_scaled_imu,
    "HIGHRES_IMU": imu_from_highres_imu,
}

#: MAVLink message type → converter.
CONVERTERS: dict[str, Callable[[MAVLinkMessage], ImuSample | GpsSample | BaroSample]] = {
    **_IMU_CONVERTERS,
    "GPS_RAW_INT": gps_from_gps_raw_int,
    "SCALED_PRESSURE": baro_from_scaled_pressure,
    "SCALED_PRESSURE2": baro_from_scaled_pressure,
    "SCALED_PRESSURE3": baro_from_scaled_pressure,
}


def sample_from_message(msg: MAVLinkMessage) -> ImuSample | GpsSample | BaroSample | None:
    """The sample a pymavlink message carries, or None for message types that carry no sensor data."""
    convert = CONVERTERS.get(msg.get_type())
    return convert(msg) if convert else None


#: MAVLink attitude message → reference name.
REFERENCE_MESSAGES = {"ATTITUDE": "onboard", "AHRS2": "ahrs2", "SIMSTATE": "truth"}
#: The reference name of ATTITUDE while the vehicle's EKF says its attitude is not yet (or no
#: longer) good (`MessageSampler`): scored apart from "onboard", so that it is not taken for the
#: estimators' error against the vehicle's attitude.
UNREADY = "onboard-unready"
#: EKF_STATUS_REPORT flags (ArduPilot) of an EKF whose attitude can be trusted: attitude good,
#: and not "never healthy yet".
EKF_READY, EKF_NEVER_HEALTHY = mavlink.EKF_ATTITUDE, mavlink.EKF_UNINITIALIZED
#: s of vehicle time after boot in which ATTITUDE is UNREADY until the boot's first
#: EKF_STATUS_REPORT says otherwise: an ArduPlane SITL's ATTITUDE before its first report (1.7 to
#: 3.1 s) was 4.3° pitch and 13.5° yaw off the truth, and set the session's max error against
#: onboard. A vehicle that sends no report (PX4, an APM 2.5) is taken as ready from then on.
BOOT_SETTLE_S = 5.0

#: Messages whose time_usec is microseconds since boot (others may carry UNIX or GPS time).
_BOOT_USEC_MESSAGES = frozenset({"RAW_IMU", "HIGHRES_IMU"})


#: Messages without a time field that ArduPilot sends *before* the first timestamped message of
#: their scheduler slot (ap_message order: MSG_AHRS 1, MSG_AHRS2 2, MSG_ATTITUDE 3, ...): they take
#: the time of the next timestamped message. Measured on a SITL recording: docs/estimators/comparison.md
LEADING_MESSAGES = frozenset({"AHRS2"})


class VehicleClock:
    """The latest vehicle time (s since boot) seen from each system, for messages without one.

    Timestamped messages are those with `time_boot_ms`, plus RAW_IMU / HIGHRES_IMU `time_usec`.
    A message without a timestamp takes the time of its own scheduler slot: SIMSTATE (sent after
    the slot's ATTITUDE and RAW_IMU) the time of the most recent timestamped message from the same
    system, AHRS2 (`LEADING_MESSAGES`, sent before the slot's ATTITUDE) that of the next one. (AHRS3,
    a third estimator on old firmware, is not a reference and not taken.)
    """

    def __init__(self) -> None:
        self.latest: dict[int, float] = {}

    def time_of(self, msg: MAVLinkMessage | ImuPacket) -> float | None:
        """The vehicle time msg carries itself, or None."""
        if isinstance(msg, ImuPacket):
            return msg.t
        if hasattr(msg, "time_boot_ms"):
            return ms_to_s(msg.time_boot_ms)
        if msg.get_type() in _BOOT_USEC_MESSAGES:
            return usec_to_s(msg.time_usec)
        return None

    def observe(self, msg: MAVLinkMessage) -> float | None:
        """Update from msg and return the latest vehicle time of its system (None: nothing seen yet)."""
        system = msg.get_srcSystem()
        t = self.time_of(msg)
        if t is not None:
            self.latest[system] = t
        return self.latest.get(system)


def attitude_from_message(msg: MAVLinkMessage, t: float) -> AttitudeSample | None:
    """ATTITUDE / AHRS2 / SIMSTATE (roll, pitch, yaw in rad) at vehicle time t, else None."""
    source = REFERENCE_MESSAGES.get(msg.get_type())
    if source is None:
        return None
    return AttitudeSample(t, float(msg.roll), float(msg.pitch), float(msg.yaw), source)


# --- one vehicle's message stream → samples ------------------------------------------------------

#: IMU message types in order of preference: RAW_IMU (ArduPilot's first IMU) and HIGHRES_IMU
#: (PX4) are primary; SCALED_IMU* are used only when no primary one arrives.
IMU_TYPES = ("RAW_IMU", "HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
_PRIMARY_IMU = frozenset(IMU_TYPES[:2])
#: Seconds of vehicle time a secondary IMU type must stream alone before it is chosen.
SECONDARY_IMU_WAIT = 2.0
#: A GPS time further than this from the vehicle clock is not boot time (UNIX/GPS epoch).
GPS_CLOCK_TOLERANCE = 5.0


class MessageSampler:
    """One vehicle's MAVLink messages, in arrival order → samples on its clock.

    The one place where a live stream and a replayed .tlog become samples, so live and offline numbers
    come from identical input. The vehicle is `system` (None: the first that sends IMU data; until
    one does, the ATTITUDE of `attitude_system`, the first that sends one, is passed on); the IMU
    stream is `imu_type` (None: RAW_IMU or HIGHRES_IMU at once, else a SCALED_IMU* type once it has
    streamed alone for SECONDARY_IMU_WAIT s). GPS_RAW_INT time_usec is used when it is boot
    time; otherwise (UNIX time on ArduPilot) the fix gets the vehicle time at its arrival.

    ATTITUDE is the reference "onboard" unless the vehicle's last EKF_STATUS_REPORT said its EKF
    was not initialised or its attitude not good: it is then `UNREADY`. At boot an ArduPlane's
    ATTITUDE comes from a DCM still settling and swings to ~70° pitch on the ground for a few
    seconds, which scored as "onboard" dominated every estimator's session error
    (docs/estimators/comparison.md). Before the boot's first report, ATTITUDE is `UNREADY` for
    the first BOOT_SETTLE_S of vehicle time and `onboard` after it: a vehicle that sends no
    EKF_STATUS_REPORT (PX4, APM 2.5) is taken as ready once its boot has settled. PX4's
    ESTIMATOR_STATUS is not needed for this: its EKF2 publishes no attitude while its own is not
    valid, so an ATTITUDE from it was good.
    """

    def __init__(self, imu_type: str | None = None, system: int | None = None) -> None:
        self.imu_type = imu_type
        self.system = system
        self.attitude_system: int | None = None
        self.clock = VehicleClock()
        self._secondary_since: dict[str, float] = {}
        self._leading: MAVLinkMessage | None = None  # an AHRS2 waiting for its slot's time
        #: whether the vehicle's last EKF_STATUS_REPORT said its attitude can be trusted; None:
        #: no report yet in this boot
        self.ekf_ready: bool | None = None

    def feed(self, msg: MAVLinkMessage | ImuPacket) -> list[ImuSample | GpsSample | AttitudeSample]:
        """The samples msg completes, in order: usually none or one; an AHRS2 held for its slot's
        time comes out just before the sample of the timestamped message that follows it."""
        kind = msg.get_type()
        if kind == "BAD_DATA" or kind.startswith("UNKNOWN"):
            return []
        system = msg.get_srcSystem()
        if self.system is None:
            if kind == "ATTITUDE" and self.attitude_system in (None, system):
                # no IMU yet: a device that only ever sends its attitude (seed 000's firmware
                # on an ascii: link) is still followed, for that reference alone
                self.attitude_system = system
                now = self.clock.observe(msg)
                sample = None if now is None else attitude_from_message(msg, now)
                return [] if sample is None else [sample]
            if kind not in IMU_TYPES:
                return []
            self.system = system
        if system != self.system:
            return []
        out: list[ImuSample | GpsSample | AttitudeSample] = []
        own_time = self.clock.time_of(msg)
        if self._leading is not None and (own_time is not None or kind in LEADING_MESSAGES):
            # the slot's first timestamped message gives its time; a second AHRS2 before any
            # timestamped message (no ATTITUDE streamed) leaves the first with the previous time
            held, self._leading = self._leading, None
            held_t = own_time if own_time is not None else self.clock.latest.get(system)
            if held_t is not None:
                sample = attitude_from_message(held, held_t)
                if sample is not None:
                    out.append(sample)
        if own_time is not None:  # self.clock.observe(msg) without reading the time twice
            self.clock.latest[system] = own_time
        now = self.clock.latest.get(system)
        if kind in LEADING_MESSAGES:
            self._leading = msg
            return out
        if kind == "EKF_STATUS_REPORT" and not isinstance(msg, ImuPacket):
            self.ekf_ready = ekf_ready(int(msg.flags))
            return out
        if now is None:
            return out
        current = self._sample(msg, kind, now)
        if current is not None:
            out.append(current)
        return out

    def imu_row(self, packet: ImuPacket, rows: list[EstimationInput | ImuRow]) -> bool:
        """`feed(packet)` of an IMU packet of the followed vehicle once its IMU stream is chosen
        (the live stream nearly always), appended to `rows`: an AHRS2 waiting for its slot's time
        comes out at the packet's, the vehicle clock moves to it and, if it is the IMU stream, its
        row follows (not an ImuSample). False, with nothing changed, where `feed` has more to do."""
        system = packet.sysid
        if system != self.system or self.imu_type is None:
            return False
        t = packet.t
        if self._leading is not None:
            held, self._leading = self._leading, None
            sample = attitude_from_message(held, t)
            if sample is not None:
                rows.append(sample)
        self.clock.latest[system] = t
        if packet.type == self.imu_type:
            rows.append(_ROWS[packet.type](t, packet.axes))
        return True

    def _sample(
        self, msg: MAVLinkMessage | ImuPacket, kind: str, now: float
    ) -> ImuSample | GpsSample | AttitudeSample | None:
        if kind in IMU_TYPES:
            if not self._is_imu_stream(kind, now):
                return None
            return imu_from_packet(msg) if isinstance(msg, ImuPacket) else _IMU_CONVERTERS[kind](msg)
        if kind == "GPS_RAW_INT":
            gps = gps_from_gps_raw_int(msg)
            if abs(gps.t - now) > GPS_CLOCK_TOLERANCE:
                gps = dataclasses.replace(gps, t=now)
            return gps
        sample = attitude_from_message(msg, now)
        if sample is not None and kind == "ATTITUDE" and not self._attitude_trusted(now):
            return dataclasses.replace(sample, source=UNREADY)
        return sample

    def _attitude_trusted(self, now: float) -> bool:
        """Whether ATTITUDE at vehicle time `now` is the reference "onboard" (the class's rule)."""
        return self.ekf_ready if self.ekf_ready is not None else now >= BOOT_SETTLE_S

    def _is_imu_stream(self, kind: str, now: float) -> bool:
        if self.imu_type is None:
            if kind in _PRIMARY_IMU:
                self.imu_type = kind
            else:
                since = self._secondary_since.setdefault(kind, now)
                if now - since >= SECONDARY_IMU_WAIT:
                    self.imu_type = kind
        return kind == self.imu_type


def ekf_ready(flags: int) -> bool:
    """Whether an EKF_STATUS_REPORT's flags say the vehicle's attitude can be trusted."""
    return bool(flags & EKF_READY) and not flags & EKF_NEVER_HEALTHY


#: Every message type that can become an estimation input (a recording's input positions count them).
INPUT_TYPES = frozenset({*IMU_TYPES, "GPS_RAW_INT", "ATTITUDE", "AHRS2", "SIMSTATE", "PARAM_VALUE"})
#: What the sampler reads: the inputs, and EKF_STATUS_REPORT, which names ATTITUDE's reference. It
#: is no input (not counted in the input positions, so older recordings' gain changes keep theirs).
SAMPLED_TYPES = INPUT_TYPES | {"EKF_STATUS_REPORT"}


#: A GPS_RAW_INT time_usec above this (2015-01-01 in µs) is UNIX time, not time since boot.
UNIX_USEC_MIN = 1_420_070_400_000_000


class MessageInputs:
    """One vehicle's messages → estimation inputs: its samples (`MessageSampler`) and a
    `GainChange` of every estimator's declination when it becomes known or changes.

    The declination follows `VehicleDeclination`'s rule: COMPASS_DEC / EKF2_MAG_DECL from any
    PARAM_VALUE, else the World Magnetic Model at the first 3D GPS fix (GPS_RAW_INT), dated by
    `wall_time` (the tlog record time, so a live run and a replay of its recording agree), else
    by GPS time when it is UNIX time, else the model's epoch. `gps_fix` turns True at the first
    3D fix (the station then asks for the parameters again: ArduPilot sets COMPASS_DEC only after
    GPS lock) and False again at a reboot.
    """

    def __init__(self, imu_type: str | None = None, system: int | None = None) -> None:
        self.sampler = MessageSampler(imu_type, system)
        self.vehicle_declination = VehicleDeclination()

    @property
    def declination(self) -> float | None:
        return self.vehicle_declination.value

    @property
    def declination_source(self) -> str:
        return self.vehicle_declination.source

    @property
    def gps_fix(self) -> bool:
        return self.vehicle_declination.gps_fix

    def feed(self, msg: MAVLinkMessage | ImuPacket, wall_time: float | None = None) -> list[EstimationInput]:
        """The inputs msg gives, in order; `wall_time`: its host UNIX time as the tlog stores it (s).
        An IMU message may come as its `ImuPacket` (read from its bytes by the link): the same inputs."""
        kind = msg.get_type()
        if kind == "PARAM_VALUE":
            return self._parameter(msg)
        clock = self.sampler.clock.latest
        before = clock.get(self.sampler.system) if self.sampler.system is not None else None
        out: list[EstimationInput] = list(self.sampler.feed(msg))
        after = clock.get(self.sampler.system) if self.sampler.system is not None else None
        if before is not None and after is not None and after < before - REBOOT_CLOCK_JUMP:
            self.vehicle_declination.reboot()
            self.sampler.ekf_ready = None  # not known again until the new boot's first EKF_STATUS_REPORT
        if kind == "GPS_RAW_INT" and msg.get_srcSystem() == self.sampler.system:
            change = self._wmm_declination(msg, wall_time)
            if change is not None:
                out.append(change)
        return out

    def feed_imu(self, packet: ImuPacket, inputs: list[EstimationInput | ImuRow]) -> bool:
        """`feed(packet)` the short way (`MessageSampler.imu_row`): its input, if any, appended to
        `inputs` as its ImuBatch row; False, with nothing changed, where `feed` must take it (the
        vehicle clock going back by more than REBOOT_CLOCK_JUMP, among others)."""
        before = self.sampler.clock.latest.get(packet.sysid)
        if before is not None and packet.t < before - REBOOT_CLOCK_JUMP:
            return False
        return self.sampler.imu_row(packet, inputs)

    def _parameter(self, msg: MAVLinkMessage) -> list[EstimationInput]:
        if self.sampler.system is not None and msg.get_srcSystem() != self.sampler.system:
            return []
        change = self.vehicle_declination.parameter(param_name(msg), float(msg.param_value))
        return [] if change is None else [change]

    def _wmm_declination(self, msg: MAVLinkMessage, wall_time: float | None) -> GainChange | None:
        if self.vehicle_declination.gps_fix:
            return None
        if wall_time is not None:
            year = decimal_year(wall_time)
        elif msg.time_usec > UNIX_USEC_MIN:
            year = decimal_year(usec_to_s(msg.time_usec))
        else:
            year = WMM_EPOCH
        lat, lon = degE7_to_deg(msg.lat), degE7_to_deg(msg.lon)
        return self.vehicle_declination.fix(int(msg.fix_type), lat, lon, mm_to_m(msg.alt), year)
