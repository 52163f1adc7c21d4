"""Sessions over REST: list recorded sessions, download an export, start/stop the recording,
add a note, list log files beside the sessions, drive a replay (play, pause, seek, speed) and ask what-if questions.

Sources are named, never given as paths: a session folder name or a log file name inside the
recording folder, so a remote page cannot read arbitrary files. State-changing requests need the
token when one is required. Decoding and estimator re-runs happen in a worker thread, so the
link reader and the live view never wait on them.
"""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from fastapi import APIRouter, Depends, HTTPException, Request, status
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field
from starlette.background import BackgroundTask

from gcs.core.gains import GainError
from gcs.logs.readers import InputError
from gcs.runtime.replay import ReplaySession
from gcs.runtime.station import GroundStation
from gcs.server.deps import client_name, get_station, require_token
from gcs.sessions import layout
from gcs.sessions.export import FORMATS, attitude_table, write_table
from gcs.sessions.sources import KINDS, cached_source
from gcs.sessions.whatif import what_if

router = APIRouter(prefix="/api", tags=["sessions"])


class Note(BaseModel):
    text: str = Field(min_length=1, max_length=2000)


class ReplayRequest(BaseModel):
    source: str = Field(description="session folder name or log file name in the recording folder")
    speed: float = Field(1.0, ge=0, description="0 = as fast as possible")
    estimators: list[str] | None = None
    gains: dict[str, dict[str, float]] = Field(default_factory=dict, description="{estimator: {gain: value}}")


class Seek(BaseModel):
    offset_s: float = Field(ge=0)


class Speed(BaseModel):
    speed: float = Field(ge=0)


class WhatIfRequest(BaseModel):
    source: str
    estimator: str
    gains: dict[str, float]


def recording_root(station: GroundStation) -> Path:
    return station.recorder.root if station.recorder is not None else Path("sessions")


def named_source(station: GroundStation, name: str) -> Path:
    """The session or log called `name` in the recording folder; 404 otherwise."""
    root = recording_root(station).resolve()
    path = (root / name).resolve()
    if path.parent != root or not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no session or log {name!r} in {root}")
    return path


def recorder_of(station: GroundStation):
    if station.recorder is None:
        raise HTTPException(status.HTTP_409_CONFLICT, detail="this station runs without recording (--no-record)")
    return station.recorder


def replay_of(request: Request) -> ReplaySession:
    replay = getattr(request.app.state, "replay", None)
    if replay is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail="no replay loaded: POST /api/replay first")
    return replay


@router.get("/sessions")
def list_recorded(station: GroundStation = Depends(get_station)) -> list[dict]:
    return [s.as_dict() for s in layout.list_sessions(recording_root(station))]


@router.get("/logs")
def list_logs(station: GroundStation = Depends(get_station)) -> list[dict]:
    """Log files from other tools (.tlog, .bin, .ulg) in the recording folder: replay and what-if
    sources, by name, beside the recorded sessions."""
    root = recording_root(station)
    if not root.is_dir():
        return []
    return [
        {"name": p.name, "kind": KINDS[p.suffix.lower()], "size_bytes": p.stat().st_size}
        for p in sorted(root.iterdir())
        if p.is_file() and p.suffix.lower() in KINDS
    ]


@router.get("/sessions/{name}/export", response_class=FileResponse)
async def export(name: str, format: str = "csv", station: GroundStation = Depends(get_station)) -> FileResponse:
    if format not in FORMATS:
        raise HTTPException(422, detail=f"format {format!r}: use {' or '.join(FORMATS)}")
    path = named_source(station, name)
    tmp = tempfile.NamedTemporaryFile(suffix=f".{format}", delete=False)
    tmp.close()
    try:
        table = await asyncio.to_thread(attitude_table, path)
        await asyncio.to_thread(write_table, table, format, tmp.name)
    except InputError as exc:
        Path(tmp.name).unlink(missing_ok=True)
        raise HTTPException(422, detail=str(exc)) from None
    return FileResponse(
        tmp.name,
        filename=f"{Path(name).stem}.{format}",
        background=BackgroundTask(Path(tmp.name).unlink, missing_ok=True),
    )


