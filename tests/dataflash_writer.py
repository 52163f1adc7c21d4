"""Turns the real SITL hop log into the same flight in the two generations of the DataFlash
format, because no ArduCopter 3.2 (TimeMS) log is in the shared data. The writer and the record
layouts are the simulator's (gcs.sim.dataflash), one owner of the format."""

from __future__ import annotations

from pymavlink.DFReader import DFReader_binary

from gcs.sim.dataflash import NEW_FORMATS, OLD_FORMATS, DataflashWriter, e7, x100, yaw_cdeg


def _old_record(name: str, ms: int, r) -> tuple[str, tuple[object, ...]] | None:
    """One hop record as ArduCopter 3.2 logged it (TimeMS, the instance in the type name)."""
    instance = getattr(r, "I", 0)
    if name == "IMU" and instance < 2:
        return ("IMU", "IMU2")[instance], (ms, r.GyrX, r.GyrY, r.GyrZ, r.AccX, r.AccY, r.AccZ)
    if name == "MAG" and instance < 2:
        return ("MAG", "MAG2")[instance], (ms, r.MagX, r.MagY, r.MagZ, r.OfsX, r.OfsY, r.OfsZ, 0, 0, 0)
    if name == "GPS":  # TimeMS: the receiver's GPS time of week; T: the boot time
        gps = (r.Status, r.GMS, r.GWk, r.NSats, x100(r.HDop), e7(r.Lat), e7(r.Lng), 0, x100(r.Alt))
        return "GPS", (*gps, x100(r.Spd), x100(r.GCrs), r.VZ, ms)
    if name == "ATT":
        angles = (x100(r.DesRoll), x100(r.Roll), x100(r.DesPitch), x100(r.Pitch), yaw_cdeg(r.DesYaw))
        return "ATT", (ms, *angles, yaw_cdeg(r.Yaw))
    if name == "AHR2":
        return "AHR2", (ms, x100(r.Roll), x100(r.Pitch), yaw_cdeg(r.Yaw), r.Alt, e7(r.Lat), e7(r.Lng))
    return None


def _new_record(name: str, ms: int, r) -> tuple[str, tuple[object, ...]] | None:
    """The same record in today's layout, with the same quantised values and time (ms · 1000)."""
    old = _old_record(name, ms, r)
    if old is None:
        return None
    kind, v = old
    us, instance = ms * 1000, getattr(r, "I", 0)
    if name == "IMU":
        return "IMU", (us, instance, *v[1:])
    if name == "MAG":
        return "MAG", (us, instance, *v[1:4])
    if name == "GPS":
        status, week_ms, week, nsats, hdop, lat, lng, _, alt, spd, gcrs, vz, _ = v
        return "GPS", (us, 0, status, week_ms, week, nsats, hdop, lat, lng, alt, spd / 100, gcrs / 100, vz, 0.0)
    if name == "ATT":
        return "ATT", (us, *(a / 100 for a in v[1:]))
    return kind, (us, *v[1:])


def hop_in_both_formats(path: str) -> tuple[DataflashWriter, DataflashWriter]:
    """The hop flight as an ArduCopter 3.2 log (TimeMS) and as a current one (TimeUS), the same
    instants (ms) and the same quantised values, so the estimates must be the same."""
    old, new = DataflashWriter(), DataflashWriter()
    for name, (fmt, columns) in OLD_FORMATS.items():
        old.define(name, fmt, columns)
    for name, (fmt, columns) in NEW_FORMATS.items():
        new.define(name, fmt, columns)
    log = DFReader_binary(path)
    while (r := log.recv_match(type=["IMU", "MAG", "GPS", "ATT", "AHR2"])) is not None:
        name, ms = r.get_type(), round(r.TimeUS / 1000)
        for writer, convert in ((old, _old_record), (new, _new_record)):
            record = convert(name, ms, r)
            if record is not None:
                writer.add(record[0], *record[1])
    return old, new
