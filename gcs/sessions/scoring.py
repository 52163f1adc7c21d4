"""A whole run's errors as the pipeline scores them: one estimator's outputs over a source (one
compiled loop, gcs.core.estimators.whole) and the source's references, handed to the pipeline's
own comparison (`CompiledComparison`) in the order they arrived, in one kernel call per CHUNK
IMU samples.

What-if, `gcs sweep` and `gcs replay --fast` score this way, so their figures are those of the
per-sample pipeline (`gcs replay`, `gcs batch`, the live station) whatever the vehicle clock does:
the comparison starts afresh where it goes back (a reboot, or the ArduPlane VTOL tlog's IMU
stepping back 1 s), and a reference is scored against the outputs of the boot it came in. A
search over one run of outputs taken for time-ordered (`errors_at`) paired references with
outputs from the other side of the step. Only the session figures are read: no lag is tried
(lag_max 0), and the errors do not depend on it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gcs.core.comparison import ErrorSummary
from gcs.core.comparison_compiled import CompiledComparison, ReferenceRuns, source_lane
from gcs.core.estimators.stepping import OUT, STEPPED, Q
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.plausibility import attitude_rows_accepted
from gcs.logs.input_table import InputTable

#: IMU samples per kernel call: the comparison's buffers grow to hold a call's outputs.
CHUNK = 1 << 16


def scored(table: InputTable, q: npt.NDArray[np.float64], fed: npt.NDArray[np.bool_]) -> dict[str, ErrorSummary]:
    """Per reference source, the session RMS / max |error| (deg) and n of the estimator whose
    output after each IMU row of `table` is q (N×4), given where `fed` (the rows the pipeline
    steps: not refused); references the pipeline refuses are left out, as it leaves them out."""
    kind = table.kind
    imu_rows = np.cumsum((kind == Kind.IMU) | (kind == Kind.IMU_MAG))  # IMU rows up to each input
    accepted = attitude_rows_accepted(table.attitude)
    ends = imu_rows[kind == Kind.ATTITUDE][accepted]  # the IMU rows that arrived before each reference
    lanes = np.zeros(len(table.names))  # the comparison's lane of each reference's name (only theirs interned)
    for code in np.unique(table.attitude_source).tolist():
        lanes[code] = source_lane(table.names[code])
    refs = np.column_stack([table.attitude, lanes[table.attitude_source]])[accepted]
    outputs = np.zeros((len(q), OUT))
    outputs[:, Q : Q + 4] = q
    outputs[:, STEPPED] = fed
    comparison = CompiledComparison(lag_max=0.0)
    first = 0
    for lo in range(0, len(q), CHUNK):
        hi = min(lo + CHUNK, len(q))
        last = int(np.searchsorted(ends, hi, side="right")) if hi < len(q) else len(ends)
        runs = ReferenceRuns([], np.ascontiguousarray(refs[first:last]), ends[first:last] - lo)
        comparison.add_batch(runs, table.imu[lo:hi], outputs[lo:hi])
        first = last
    return {ref: stats["session"] for ref, stats in comparison.summary()["references"].items()}