@router.get("/recording")
def recording(station: GroundStation = Depends(get_station)) -> dict:
    return station.recorder.status() if station.recorder else {"state": "off"}


@router.post("/recording/start", dependencies=[Depends(require_token)])
async def start_recording(station: GroundStation = Depends(get_station)) -> dict:
    recorder = recorder_of(station)
    recorder.start_recording()
    return recorder.status()


@router.post("/recording/stop", dependencies=[Depends(require_token)])
async def stop_recording(request: Request, station: GroundStation = Depends(get_station)) -> dict:
    """Detach the session in the event loop, then close it (flush, Parquet) in a worker thread."""
    recorder = recorder_of(station)
    session = recorder.detach(client_name(request))
    if session is not None:
        try:
            await asyncio.to_thread(recorder.finish, session)
        except OSError as exc:
            recorder.report_error(f"cannot close session {session.folder}: {exc.strerror or exc}")
    return recorder.status()


@router.post("/recording/note", dependencies=[Depends(require_token)])
async def add_note(note: Note, request: Request, station: GroundStation = Depends(get_station)) -> dict:
    recorder_of(station).note(note.text, client_name(request))
    return {"ok": True}


@router.post("/replay", dependencies=[Depends(require_token)])
async def load_replay(body: ReplayRequest, request: Request, station: GroundStation = Depends(get_station)) -> dict:
    """Load a source and start playing it (replacing any replay already loaded)."""
    path = named_source(station, body.source)
    try:
        source = await asyncio.to_thread(cached_source, path)
        replay = ReplaySession(source, body.speed, body.estimators, body.gains)
    except (InputError, KeyError, GainError) as exc:
        raise HTTPException(422, detail=str(exc).strip("'")) from None
    await unload_replay(request)
    hub = getattr(request.app.state, "hub", None)
    if hub is not None:
        replay.add_listener(hub.on_points)  # the dashboard plots replayed points as it plots live ones
    request.app.state.replay = replay
    request.app.state.replay_task = asyncio.create_task(replay.run())
    return replay.status()


@router.get("/replay")
def replay_status(request: Request) -> dict:
    return replay_of(request).status()


@router.get("/replay/current")
def current_replay(request: Request) -> dict:
    """The loaded replay's status with loaded=true, or {"loaded": false}: what the page polls
    (no 404 every second while nothing is replayed)."""
    replay = getattr(request.app.state, "replay", None)
    return {"loaded": False} if replay is None else {"loaded": True, **replay.status()}


@router.post("/replay/play", dependencies=[Depends(require_token)])
def play(request: Request) -> dict:
    replay = replay_of(request)
    replay.play()
    return replay.status()


@router.post("/replay/pause", dependencies=[Depends(require_token)])
def pause(request: Request) -> dict:
    replay = replay_of(request)
    replay.pause()
    return replay.status()


@router.post("/replay/seek", dependencies=[Depends(require_token)])
async def seek(body: Seek, request: Request) -> dict:
    replay = replay_of(request)
    replay.pause()
    await asyncio.to_thread(replay.seek, body.offset_s)
    replay.play()
    return replay.status()


@router.post("/replay/speed", dependencies=[Depends(require_token)])
def speed(body: Speed, request: Request) -> dict:
    replay = replay_of(request)
    replay.set_speed(body.speed)
    return replay.status()


@router.delete("/replay", dependencies=[Depends(require_token)])
async def unload_replay(request: Request) -> dict:
    task = getattr(request.app.state, "replay_task", None)
    if task is not None:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    request.app.state.replay = request.app.state.replay_task = None
    return {"ok": True}


@router.post("/whatif")
async def whatif(body: WhatIfRequest, station: GroundStation = Depends(get_station)) -> dict:
    """Old and new output of one estimator over a whole session with other gains, and the RMS table."""
    path = named_source(station, body.source)
    try:
        result = await asyncio.to_thread(what_if, path, body.estimator, body.gains)
    except KeyError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=exc.args[0]) from None
    except (InputError, GainError) as exc:
        raise HTTPException(422, detail=str(exc)) from None
    return result.as_dict()
