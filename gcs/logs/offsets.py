"""The growing index of message offsets the compiled log walkers (ULog, DataFlash) build."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.jit import kernel


@kernel
def appended(offsets: npt.NDArray[np.int64], n: int, offset: int) -> npt.NDArray[np.int64]:
    """`offsets` with `offset` at n, doubled first when full: an index sized for the shortest
    possible message would take several times the file's size, so it starts small and grows."""
    if n == len(offsets):
        grown = np.empty(2 * n, dtype=np.int64)
        grown[:n] = offsets
        offsets = grown
    offsets[n] = offset
    return offsets
