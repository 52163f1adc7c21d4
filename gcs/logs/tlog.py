"""MAVLink telemetry logs (.tlog from Mission Planner, QGroundControl, MAVProxy or gcs) → the
sample stream, decoded by the same framing and `MessageSampler` as the live link."""

from __future__ import annotations

from collections.abc import Iterator

from gcs.core.estimation import EstimationInput
from gcs.logs.logfile import InputError
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.sampling import IMU_TYPES, INPUT_TYPES, MessageInputs
from gcs.mavlink.tlog import read_tlog_records


def _imu_stream(path: str) -> tuple[str, int]:
    """The IMU message type to use (RAW_IMU first) and the system that sends it."""
    decoder = MavlinkDecoder()
    seen: dict[str, int] = {}
    for _, packet in read_tlog_records(path):
        for msg in decoder.feed(packet, final=True):
            if msg.get_type() in IMU_TYPES:
                seen.setdefault(msg.get_type(), msg.get_srcSystem())
        if "RAW_IMU" in seen:
            break
    for kind in IMU_TYPES:
        if kind in seen:
            return kind, seen[kind]
    raise InputError(f"{path}: offset 0: no IMU message ({', '.join(IMU_TYPES)}) found; is this a .tlog?")


def read_tlog(path: str, inputs: MessageInputs | None = None) -> Iterator[EstimationInput]:
    """Inputs of one vehicle in arrival order, made as the live pipeline makes them: IMU from
    RAW_IMU (or the first IMU type present), GPS from GPS_RAW_INT, references from ATTITUDE,
    AHRS2 and SIMSTATE, and a declination `GainChange` from the COMPASS_DEC / EKF2_MAG_DECL the
    log holds (else the World Magnetic Model's at the first 3D fix; `inputs.declination_source`
    says which). Packets the ground station sent (link bits 3 in the timestamp) are skipped."""
    imu_type, system = _imu_stream(path)
    if inputs is None:
        inputs = MessageInputs(imu_type, system)
    decoder = MavlinkDecoder()
    for usec, packet in read_tlog_records(path):
        if usec & 3 == 3:
            continue
        for msg in decoder.feed(packet, final=True):
            if msg.get_type() in INPUT_TYPES:  # what the live estimation subscribes to, no more
                yield from inputs.feed(msg, (usec & ~3) / 1e6)
