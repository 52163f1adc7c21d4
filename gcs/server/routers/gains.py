"""Estimator gains over REST: list the declarations with current values and slider shapes,
change one gain, reset an estimator to a preset. Changes need the token when one is required;
the Station records each one in its event log."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, status

from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.gains import GainError
from gcs.server.deps import TOKEN, ClientDep, StationDep
from gcs.server.models import EstimatorGains, GainChange, GainInfo, GainUpdate, PresetRequest, PresetResult
from gcs.server.sliders import slider_spec

router = APIRouter(prefix="/api/estimators", tags=["gains"])


def describe(name: str, est: AttitudeEstimator) -> EstimatorGains:
    presets = est.gains.presets
    infos = []
    for g in est.gains.declarations.values():
        spec = slider_spec(g, presets)
        infos.append(
            GainInfo(
                name=g.name,
                value=est.gains[g.name],
                default=g.default,
                min=g.min,
                max=g.max,
                unit=g.unit,
                meaning=g.meaning,
                scale=spec.scale,
                slider_min=spec.lo,
                slider_max=spec.hi,
                slider_step=spec.step,
            )
        )
    return EstimatorGains(
        name=name, preset=est.preset, presets=list(presets), default_preset=est.DEFAULT_PRESET, gains=infos
    )


def known_estimator(station: StationDep, name: str) -> AttitudeEstimator:
    try:
        return station.estimator(name)
    except KeyError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=exc.args[0]) from None


@router.get("", response_model=list[EstimatorGains])
async def list_estimators(station: StationDep) -> list[EstimatorGains]:
    return [describe(name, station.estimator(name)) for name in station.estimator_names()]


@router.get("/{name}", response_model=EstimatorGains)
async def get_estimator(name: str, station: StationDep) -> EstimatorGains:
    return describe(name, known_estimator(station, name))


@router.put(
    "/{name}/gains/{gain}",
    response_model=GainChange,
    dependencies=[TOKEN],
    responses={
        404: {"description": "unknown estimator or gain"},
        422: {"description": "value outside the gain's declared bounds"},
    },
)
async def put_gain(name: str, gain: str, body: GainUpdate, station: StationDep, client: ClientDep) -> GainChange:
    est = known_estimator(station, name)
    if gain not in est.gains.declarations:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            detail=f"estimator {name} has no gain {gain!r}; known: {', '.join(est.gains.declarations)}",
        )
    try:
        old, new = station.set_gain(name, gain, body.value, client)
    except GainError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(exc)) from None
    return GainChange(estimator=name, gain=gain, old=old, new=new)


@router.post("/{name}/preset", response_model=PresetResult, dependencies=[TOKEN])
async def reset_preset(name: str, body: PresetRequest, station: StationDep, client: ClientDep) -> PresetResult:
    est = known_estimator(station, name)
    try:
        changes = station.reset_gains(name, body.preset, client)
    except GainError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(exc)) from None
    return PresetResult(
        estimator=name,
        preset=est.preset,
        changes=[GainChange(estimator=name, gain=g, old=o, new=n) for g, (o, n) in changes.items()],
    )
