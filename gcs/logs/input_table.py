"""Estimation inputs in columns: a whole flight's samples as a few NumPy arrays.

A flight-hour at 400 Hz is 1.4 million IMU samples; as Python objects (an `ImuSample` with three
arrays) that is about 650 bytes each, in columns 82. The table keeps every value bit for bit
(float64, and whether the optional magnetometer and GPS velocity were present), so the inputs it
hands back feed a pipeline to exactly the numbers the original objects give.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gcs.core.estimation import EstimationInput, GainChange
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample

Floats = npt.NDArray[np.float64]


#: Columns per row of each table.
IMU_COLUMNS = 10  # t, gyro xyz, accel xyz, mag xyz (NaN without a magnetometer)
GPS_COLUMNS = 10  # t, lat, lon, alt, ground_speed, course, vel_ned xyz (NaN without), fix_type
ATTITUDE_COLUMNS = 4  # t, roll, pitch, yaw
NAN3 = (float("nan"),) * 3


class _Names:
    """Interned strings (sample sources, estimator and gain names) → small integer codes."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self._codes: dict[str, int] = {}

    def code(self, name: str) -> int:
        code = self._codes.get(name)
        if code is None:
            code = self._codes[name] = len(self.names)
            self.names.append(name)
        return code


class InputTableBuilder:
    """Appends inputs one at a time into growable typed arrays (8 bytes per float, no objects)."""

    def __init__(self) -> None:
        self._kind = array("B")
        self._imu, self._gps, self._attitude, self._gain_value = array("d"), array("d"), array("d"), array("d")
        self._imu_source, self._gps_source, self._attitude_source = array("H"), array("H"), array("H")
        self._gain_estimator, self._gain_name = array("h"), array("H")
        self._names = _Names()

    def __len__(self) -> int:
        return len(self._kind)

    def append(self, item: EstimationInput) -> None:
        code = self._names.code
        if isinstance(item, ImuSample):
            self._kind.append(Kind.IMU if item.mag is None else Kind.IMU_MAG)
            self._imu.append(item.t)
            self._imu.extend(item.gyro.tolist())
            self._imu.extend(item.accel.tolist())
            self._imu.extend(NAN3 if item.mag is None else item.mag.tolist())
            self._imu_source.append(code(item.source))
        elif isinstance(item, GpsSample):
            self._kind.append(Kind.GPS if item.vel_ned is None else Kind.GPS_VEL)
            self._gps.extend((item.t, item.lat, item.lon, item.alt, item.ground_speed, item.course))
            self._gps.extend(NAN3 if item.vel_ned is None else item.vel_ned.tolist())
            self._gps.append(item.fix_type)
            self._gps_source.append(code(item.source))
        elif isinstance(item, AttitudeSample):
            self._kind.append(Kind.ATTITUDE)
            self._attitude.extend((item.t, item.roll, item.pitch, item.yaw))
            self._attitude_source.append(code(item.source))
        else:
            self._kind.append(Kind.GAIN)
            self._gain_estimator.append(-1 if item.estimator is None else code(item.estimator))
            self._gain_name.append(code(item.name))
            self._gain_value.append(item.value)

    def build(self) -> InputTable:
        def rows(values: array[float], columns: int) -> Floats:
            return np.frombuffer(values, dtype=np.float64).reshape(-1, columns)

        def codes(values: array[int], dtype: type[np.generic]) -> npt.NDArray[np.generic]:
            return np.frombuffer(values, dtype=dtype)

        return InputTable(
            kind=codes(self._kind, np.uint8),
            imu=rows(self._imu, IMU_COLUMNS),
            imu_source=codes(self._imu_source, np.uint16),
            gps=rows(self._gps, GPS_COLUMNS),
            gps_source=codes(self._gps_source, np.uint16),
            attitude=rows(self._attitude, ATTITUDE_COLUMNS),
            attitude_source=codes(self._attitude_source, np.uint16),
            gain_estimator=codes(self._gain_estimator, np.int16),
            gain_name=codes(self._gain_name, np.uint16),
            gain_value=np.frombuffer(self._gain_value, dtype=np.float64),
            names=tuple(self._names.names),
        )


