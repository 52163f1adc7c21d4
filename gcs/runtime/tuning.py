"""Remote gain tuning of the vehicle, made safe: only the parameters of a tuning profile, inside
their bounds, by small steps, not too often, every write verified and logged, and one call that
puts back every value as it was before the flight.

A tuning profile (gcs/runtime/profiles/*.toml, or any file of that shape) declares each tunable
parameter once: the firmware's documented range, the largest change one write may make, one line of
meaning. The REST panel and `gcs params set --profile` both go through `TuningSession.set`, so they
refuse the same things with the same messages. The rate limits (`PER_PARAM_INTERVAL`,
`GLOBAL_PER_SECOND`) keep a dragged slider from flooding a 57600-baud radio; a revert is paced by
its own verified writes. See docs/vehicles.md.
"""

from __future__ import annotations

import math
import time
import tomllib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from gcs.mavlink.params import ParamError, format_value, same_value
from gcs.runtime.link import LinkState
from gcs.runtime.params import Param, ParamClient, ParamTimeout

#: The shipped profiles (package data).
_PROFILES = resources.files("gcs.runtime").joinpath("profiles")
#: Least time between two writes of the same parameter, s.
PER_PARAM_INTERVAL = 0.2
#: Most writes (all parameters together) in any one-second window.
GLOBAL_PER_SECOND = 5


class TuningRefused(ParamError):
    """A write the safety rules do not allow; the message names the rule and the numbers."""


class RateLimited(TuningRefused):
    """A write refused only because it came too soon; the same write may succeed later."""


class StaleValue(TuningRefused):
    """A write based on a value the parameter no longer has: another page, a script or the vehicle
    changed it since the writer last looked. Written anyway, a slider on a page that had not yet
    seen another page's write put the old value back (within the step limit)."""


class ProfileError(ValueError):
    """A tuning profile file that is not valid; the message names the file and the entry."""


@dataclass(frozen=True, slots=True)
class Tunable:
    name: str
    min: float
    max: float
    step: float
    meaning: str


