"""MAVLink telemetry logs (.tlog from Mission Planner, QGroundControl, MAVProxy or gcs) → the
sample stream, decoded by the same framing and `MessageSampler` as the live link."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from gcs.core.estimation import EstimationInput
from gcs.logs.logfile import InputError
from gcs.mavlink.decoding import decode
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.sampling import IMU_TYPES, SAMPLED_TYPES, MessageInputs
from gcs.mavlink.tlog import TlogRecords, read_tlog_records

#: IMU instance → message type (ArduPilot sends its first IMU as RAW_IMU, the others scaled).
IMU_INSTANCES = ("", "SCALED_IMU2", "SCALED_IMU3")


def _imu_stream(path: str, imu: int) -> tuple[str, int]:
    """The IMU message type to use (instance 0: RAW_IMU, else the first IMU type present; then
    SCALED_IMU2, SCALED_IMU3) and the system that sends it."""
    if not 0 <= imu < len(IMU_INSTANCES):
        last = len(IMU_INSTANCES) - 1
        raise InputError(f"{path}: offset 0: IMU instance {imu}: a .tlog carries instances 0 to {last}")
    wanted = IMU_INSTANCES[imu] or "RAW_IMU"
    decoder = MavlinkDecoder()
    seen: dict[str, int] = {}
    for _, packet in read_tlog_records(path):
        for _, kind, sysid, _ in decoder.frames(packet, final=True):
            if kind in IMU_TYPES:
                seen.setdefault(kind, sysid)
        if wanted in seen:
            break
    for kind in IMU_TYPES if imu == 0 else (wanted,):
        if kind in seen:
            return kind, seen[kind]
    raise no_imu(path, IMU_TYPES if imu == 0 else (wanted,))


def no_imu(path: str, types: Sequence[str]) -> InputError:
    """Why a .tlog (or a session's) gives no estimate: every command that estimates from one
    refuses it with this line (`gcs replay` ran on, printed an empty table and exited 0)."""
    return InputError(f"{path}: offset 0: no IMU message ({', '.join(types)}) in the log: nothing to estimate from")


def read_tlog(
    path: str, imu: int = 0, inputs: MessageInputs | None = None, records: TlogRecords | None = None
) -> Iterator[EstimationInput]:
    """Inputs of one vehicle in arrival order, made as the live pipeline makes them: IMU instance
    `imu` (see `_imu_stream`), GPS from GPS_RAW_INT, references from ATTITUDE, AHRS2 and
    SIMSTATE, and a declination `GainChange` from the COMPASS_DEC / EKF2_MAG_DECL the log holds
    (else the World Magnetic Model's at the first 3D fix; `inputs.declination_source` says
    which). Packets the ground station sent (link bits 3 in the timestamp) are skipped. Pass
    `records` (read_tlog_records(path)) to learn afterwards where the file was damaged, and
    `inputs` to read the declination it found; for instance 0 they pick the IMU as live does,
    for any other they are set to that instance's stream (they took the first IMU, whatever
    `imu` asked: `gcs estimate --imu 1` gave instance 0's attitude)."""
    imu_type, system = _imu_stream(path, imu)
    if inputs is None:
        inputs = MessageInputs(imu_type, system)
    elif imu:
        inputs.sampler.imu_type, inputs.sampler.system = imu_type, system
    decoder = MavlinkDecoder()
    for usec, packet in records if records is not None else read_tlog_records(path):
        if usec & 3 == 3:
            continue
        for raw, kind, _, _ in decoder.frames(packet, final=True):
            if kind in SAMPLED_TYPES:  # what the live estimation subscribes to, no more
                yield from inputs.feed(decode(raw), (usec & ~3) / 1e6)
