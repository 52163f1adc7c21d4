"""One small listener type: parts announce things (a state change, new points, an event) and
others connect and disconnect, instead of each part keeping its own list of callbacks."""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, ParamSpec

P = ParamSpec("P")


class Signal(Generic[P]):
    """Callbacks called in connection order, synchronously, on the caller's thread (the event
    loop for every station part). A callback that raises is not caught here: it is a bug in the
    listener, and the part that emitted fails under its supervisor where it can be seen."""

    def __init__(self) -> None:
        self._callbacks: list[Callable[P, object]] = []

    def connect(self, callback: Callable[P, object]) -> Callable[[], None]:
        """Call `callback` on every emit from now on; returns the function that disconnects it."""
        self._callbacks.append(callback)
        return lambda: self.disconnect(callback)

    def disconnect(self, callback: Callable[P, object]) -> None:
        if callback in self._callbacks:
            self._callbacks.remove(callback)

    def emit(self, *args: P.args, **kwargs: P.kwargs) -> None:
        for callback in list(self._callbacks):
            callback(*args, **kwargs)

    def __len__(self) -> int:
        return len(self._callbacks)
