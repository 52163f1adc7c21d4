"""Estimator gains over REST: list the declarations with current values and slider shapes,
change one gain, reset an estimator to a preset. Changes need the token when one is required
and are recorded in the station's event log by GainControl."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request, status

from gcs.core.gains import GainError
from gcs.server.deps import client_name, get_gains, require_token
from gcs.server.gains import GainControl, slider_spec
from gcs.server.models import EstimatorGains, GainChange, GainInfo, GainUpdate, PresetRequest, PresetResult

router = APIRouter(prefix="/api/estimators", tags=["gains"])


def describe(name: str, est) -> EstimatorGains:
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


def known_estimator(name: str, gains: GainControl):
    try:
        return gains.estimator(name)
    except KeyError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=exc.args[0]) from None


@router.get("", response_model=list[EstimatorGains])
def list_estimators(gains: GainControl = Depends(get_gains)) -> list[EstimatorGains]:
    return [describe(name, est) for name, est in gains.pipeline.estimators.items()]


@router.get("/{name}", response_model=EstimatorGains)
def get_estimator(name: str, gains: GainControl = Depends(get_gains)) -> EstimatorGains:
    return describe(name, known_estimator(name, gains))


@router.put(
    "/{name}/gains/{gain}",
    response_model=GainChange,
    dependencies=[Depends(require_token)],
    responses={
        404: {"description": "unknown estimator or gain"},
        422: {"description": "value outside the gain's declared bounds"},
    },
)
def put_gain(
    name: str, gain: str, body: GainUpdate, request: Request, gains: GainControl = Depends(get_gains)
) -> GainChange:
    est = known_estimator(name, gains)
    if gain not in est.gains.declarations:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            detail=f"estimator {name} has no gain {gain!r}; known: {', '.join(est.gains.declarations)}",
        )
    try:
        old, new = gains.set(name, gain, body.value, client_name(request))
    except GainError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(exc)) from None
    return GainChange(estimator=name, gain=gain, old=old, new=new)


@router.post("/{name}/preset", response_model=PresetResult, dependencies=[Depends(require_token)])
def reset_preset(
    name: str, body: PresetRequest, request: Request, gains: GainControl = Depends(get_gains)
) -> PresetResult:
    est = known_estimator(name, gains)
    try:
        changes = gains.reset(name, body.preset, client_name(request))
    except GainError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(exc)) from None
    return PresetResult(
        estimator=name,
        preset=est.preset,
        changes=[GainChange(estimator=name, gain=g, old=o, new=n) for g, (o, n) in changes.items()],
    )