@dataclass(frozen=True)
class TuningProfile:
    name: str
    title: str
    autopilot: str
    detect: str  # a parameter only this firmware has
    params: dict[str, Tunable]

    def spec(self, name: str) -> Tunable:
        """The declaration of name, or TuningRefused: only declared parameters are tunable."""
        spec = self.params.get(name)
        if spec is None:
            raise TuningRefused(f"{name} is not in the tuning profile {self.name} (tunable: {', '.join(self.params)})")
        return spec

    def check(self, name: str, value: float, current: float) -> Tunable:
        """The declaration of name, or TuningRefused saying why writing value (from current) is not allowed."""
        spec = self.spec(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise TuningRefused(f"{name}: {value!r} is not a finite number")
        if not spec.min <= value <= spec.max:
            raise TuningRefused(
                f"{name} = {format_value(value)} is outside the allowed range "
                f"[{format_value(spec.min)}, {format_value(spec.max)}]"
            )
        change = abs(value - current)  # shown to 6 digits: 0.04, not the float32 values' 0.040000001
        if change > spec.step and not same_value(change, spec.step):
            raise TuningRefused(
                f"{name}: {format_value(current)} -> {format_value(value)} changes it by "
                f"{format_value(float(f'{change:.6g}'))}, more than the largest step {format_value(spec.step)} "
                f"allowed per write"
            )
        return spec


def available_profiles() -> list[str]:
    """Names of the profiles shipped with gcs."""
    return sorted(p.name.removesuffix(".toml") for p in _PROFILES.iterdir() if p.name.endswith(".toml"))


def load_profile(name_or_path: str | Path) -> TuningProfile:
    """A shipped profile by name ("arducopter-4"), or a profile file by path."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ProfileError(f"cannot read tuning profile {path}: {exc.strerror}") from None
        return parse_profile(text, str(path))
    if str(name_or_path) not in available_profiles():
        raise ProfileError(f"unknown tuning profile {name_or_path!r}; shipped: {', '.join(available_profiles())}")
    resource = _PROFILES.joinpath(f"{name_or_path}.toml")
    return parse_profile(resource.read_text(encoding="utf-8"), f"{name_or_path}.toml")


def parse_profile(text: str, source: str) -> TuningProfile:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{source}: {exc}") from None
    for key in ("name", "autopilot", "detect"):
        if not isinstance(data.get(key), str):
            raise ProfileError(f"{source}: `{key}` must be a string")
    entries = data.get("params")
    if not isinstance(entries, dict) or not entries:
        raise ProfileError(f"{source}: no [params.NAME] tables")
    params = {}
    for name, entry in entries.items():
        where = f"{source}: params.{name}"
        try:
            lo, hi, step = (float(entry[k]) for k in ("min", "max", "step"))
            meaning = str(entry["meaning"])
        except KeyError as exc:
            raise ProfileError(f"{where}: missing {exc.args[0]}") from None
        except (TypeError, ValueError):
            raise ProfileError(f"{where}: min, max and step must be numbers") from None
        if not lo < hi:
            raise ProfileError(f"{where}: min {lo} is not below max {hi}")
        if not 0 < step <= hi - lo:
            raise ProfileError(f"{where}: step {step} must be > 0 and at most max - min")
        params[name] = Tunable(name, lo, hi, step, meaning)
    return TuningProfile(data["name"], data.get("title", data["name"]), data["autopilot"], data["detect"], params)


def detect_profile(names, autopilot: str | None = None) -> TuningProfile | None:
    """The shipped profile for a vehicle, from a parameter only its firmware has (with the
    autopilot family, when known, agreeing)."""
    for profile in map(load_profile, available_profiles()):
        if profile.detect in names and autopilot in (None, profile.autopilot):
            return profile
    return None


async def open_session(params: ParamClient, profile: TuningProfile | str | None = None) -> TuningSession:
    """A started session: the whole table downloaded first when it is not yet (the pre-flight
    record of everything), the profile detected from it when not given."""
    if not params.complete:
        await params.download()
    if profile is None:
        profile = detect_profile(params.table, params.vehicle.autopilot)
        if profile is None:
            raise ProfileError(
                f"no shipped tuning profile fits this vehicle ({params.vehicle.autopilot}); "
                f"shipped: {', '.join(available_profiles())}"
            )
    elif isinstance(profile, str):
        profile = load_profile(profile)
    session = TuningSession(params, profile)
    await session.start()
    return session


@dataclass
class RateLimiter:
    """At most one write per parameter every `per_param` s and `per_second` writes in any 1 s."""

    per_param: float = PER_PARAM_INTERVAL
    per_second: int = GLOBAL_PER_SECOND
    clock: Callable[[], float] = time.monotonic
    _last: dict[str, float] = field(default_factory=dict)
    _recent: deque = field(default_factory=deque)

    def take(self, name: str) -> None:
        """Count a write of name now, or RateLimited saying how long to wait."""
        now = self.clock()
        while self._recent and now - self._recent[0] >= 1.0:
            self._recent.popleft()
        last = self._last.get(name)
        if last is not None and now - last < self.per_param:
            raise RateLimited(
                f"{name} was written {now - last:.2f} s ago; wait "
                f"{self.per_param - (now - last):.2f} s (at least {self.per_param} s "
                f"between writes of one parameter)"
            )
        if len(self._recent) >= self.per_second:
            raise RateLimited(
                f"{self.per_second} writes in the last second already; wait "
                f"{1.0 - (now - self._recent[0]):.2f} s (at most {self.per_second} writes per s)"
            )
        self._last[name] = now
        self._recent.append(now)

    def snapshot(self) -> TuningLimits:
        return TuningLimits(self.per_param, self.per_second)


@dataclass(frozen=True, slots=True)
class TuningLimits:
    per_param_interval_s: float
    max_writes_per_s: int


@dataclass(frozen=True, slots=True)
class TunedParam:
    """One tunable as the tuning panel shows it."""

    name: str
    min: float
    max: float
    step: float
    meaning: str
    current: float | None  # the table's: after a write the vehicle did not echo, what it held before
    preflight: float | None
    changed: bool | None  # None while either value is unknown (the vehicle's, after a write it did not echo)


@dataclass(frozen=True, slots=True)
class TuningSnapshot:
    profile: str
    title: str
    started: float | None  # UNIX time the pre-flight values were taken
    limits: TuningLimits
    params: list[TunedParam]


class TuningSession:
    """Tuning of one vehicle during one flight: the pre-flight snapshot, the guarded writes, the revert.

    `start()` takes the snapshot (the profile's parameters read fresh from the vehicle, and the
    whole table when it has been downloaded); the first `set` calls it if nobody did.
    """

    def __init__(self, params: ParamClient, profile: TuningProfile, limiter: RateLimiter | None = None) -> None:
        self.params = params
        self.profile = profile
        self.limiter = limiter or RateLimiter()
        self.preflight: dict[str, int | float] = {}
        self.table_snapshot: dict[str, int | float] = {}
        self.started: float | None = None  # UNIX time of the snapshot
        self.written: set[str] = set()
        # name -> the table's entry when a write of it got no echo: the vehicle's value is unknown
        # (it may have taken the write) until another PARAM_VALUE of it replaces that entry
        self.unechoed: dict[str, Param | None] = {}

    async def start(self) -> None:
        if self.started is not None:
            return
        preflight = {}
        for name in self.profile.params:
            preflight[name] = (await self.params.read(name)).value
        self.preflight = preflight
        self.table_snapshot = self.params.values()
        self.started = time.time()

    async def set(self, name: str, value: float, client: str, expected: float | None = None) -> Param:
        """A verified write of one profile parameter, or TuningRefused / ParamError saying why not.
        `expected`: the value the writer saw and chose `value` from (a page's slider is centred on
        it); when the vehicle's value is another now, StaleValue and nothing is written."""
        self.profile.spec(name)  # refuse other parameters before touching the vehicle
        self._connected(f"{name}: not written")
        await self.start()
        known = self.params.table.get(name)
        if known is None or self._unechoed(name, known):
            # the vehicle's value, not the table's: after a write it took without echo, a step
            # from the table's older value moved the gain by up to twice the largest step
            known = await self.params.read(name)
        if expected is not None and not same_value(known.value, expected):
            raise StaleValue(
                f"{name}: not written: it is {format_value(known.value)} now, not the {format_value(expected)} "
                f"this write was based on (changed by another page, a script or the vehicle); look again and retry"
            )
        self.profile.check(name, value, known.value)
        self.limiter.take(name)
        self.written.add(name)  # even if the write fails: the vehicle may have taken it
        return await self._write(name, value, client)

    async def _write(self, name: str, value: float, client: str) -> Param:
        """A verified write, remembering one that got no echo (see `rows`)."""
        try:
            stored = await self.params.set(name, value, client)
        except ParamTimeout:
            self.unechoed[name] = self.params.table.get(name)
            raise
        self.unechoed.pop(name, None)
        return stored

    async def revert(self, client: str) -> list[Param]:
        """Write back the pre-flight value of every profile parameter that differs from it now (or
        that this session wrote), each verified. Raises ParamError listing those that failed,
        after trying them all: a ParamTimeout when the vehicle answered none of them (a timeout
        is no refusal: the REST answer was 422, "refused", for it). While the link is not
        connected, TuningRefused at once (and for each write left when it goes during the revert)."""
        if self.started is None:
            return []
        self._connected("not reverted, nothing written")
        restored: list[Param] = []
        failed: list[ParamError] = []
        for name, value in self.preflight.items():
            known = self.params.table.get(name)
            if name not in self.written and known is not None and same_value(known.value, value):
                continue
            try:
                self._connected(f"{name}: not written")  # a link lost during the revert
                restored.append(await self._write(name, value, client))
                self.written.discard(name)
            except ParamError as exc:
                failed.append(exc)
        if failed:
            kind = ParamTimeout if all(isinstance(exc, ParamTimeout) for exc in failed) else ParamError
            raise kind(f"revert incomplete ({len(restored)} restored): " + "; ".join(map(str, failed)))
        return restored

    def _connected(self, what: str) -> None:
        """TuningRefused saying `what` while the link is not connected. ParamClient waits up to 10 s
        for the link: a write then changed the gain whenever it came back, seconds after the click,
        the page saying "writing…" all along, and a revert waited 10 s per parameter to fail."""
        link = self.params.link
        if link.state != LinkState.CONNECTED:
            raise TuningRefused(f"{what}: the link to the vehicle is {link.state}; try again when it is back")

    def _unechoed(self, name: str, known: Param) -> bool:
        """Is the table's entry for name still the one it had when a write of it got no echo?"""
        return name in self.unechoed and self.unechoed[name] is known

    def rows(self) -> list[TunedParam]:
        """Each tunable with its limits, current and pre-flight value: what the panel shows. A
        parameter whose last write got no echo is `changed: None` until the vehicle sends its value
        again: it may hold the new value while the table still has the old one, and the panel
        showed it unchanged, with nothing to revert."""
        out = []
        for name, spec in self.profile.params.items():
            known = self.params.table.get(name)
            current = known.value if known is not None else None
            before = self.preflight.get(name)
            unechoed = known is not None and self._unechoed(name, known)
            changed = None if current is None or before is None or unechoed else not same_value(current, before)
            out.append(TunedParam(name, spec.min, spec.max, spec.step, spec.meaning, current, before, changed))
        return out

    def snapshot(self) -> TuningSnapshot:
        return TuningSnapshot(self.profile.name, self.profile.title, self.started, self.limiter.snapshot(), self.rows())
