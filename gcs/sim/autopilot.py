"""The simulated autopilot's insides: sensors sampled from the truth, its own attitude filters
run at the loop rate, the latest GPS fix, and the MAVLink messages it builds from them.

Units on the wire follow what each firmware really sends (docs/vehicles.md):
ArduPilot RAW_IMU / SCALED_IMU2 carry mG, mrad/s and mgauss as integers; PX4 HIGHRES_IMU carries
m/s², rad/s, gauss and hPa; SIMSTATE carries the truth as ArduPilot SITL sends it.
"""

from __future__ import annotations

import math

import numpy as np

from gcs.core.rotation import vec3
from gcs.mavlink.dialect import mavlink
from gcs.sim.ahrs import OnboardAhrs
from gcs.sim.motion import GRAVITY, Script, Truth
from gcs.sim.params import ParamTable
from gcs.sim.profiles import Profile
from gcs.sim.sensors import BaroModel, GpsFix, GpsModel, Home, ImuModel, ImuReading, SensorFaults

GPS_RATE_HZ = 5.0
#: ArduPilot DCM's fixed gyro-drift integral gain (AP_AHRS_DCM `_ki`), 1/s².
DCM_KI = 0.0087
#: ATT_W_GYRO_BIAS → the filter's bias gain: PX4 applies it to the already-weighted correction.
PX4_BIAS_GAIN_SCALE = 0.1
#: SYS_STATUS sensor bits the simulated board has (gyro, accel, mag, baro, GPS, AHRS).
SENSORS_PRESENT = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_AHRS
)


def _int16(value: float) -> int:
    return max(-32768, min(32767, int(round(value))))


def milli_g(accel: float) -> int:
    """m/s² → mG as ArduPilot's send_raw_imu does (accel · 1000 / GRAVITY_MSS)."""
    return _int16(accel * 1000.0 / GRAVITY)


def _centidegrees(angle: float) -> int:
    """rad → 0..35999 cdeg (heading / course fields)."""
    return int(round(math.degrees(angle) * 100.0)) % 36000


def _deg_e7(degrees: float) -> int:
    return int(round(degrees * 1e7))