def gain_columns(
    changes: list[GainChange], names: list[str]
) -> tuple[npt.NDArray[np.int16], npt.NDArray[np.uint16], Floats]:
    """An input table's gain columns (estimator code or -1, gain name code, value) for changes,
    their names interned into `names` (appended where new), for readers that build tables whole."""
    for change in changes:
        names.extend(n for n in (change.estimator, change.name) if n is not None and n not in names)
    estimator = np.array([-1 if c.estimator is None else names.index(c.estimator) for c in changes], dtype=np.int16)
    name = np.array([names.index(c.name) for c in changes], dtype=np.uint16)
    return estimator, name, np.array([c.value for c in changes], dtype=np.float64)


@dataclass(frozen=True, eq=False)
class InputTable:
    """Inputs in their original order: `kind[i]` says which table holds input i; each table's
    rows are in input order too, so the k-th IMU input is row k of `imu`."""

    kind: npt.NDArray[np.generic]
    imu: Floats
    imu_source: npt.NDArray[np.generic]
    gps: Floats
    gps_source: npt.NDArray[np.generic]
    attitude: Floats
    attitude_source: npt.NDArray[np.generic]
    gain_estimator: npt.NDArray[np.generic]
    gain_name: npt.NDArray[np.generic]
    gain_value: Floats
    names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.kind)

    @property
    def nbytes(self) -> int:
        arrays: list[npt.NDArray[np.generic]] = [self.kind, self.imu, self.imu_source, self.gps, self.gps_source]
        arrays += [self.attitude, self.attitude_source, self.gain_estimator, self.gain_name, self.gain_value]
        return sum(a.nbytes for a in arrays)

    @property
    def imu_count(self) -> int:
        return len(self.imu)

    def inputs(self, start: int = 0, stop: int | None = None) -> Iterator[EstimationInput]:
        """Inputs start..stop-1 as the objects they were built from."""
        stop = len(self) if stop is None else stop
        counts = np.bincount(self.kind[:start], minlength=len(Kind))
        imu_row = int(counts[Kind.IMU] + counts[Kind.IMU_MAG])
        gps_row = int(counts[Kind.GPS] + counts[Kind.GPS_VEL])
        att_row, gain_row = int(counts[Kind.ATTITUDE]), int(counts[Kind.GAIN])
        names = self.names
        for kind in self.kind[start:stop].tolist():
            if kind <= Kind.IMU_MAG:
                r = self.imu[imu_row]
                mag = r[7:10].copy() if kind == Kind.IMU_MAG else None
                yield ImuSample(float(r[0]), r[1:4].copy(), r[4:7].copy(), mag, names[self.imu_source[imu_row]])
                imu_row += 1
            elif kind <= Kind.GPS_VEL:
                g = self.gps[gps_row]
                vel = g[6:9].copy() if kind == Kind.GPS_VEL else None
                t, lat, lon, alt, speed, course = g[:6].tolist()
                yield GpsSample(t, lat, lon, alt, speed, course, vel, int(g[9]), names[self.gps_source[gps_row]])
                gps_row += 1
            elif kind == Kind.ATTITUDE:
                t, roll, pitch, yaw = self.attitude[att_row].tolist()
                yield AttitudeSample(t, roll, pitch, yaw, names[self.attitude_source[att_row]])
                att_row += 1
            else:
                yield self.gain_change(gain_row)
                gain_row += 1

    def gain_change(self, k: int) -> GainChange:
        """The k-th gain change input."""
        estimator = int(self.gain_estimator[k])
        return GainChange(
            None if estimator < 0 else self.names[estimator], self.names[self.gain_name[k]], float(self.gain_value[k])
        )

    def references(self) -> dict[str, Floats]:
        """Reference attitudes {source: N×4 array of t, roll, pitch, yaw}, in input order."""
        return {
            self.names[code]: self.attitude[self.attitude_source == code]
            for code in np.unique(self.attitude_source).tolist()
        }
