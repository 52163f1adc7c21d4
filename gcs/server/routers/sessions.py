"""Sessions over REST: list recorded sessions, download an export, start/stop the recording,
add a note, list log files beside the sessions, compute a replay and ask what-if questions.

Sources are named, never given as paths: a session folder name or a log file name inside the
recording folder, so a remote page cannot read arbitrary files. State-changing requests need the
token. Replays, exports and what-if run in the station's worker process, so the link reader and
the live view never wait on them, and each client may ask for only so many a minute
(`server.ratelimit`). A replay is one request (GET /api/replay): the whole replay, computed in the
worker, for the asking viewer's replay page to play (web/public/replay.html); nothing of it goes to
the live plots or to any other viewer.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Query, status
from fastapi.responses import FileResponse, Response
from pydantic import Field
from starlette.background import BackgroundTask

from gcs.core.gains import GainError
from gcs.logs.logfile import InputError
from gcs.runtime.facade import StationFacade
from gcs.runtime.replay import replay_series, selection
from gcs.runtime.snapshots import RecordingSnapshot
from gcs.runtime.station import StationError
from gcs.server.deps import TOKEN, ClientDep, StationDep
from gcs.server.models import Body
from gcs.server.ratelimit import rate_limited
from gcs.sessions import layout
from gcs.sessions.export import FORMATS
from gcs.sessions.sources import KINDS
from gcs.sessions.whatif import WhatIfView
from gcs.sessions.workbench import export_file, what_if_view

router = APIRouter(prefix="/api", tags=["sessions"])


class Note(Body):
    text: str = Field(min_length=1, max_length=2000)


class WhatIfRequest(Body):
    source: str
    estimator: str
    gains: dict[str, float]


def named_source(station: StationFacade, name: str) -> Path:
    """The session or log called `name` in the recording folder; 404 otherwise."""
    root = station.recording_root.resolve()
    path = (root / name).resolve()
    if not inside(root, path) or not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no session or log {name!r} in {root}")
    return path


def inside(root: Path, path: Path) -> bool:
    """Is `path`, its links followed, an entry of the (resolved) recording folder `root`? The
    lists offer only what `named_source` opens: a link to a file elsewhere was listed, with
    that file's size, and its replay answered 404."""
    return path.resolve().parent == root


def conflict(exc: StationError) -> HTTPException:
    return HTTPException(status.HTTP_409_CONFLICT, detail=str(exc))


@router.get("/sessions")
async def list_recorded(station: StationDep) -> list[dict[str, Any]]:
    root = station.recording_root.resolve()
    return [s.as_dict() for s in layout.list_sessions(station.recording_root) if inside(root, Path(s.path))]


@router.get("/logs")
async def list_logs(station: StationDep) -> list[dict[str, Any]]:
    """Log files from other tools (.tlog, .bin, .log, .ulg) in the recording folder: replay and what-if
    sources, by name, beside the recorded sessions."""
    root = station.recording_root.resolve()
    if not root.is_dir():
        return []
    return [
        {"name": p.name, "kind": KINDS[p.suffix.lower()], "size_bytes": p.stat().st_size}
        for p in sorted(root.iterdir())
        if p.is_file() and p.suffix.lower() in KINDS and inside(root, p)
    ]


@router.get("/sessions/{name}/export", response_class=FileResponse, dependencies=[Depends(rate_limited("export"))])
async def export(name: str, station: StationDep, format: str = "csv") -> FileResponse:
    if format not in FORMATS:
        raise HTTPException(422, detail=f"format {format!r}: use one of {', '.join(FORMATS)}")
    path = named_source(station, name)
    with tempfile.NamedTemporaryFile(suffix=f".{format}", delete=False) as tmp:
        out = Path(tmp.name)
    try:
        await station.in_worker(export_file, path, format, out)
    except InputError as exc:
        out.unlink(missing_ok=True)
        raise HTTPException(422, detail=str(exc)) from None
    return FileResponse(
        out, filename=f"{Path(name).stem}.{format}", background=BackgroundTask(out.unlink, missing_ok=True)
    )


@router.get("/recording")
async def recording(station: StationDep) -> RecordingSnapshot:
    return station.recording_snapshot()


@router.post("/recording/start", dependencies=[TOKEN])
async def start_recording(station: StationDep) -> RecordingSnapshot:
    try:
        return station.start_recording()
    except StationError as exc:
        raise conflict(exc) from None


@router.post("/recording/stop", dependencies=[TOKEN])
async def stop_recording(station: StationDep, client: ClientDep) -> RecordingSnapshot:
    try:
        return await station.stop_recording(client)
    except StationError as exc:
        raise conflict(exc) from None


@router.post("/recording/note", dependencies=[TOKEN])
async def add_note(note: Note, station: StationDep, client: ClientDep) -> dict[str, bool]:
    try:
        station.add_note(note.text, client)
    except StationError as exc:
        raise conflict(exc) from None
    return {"ok": True}


@router.get("/replay", dependencies=[Depends(rate_limited("replay"))])
async def replay(
    station: StationDep,
    source: str = Query(description="session folder name or log file name in the recording folder"),
    estimator: list[str] | None = Query(None, description="estimators to run (repeatable; default all)"),
    gain: list[str] = Query([], description="[EST.]NAME=VALUE gain overrides (repeatable)"),
) -> Response:
    """The whole replay of a session or log, computed in the worker process: every source's
    attitude (vehicle s, degrees; the live frames' columns) and the session error table. Read-only:
    it changes nothing on the station, and only the viewer that asked sees it."""
    path = named_source(station, source)
    try:
        names, gains = selection(estimator, gain)
        body = await station.in_worker(replay_series, path, names, gains)
    except (InputError, KeyError, GainError, ValueError) as exc:
        raise HTTPException(422, detail=str(exc.args[0] if isinstance(exc, KeyError) else exc)) from None
    return Response(body, media_type="application/json")


@router.post("/whatif", dependencies=[TOKEN, Depends(rate_limited("whatif"))])
async def whatif(body: WhatIfRequest, station: StationDep) -> WhatIfView:
    """Old and new output of one estimator over a whole session with other gains, and the RMS table."""
    path = named_source(station, body.source)
    try:
        return await station.in_worker(what_if_view, path, body.estimator, body.gains)
    except KeyError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=exc.args[0]) from None
    except (InputError, GainError) as exc:
        raise HTTPException(422, detail=str(exc)) from None