class Autopilot:
    """Sensors, filters and message builders for one profile and one truth script.

    `tick(t)` runs the autopilot loop (sample IMU 0, update the filters); `gps_tick(t)` takes a
    fix; `build(name, t)` returns the pymavlink message `name` for vehicle time t (s).
    """

    def __init__(
        self,
        profile: Profile,
        script: Script,
        faults: SensorFaults,
        params: ParamTable,
        seed: np.random.SeedSequence,
        home: Home,
    ) -> None:
        self.profile, self.script, self.faults, self.params, self.home = profile, script, faults, params, home
        streams = seed.spawn(2 + profile.imu_count)
        self.imus = [ImuModel(faults, np.random.default_rng(s)) for s in streams[2:]]
        self.gps = GpsModel(faults, home, np.random.default_rng(streams[0]))
        self.baro = BaroModel(faults, home, np.random.default_rng(streams[1]))
        self.fix: GpsFix | None = None
        self.gps_accel = (0.0, 0.0, 0.0)  # m/s² NED, from the last two fixes
        self.primary, self.secondary = self._make_filters()
        self.armed = False
        self._truth: Truth | None = None
        self.imu_reading: ImuReading | None = None  # IMU 0 at the last loop (the onboard log's IMU)

    def _make_filters(self) -> tuple[OnboardAhrs, OnboardAhrs | None]:
        """The filter behind ATTITUDE and, on Pixhawk ArduPilot, the one behind AHRS2.

        ArduPilot DCM takes AHRS_RP_P / AHRS_YAW_P; PX4's attitude_estimator_q is the same
        complementary filter with ATT_W_ACC / ATT_W_MAG / ATT_W_GYRO_BIAS. The Pixhawk's EKF3 is
        stood in for by a stiffer filter of the same kind, so ATTITUDE and AHRS2 differ slightly.
        """
        dec = self.faults.declination
        assert dec is not None, "SimVehicle resolves the declination from its home"
        p = self.params
        if self.profile.name == "px4":
            return OnboardAhrs(p["ATT_W_ACC"], p["ATT_W_MAG"], p["ATT_W_GYRO_BIAS"] * PX4_BIAS_GAIN_SCALE, dec), None
        dcm = OnboardAhrs(p["AHRS_RP_P"], p["AHRS_YAW_P"], DCM_KI, dec)
        if self.profile.imu_count > 1:
            return OnboardAhrs(0.5, 0.5, 0.02, dec), dcm
        return dcm, None

    def apply_param(self, name: str, value: float) -> None:
        """Make a changed parameter take effect in the filters that read it."""
        dcm = self.secondary or self.primary
        if self.profile.name == "px4":
            if name == "ATT_W_ACC":
                self.primary.kp = value
            elif name == "ATT_W_MAG":
                self.primary.kp_yaw = value
            elif name == "ATT_W_GYRO_BIAS":
                self.primary.ki = value * PX4_BIAS_GAIN_SCALE
        elif name == "AHRS_RP_P":
            dcm.kp = value
        elif name == "AHRS_YAW_P":
            dcm.kp_yaw = value
        elif name in ("COMPASS_DEC", "EKF2_MAG_DECL"):
            declination = value if name == "COMPASS_DEC" else math.radians(value)
            for f in (self.primary, self.secondary):
                if f is not None:
                    f.declination = declination

    # --- internal clock ----------------------------------------------------------------------------

    def truth(self, t: float) -> Truth:
        """Truth at t, computed once per distinct time."""
        if self._truth is None or self._truth.t != t:
            self._truth = self.script.truth(t)
        return self._truth

    def tick(self, t: float) -> None:
        """One autopilot loop: sample IMU 0 and run the attitude filters on it."""
        r = self.imu_reading = self.imus[0].sample(self.truth(t))
        self.primary.update(t, r.gyro, r.accel, r.mag, self.gps_accel)
        if self.secondary is not None:
            self.secondary.update(t, r.gyro, r.accel, r.mag, self.gps_accel)

    def gps_tick(self, t: float) -> None:
        """Take a receiver fix; its velocity change since the last one is the filters' a_ned."""
        fix = self.gps.fix(self.truth(t))
        if self.fix is not None and fix.t > self.fix.t:
            dt = fix.t - self.fix.t
            self.gps_accel = vec3((fix.vel_ned[i] - self.fix.vel_ned[i]) / dt for i in range(3))
        self.fix = fix

    # --- messages ----------------------------------------------------------------------------------

    def build(self, name: str, t: float):
        return getattr(self, "_" + name.lower())(t)

    def _heartbeat(self, t: float):
        base = (
            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        )
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, self.profile.autopilot, base, self.profile.custom_mode, state, 3
        )

    def _raw_imu(self, t: float):
        r = self.imus[0].sample(self.truth(t))
        return mavlink.MAVLink_raw_imu_message(int(round(t * 1e6)), *self._scaled(r))

    def _scaled_imu2(self, t: float):
        r = self.imus[1].sample(self.truth(t))
        return mavlink.MAVLink_scaled_imu2_message(int(round(t * 1e3)), *self._scaled(r))

    @staticmethod
    def _scaled(r: ImuReading) -> list[int]:
        """ArduPilot's integer units: mG, mrad/s, mgauss, in FRD order x, y, z."""
        return (
            [milli_g(a) for a in r.accel] + [_int16(g * 1000.0) for g in r.gyro] + [_int16(m * 1000.0) for m in r.mag]
        )

    def _highres_imu(self, t: float):
        truth = self.truth(t)
        r = self.imus[0].sample(truth)
        pressure = self.baro.pressure(truth)
        altitude = self.home.alt - float(truth.pos[2])
        return mavlink.MAVLink_highres_imu_message(
            int(round(t * 1e6)),
            *r.accel,
            *r.gyro,
            *r.mag,
            pressure / 100.0,
            0.0,
            altitude,
            self.baro.temperature(truth),
            0x1FFF,
        )  # fields_updated: all 13 fields are new

    def _scaled_pressure(self, t: float):
        truth = self.truth(t)
        return mavlink.MAVLink_scaled_pressure_message(
            int(round(t * 1e3)), self.baro.pressure(truth) / 100.0, 0.0, int(round(self.baro.temperature(truth) * 100))
        )

    def _sensor_offsets(self, t: float):
        truth = self.truth(t)
        p = self.params
        return mavlink.MAVLink_sensor_offsets_message(
            *(_int16(p[f"COMPASS_OFS_{axis}"]) for axis in "XYZ"),
            p["COMPASS_DEC"],
            int(round(self.baro.pressure(truth))),
            int(round(self.baro.temperature(truth) * 100)),
            *(p[f"INS_GYROFFS_{axis}"] for axis in "XYZ"),
            *(p[f"INS_ACCOFFS_{axis}"] for axis in "XYZ"),
        )

    def _sys_status(self, t: float):
        current = 1500 if self.armed else 60  # cA
        return mavlink.MAVLink_sys_status_message(
            SENSORS_PRESENT, SENSORS_PRESENT, SENSORS_PRESENT, 250, 12400, current, 80, 0, 0, 0, 0, 0, 0
        )

    def _gps_raw_int(self, t: float):
        fix = self.fix or self.gps.fix(self.truth(t))
        # HDOP 0.9 / VDOP 1.4 and 12 satellites: a good open-sky u-blox fix; accuracies from the noise.
        return mavlink.MAVLink_gps_raw_int_message(
            int(round(fix.t * 1e6)),
            mavlink.GPS_FIX_TYPE_3D_FIX,
            _deg_e7(fix.lat),
            _deg_e7(fix.lon),
            int(round(fix.alt * 1000)),
            90,
            140,
            int(round(fix.ground_speed * 100)),
            _centidegrees(fix.course),
            12,
            int(round(fix.alt * 1000)),
            max(1, int(self.faults.gps_pos_noise * 1000)),
            max(1, int(self.faults.gps_pos_noise * 1500)),
            max(1, int(self.faults.gps_vel_noise * 1000)),
            0,
        )

    def _global_position_int(self, t: float):
        fix = self.fix or self.gps.fix(self.truth(t))
        vn, ve, vd = fix.vel_ned
        return mavlink.MAVLink_global_position_int_message(
            int(round(t * 1e3)),
            _deg_e7(fix.lat),
            _deg_e7(fix.lon),
            int(round(fix.alt * 1000)),
            int(round((fix.alt - self.home.alt) * 1000)),
            int(round(vn * 100)),
            int(round(ve * 100)),
            int(round(vd * 100)),
            _centidegrees(self.primary.euler()[2]),
        )

    def _attitude(self, t: float):
        return mavlink.MAVLink_attitude_message(int(round(t * 1e3)), *self.primary.euler(), *self.primary.rate)

    def _attitude_quaternion(self, t: float):
        return mavlink.MAVLink_attitude_quaternion_message(int(round(t * 1e3)), *self.primary.q, *self.primary.rate)

    def _ahrs(self, t: float):
        dcm = self.secondary or self.primary
        return mavlink.MAVLink_ahrs_message(*(-b for b in dcm.bias), 0.0, 0.0, dcm.error_rp, dcm.error_yaw)

    def _ahrs2(self, t: float):
        assert self.secondary is not None  # AHRS2 is only in the streams of profiles with two IMUs
        fix = self.fix or self.gps.fix(self.truth(t))
        return mavlink.MAVLink_ahrs2_message(*self.secondary.euler(), fix.alt, _deg_e7(fix.lat), _deg_e7(fix.lon))

    def _simstate(self, t: float):
        truth = self.truth(t)
        lat, lon = self.home.lat_lon(float(truth.pos[0]), float(truth.pos[1]))
        return mavlink.MAVLink_simstate_message(
            *truth.euler, *map(float, truth.specific_force), *map(float, truth.omega_body), _deg_e7(lat), _deg_e7(lon)
        )

    def _ekf_status_report(self, t: float):
        """ArduPilot's EKF_STATUS_REPORT: flags of a healthy EKF3 with a 3D fix, small variances
        (only the pixhawk profile has it, streamed when asked for as ArduCopter's SRx default 0 has it;
        the APM 2.5 and PX4 have none)."""
        flags = (
            mavlink.EKF_ATTITUDE
            | mavlink.EKF_VELOCITY_HORIZ
            | mavlink.EKF_VELOCITY_VERT
            | mavlink.EKF_POS_HORIZ_REL
            | mavlink.EKF_POS_HORIZ_ABS
            | mavlink.EKF_POS_VERT_ABS
            | mavlink.EKF_PRED_POS_HORIZ_REL
            | mavlink.EKF_PRED_POS_HORIZ_ABS
        )
        return mavlink.MAVLink_ekf_status_report_message(flags, 0.05, 0.08, 0.06, 0.03, 0.0)

    def _estimator_status(self, t: float):
        """PX4's ESTIMATOR_STATUS: EKF2's solution flags of a healthy filter using GPS, small test
        ratios and accuracies (only the px4 profile has it)."""
        flags = (
            mavlink.ESTIMATOR_ATTITUDE
            | mavlink.ESTIMATOR_VELOCITY_HORIZ
            | mavlink.ESTIMATOR_VELOCITY_VERT
            | mavlink.ESTIMATOR_POS_HORIZ_REL
            | mavlink.ESTIMATOR_POS_HORIZ_ABS
            | mavlink.ESTIMATOR_POS_VERT_ABS
            | mavlink.ESTIMATOR_PRED_POS_HORIZ_REL
            | mavlink.ESTIMATOR_PRED_POS_HORIZ_ABS
        )
        ratios, accuracies = (0.1, 0.1, 0.2, 0.1, 0.0, 0.0), (0.6, 0.9)  # vel, pos h/v, mag, hagl, tas; m
        return mavlink.MAVLink_estimator_status_message(int(round(t * 1e6)), flags, *ratios, *accuracies)

    @staticmethod
    def statustext(severity: int, text: str):
        """A STATUSTEXT as ArduPilot sends it (e.g. "Arming motors"): 50 bytes, NUL-padded."""
        return mavlink.MAVLink_statustext_message(severity, text.encode()[:50])

    def _autopilot_version(self, t: float):
        p = self.profile
        vendor, product, uid = 0x1209, 0x5741, 0x5349_4D00_0001  # pid.codes open-source ids; "SIM" uid
        return mavlink.MAVLink_autopilot_version_message(
            p.capabilities, p.flight_sw_version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, vendor, product, uid
        )
