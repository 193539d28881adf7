"""The FastAPI application: REST, the two WebSocket endpoints, and the viewer's static files.

Endpoints only translate between the network and the pure parts: `protocol` / `gazehdr.drivers.wire`
parse messages, `live.SessionHub` runs the sessions, `scenes.library` holds the scenes.
`create_app(config)` builds everything from one `ServerConfig`, so tests start a real server
with exactly the settings they need.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import contextlib
import dataclasses
import functools
import logging
import secrets
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, FastAPI, HTTPException, Request, WebSocket
from fastapi import Path as PathParam
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles

from gazehdr.fair_share import VIEW_BURST, VIEW_RATE, ConnectionShare, error_text
from gazehdr.gaze_link import GazeLink
from gazehdr.live import LiveSession, SessionHub, TooManySessionsError, Viewer
from gazehdr.metrics import Metrics
from gazehdr.params_schema import ParamsChange, changed
from gazehdr.protocol import (
    WORK_CONTROLS,
    Ack,
    EncodingChoice,
    KeyframeRequest,
    ProtocolError,
    SceneMaps,
    Warp,
    parse_control,
)
from gazehdr.recordings import MAX_UPLOAD_BYTES as MAX_RECORDING_BYTES
from gazehdr.recordings import RecordingLibrary
from gazehdr.scenes import Scene
from gazehdr.scenes.exr import SceneError
from gazehdr.scenes.level import session_frames
from gazehdr.scenes.library import (
    MAX_UPLOAD_BYTES,
    NoSuchSceneError,
    SceneBusyError,
    SceneExistsError,
    SceneLibrary,
    check_name,
)
from gazehdr.security import install as install_guard
from gazehdr.session import PRESET_VALUES, SIZE_STEP, Session, SessionSettings, fit_size
from gazehdr.sim import Params
from gazehdr.sim.layout import Layout
from gazehdr.sim.params import OURS, SECTIONS, check_remote_change
from gazehdr.sim.presets import describe
from gazehdr.viewer import default_web_dir, viewer_files

CLOSE_POLICY = 1008
CLOSE_BUSY = 1013
CLOSE_INTERNAL = 1011
log = logging.getLogger("gazehdr.app")
#: A scene or recording name, as `check_name` accepts it (documented; checked by check_name: 400).
Name = Annotated[
    str,
    PathParam(
        description="letters, digits, '_', '.', '-'; up to 64; no '..', no final '.'",
        max_length=64,  # refused before anything quotes it: an error never echoes a long name
        json_schema_extra={"pattern": r"^(?!.*\.\.)(?!.*\.$)[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"},
    ),
]


@dataclass(frozen=True)
class ServerConfig:
    host: str = "127.0.0.1"
    port: int = 8000
    session: SessionSettings = field(default_factory=SessionSettings)
    #: Bearer token for writes, private reads and both WebSockets (`gazehdr.security`); `serve`
    #: generates one when none is configured.
    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    #: False (`serve --no-auth`): no credential is asked for anything; Host and Origin still are.
    auth: bool = True
    #: Host names besides loopback and the bound address that clients may use (`--allow-host`).
    allow_hosts: tuple[str, ...] = ()
    data_dir: Path | None = None
    #: Scenes opened at start (e.g. an EXR named on the command line), by name.
    scenes: dict[str, Scene] = field(default_factory=dict)
    allow_origins: tuple[str, ...] = ()
    session_grace_s: float = 10.0
    max_sessions: int = 8
    max_upload_bytes: int = MAX_UPLOAD_BYTES
    #: Uploads handled at once: each holds its body (up to `max_upload_bytes`) in memory and a
    #: decode worker; one more is refused with 503 rather than queued (ours: 2, so uploads take
    #: at most twice the cap of the server's memory).
    max_uploads: int = 2
    #: The viewer's files (`gazehdr.viewer`); None: the installed package's.
    web_dir: Path | None = None
    #: Publish each session's journal (the gaze it follows, its events) as LSL streams of this
    #: name (`gazehdr.drivers.lsl.outlet.session_outlets`); None: no LSL.
    lsl_outlet: str | None = None
    #: An experiment to serve at /experiment (`serve --experiment`, `gazehdr experiment run`);
    #: a `gazehdr.experiment.service.ExperimentConfig`.
    experiment: Any = None


def _publisher(name: str | None) -> Callable[[Session], Any] | None:
    """What makes each session's LSL outlets (`serve --lsl-outlet NAME`), or None."""
    if name is None:
        return None
    from gazehdr.drivers.lsl.outlet import session_outlets

    return lambda session: session_outlets(name, session.id, session.log_screen)


def create_app(config: ServerConfig) -> FastAPI:
    """The app for `config`; ViewerMissingError (a ValueError) when the viewer is incomplete."""
    web_dir = config.web_dir or default_web_dir()
    viewer_files(web_dir)  # a server whose viewer would answer 404 does not start
    metrics = Metrics()
    # A scene is kept at its level for the frames sessions can have (gazehdr.scenes.level).
    budget = (config.session.width, config.session.height)
    frames = session_frames(budget, fit_size, SIZE_STEP)
    scenes = SceneLibrary(config.data_dir, config.scenes, frames=frames)
    recordings = RecordingLibrary(config.data_dir)
    hub = SessionHub(
        config.session,
        scenes,
        metrics,
        recordings,
        grace_s=config.session_grace_s,
        max_sessions=config.max_sessions,
        publish=_publisher(config.lsl_outlet),
    )
    defaults = {"params": config.session.params}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        await hub.close()
        scene_work.close()

    app = FastAPI(
        title="gazehdr",
        summary="Gaze-adaptive HDR display: live simulation of the viewer's eye",
        lifespan=lifespan,
    )
    app.state.hub = hub
    app.state.metrics = metrics
    app.state.config = config
    uploads = app.state.uploads = UploadSlots(config.max_uploads)
    scene_work = app.state.scene_work = SceneWork()

    # --- REST ---------------------------------------------------------------------------------

    @app.get("/api/health")
    async def health() -> dict[str, Any]:
        return {
            "status": "ok",
            "sessions": len(hub.sessions),
            "viewers": int(metrics.viewers.value),
            "trackers": hub.trackers.connections,
        }

    @app.get("/metrics", response_class=PlainTextResponse)
    async def prometheus() -> PlainTextResponse:
        return PlainTextResponse(metrics.render(), media_type="text/plain; version=0.0.4")

    @app.get("/api/scenes")
    async def list_scenes() -> dict[str, list[str]]:
        return {"scenes": scenes.names()}

    @app.put(
        "/api/scenes/{name:path}",
        status_code=201,
        openapi_extra=_binary_body("an image: OpenEXR, .hdr or PFM", config.max_upload_bytes),
        responses={
            400: {"description": "the name is not allowed"},
            409: {"description": "a scene of that name exists (see `overwrite`)"},
            413: {"description": "the upload is over the size limit"},
            422: {"description": "not an image the server can read"},
            503: {"description": "as many uploads as the server handles at once are running"},
        },
    )
    async def upload_scene(name: Name, request: Request, overwrite: bool = False) -> dict[str, str]:
        """Upload an image (OpenEXR, Radiance .hdr, PFM) as the request body; it is validated
        before it is kept. An existing upload of that name is replaced only with `overwrite`."""
        with uploads.take():
            chunks = await _upload_body(name, request, config.max_upload_bytes)
            try:
                await scene_work.run(request, scenes.store, name, chunks, overwrite=overwrite)
            except SceneExistsError as e:
                raise HTTPException(409, str(e)) from None
            except SceneBusyError as e:
                raise HTTPException(503, str(e), headers={"Retry-After": "1"}) from None
            except SceneError as e:
                raise HTTPException(422, str(e)) from None
        hub.broadcast({"type": "scenes", "scenes": scenes.names()})
        return {"name": name}

    @app.get(
        "/api/scenes/{name}",
        responses={
            404: {"description": "no such scene"},
            503: {"description": "as many scene requests as the server handles are running"},
        },
    )
    async def describe_scene(name: Name, request: Request) -> dict[str, Any]:
        """A scene's format, size, layers and scale (cd/m² per unit) with its source."""
        return await _scene_call(scene_work, request, scenes.describe, name)

    @app.patch(
        "/api/scenes/{name}",
        responses={
            400: {"description": "the body is not JSON"},
            404: {"description": "no such scene"},
            503: {"description": "as many scene requests as the server handles are running"},
        },
    )
    async def configure_scene(
        name: Name,
        request: Request,
        values: dict[str, Any] = Body(...),  # noqa: B008
    ) -> dict[str, Any]:
        """Set a scene's `scale` (cd/m² per unit), estimate `kind` or EXR `layer` (null: the
        default); every session showing it changes at once."""
        return await _scene_call(scene_work, request, scenes.configure, name, values)

    @app.get("/api/recordings")
    async def list_recordings() -> dict[str, list[str]]:
        """Session logs a session can follow as gaze source `replay:NAME`."""
        return {"recordings": recordings.names()}

    @app.put(
        "/api/recordings/{name:path}",
        status_code=201,
        openapi_extra=_binary_body(
            "a session log (JSON Lines)", min(config.max_upload_bytes, MAX_RECORDING_BYTES)
        ),
        responses={
            400: {"description": "the name is not allowed"},
            413: {"description": "the upload is over the size limit"},
            422: {"description": "not a session log with samples"},
            503: {"description": "as many uploads as the server handles at once are running"},
        },
    )
    async def upload_recording(name: Name, request: Request) -> dict[str, str]:
        """Upload a session log (JSON Lines, drivers/sessionlog/); validated before kept."""
        cap = min(config.max_upload_bytes, MAX_RECORDING_BYTES)
        with uploads.take():
            chunks = await _upload_body(name, request, cap)
            try:
                await asyncio.to_thread(recordings.store, name, chunks)
            except ValueError as e:
                raise HTTPException(422, str(e)) from None
        return {"name": name}

    @app.get("/api/params")
    async def get_params() -> dict[str, Any]:
        """Parameters new sessions start with, the preset they are nearest (`preset`: "paper",
        "visible", or one with the names it changes), and every preset's values; `defaults`
        is the paper's preset."""
        return {
            "params": defaults["params"].to_dict(),
            "preset": describe(defaults["params"]),
            "presets": PRESET_VALUES,
            "defaults": Params().to_dict(),
            "sections": SECTIONS,
            "ours": sorted(OURS),
        }

    @app.put("/api/params", responses={400: {"description": "the body is not JSON"}})
    async def put_params(body: ParamsChange) -> dict[str, Any]:
        """Change (some of) the parameters new sessions start with."""
        values = changed(body)
        try:
            check_remote_change(defaults["params"], values)
            params = Params.from_dict({**defaults["params"].to_dict(), **values})
            Layout.for_frame(config.session.width, config.session.height, params)  # its work
        except (TypeError, ValueError) as e:
            raise HTTPException(422, f"parameters refused: {e}") from None
        defaults["params"] = params
        hub.settings = dataclasses.replace(hub.settings, params=params)
        return {"params": params.to_dict()}

    @app.get("/api/sessions")
    async def list_sessions() -> list[dict[str, Any]]:
        return [
            {
                "id": live.session.id,
                "viewers": len(live.viewers),
                "scene": live.session.scene_name,
                "model": str(live.session.model),
                "split": None if live.session.split is None else str(live.session.split),
                "frame": live.session.frame,
                "time": live.session.sim.time,
                "size": list(live.session.size),
            }
            for live in hub.sessions.values()
        ]

    # --- /ws/view -----------------------------------------------------------------------------

    @app.websocket("/ws/view")
    async def view(ws: WebSocket, session: str | None = None) -> None:
        await ws.accept()  # Host, Origin and credential: checked by gazehdr.security's Guard
        viewer = Viewer(ws.send_bytes, ws.send_json, metrics)
        try:
            live = await hub.join(session, viewer)
        except TooManySessionsError as e:
            await ws.close(CLOSE_BUSY, str(e))
            return
        except Exception as e:  # a scene or device that fails: say so instead of a bare close
            log.exception("could not start a session")
            await ws.send_json({"type": "error", "message": f"no session: {e}", "in": None})
            await ws.close(CLOSE_INTERNAL, "could not start a session")
            return
        hello = {"type": "hello", "protocol": 1, "session": live.session.id}
        viewer.mailbox.put(None, [{**hello, **live.session.state()}])
        tasks = [
            asyncio.create_task(viewer.pump()),
            asyncio.create_task(viewer.pump_gaze()),
            asyncio.create_task(_receive_controls(ws, live, viewer)),
        ]
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in done:  # an error is the socket gone mid-send: nothing to tell anyone.
                task.exception()  # Not result(): its raise would put this frame, which holds the
                # session, in a traceback the task keeps, a cycle that outlives the session.
        finally:
            for task in tasks:
                task.cancel()
            hub.leave(live, viewer)
        with contextlib.suppress(Exception):
            await ws.close()

    async def _receive_controls(ws: WebSocket, live: LiveSession, viewer: Viewer) -> None:
        share = ConnectionShare(VIEW_RATE, VIEW_BURST)  # this viewer's share (fair_share)
        while True:
            while (wait := share.admit(time.monotonic())) > 0:
                metrics.messages_held.inc()
                await asyncio.sleep(wait)  # not reading: the socket holds the sender back
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            try:
                text = message.get("text")
                if text is None:
                    raise ProtocolError("binary messages are not accepted; send JSON text")
                control = parse_control(text)
                if isinstance(control, WORK_CONTROLS):
                    while (wait := share.work(time.monotonic())) > 0:
                        metrics.messages_held.inc()
                        await asyncio.sleep(wait)
                if isinstance(control, Ack):
                    viewer.ack()
                    continue
                if isinstance(control, SceneMaps):
                    viewer.want_maps(control.send, live.scene_map)
                    continue
                if isinstance(control, Warp):
                    live.set_warp(viewer, control.on)
                    continue
                if isinstance(control, EncodingChoice):  # per viewer (docs/protocol.md)
                    live.streams.choose(viewer, control.encoding)
                    continue
                if isinstance(control, KeyframeRequest):
                    live.streams.want_key(viewer)
                    continue
                live.submit(control)
            except ProtocolError as e:
                metrics.protocol_errors.inc()
                left_out = share.error(time.monotonic())
                if left_out is not None:
                    note = {"type": "error", "message": error_text(str(e), left_out)}
                    viewer.mailbox.put(None, [{**note, "in": e.in_type}])

    # --- /ws/gaze -----------------------------------------------------------------------------

    @app.websocket("/ws/gaze")
    async def gaze(ws: WebSocket) -> None:
        await ws.accept()  # the bearer token: checked by gazehdr.security's Guard
        hub.trackers.connections += 1
        metrics.trackers.set(hub.trackers.connections)
        link = GazeLink(ws, hub, metrics)
        try:
            await link.run()
        finally:
            hub.trackers.connections -= 1
            link.close()

    if config.experiment is not None:
        from gazehdr.experiment.service import install as install_experiment

        install_experiment(app, config.experiment, web_dir, hub.trackers)
    app.mount("/", StaticFiles(directory=web_dir, html=True), name="web")
    app.add_exception_handler(RequestValidationError, _validation_error)
    install_guard(app, config)
    return app


def _binary_body(what: str, cap: int) -> dict[str, Any]:
    """The OpenAPI request body of an upload: raw bytes, at most `cap` (else 413)."""
    schema = {"type": "string", "format": "binary", "maxLength": cap}
    return {
        "requestBody": {
            "required": True,
            "description": f"{what}, as the raw body; at most {cap} bytes",
            "content": {"application/octet-stream": {"schema": schema}},
        }
    }


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 in the API's one error shape: `detail` is a sentence, not a list."""
    assert isinstance(exc, RequestValidationError)
    said = []
    for error in exc.errors():
        where = ".".join(str(part) for part in error.get("loc", ()))
        said.append(f"{where}: {error.get('msg', 'invalid')}")
    return JSONResponse({"detail": "; ".join(said) or "invalid request"}, status_code=422)


async def _scene_call(
    work: SceneWork, request: Request, call: Callable[..., dict[str, Any]], name: str, *args: Any
) -> dict[str, Any]:
    """A scene library call on the scene threads; an unknown name is 404, bad input 422, no
    decode slot free 503."""
    try:
        return await work.run(request, call, name, *args)
    except SceneBusyError as e:
        raise HTTPException(503, str(e), headers={"Retry-After": "1"}) from None
    except SceneError as e:
        raise HTTPException(404 if isinstance(e, NoSuchSceneError) else 422, str(e)) from None


class SceneWork:
    """The scene routes' library calls (PUT, GET, PATCH /api/scenes/NAME: any of them may
    decode a file) on threads of their own, so the threads that start sessions never wait
    behind them. At most `limit` calls are in flight (running or queued) and at most
    `per_client` for one client address; one more is refused with 503 rather than queued. A
    call counts until its thread is done with it, even when its client has gone. Decoding
    itself is bounded by the library (`gazehdr.scenes.library.DecodeSlots`)."""

    def __init__(self, threads: int = 6, limit: int = 32, per_client: int = 8) -> None:
        self.pool = concurrent.futures.ThreadPoolExecutor(threads, "gazehdr-scenes")
        self.limit, self.per_client = limit, per_client
        self.busy = 0
        self.clients: collections.Counter[str] = collections.Counter()

    async def run(self, request: Request, call: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        client = request.client.host if request.client else "?"
        if self.busy >= self.limit or self.clients[client] >= self.per_client:
            raise HTTPException(
                503,
                f"the server handles {self.limit} scene requests at once, {self.per_client} "
                "from one client (its limits); try again shortly",
                headers={"Retry-After": "1"},
            )
        self.busy += 1  # taken on the event loop, with no await since the check
        self.clients[client] += 1
        loop = asyncio.get_running_loop()

        def done(_: concurrent.futures.Future[Any]) -> None:
            with contextlib.suppress(RuntimeError):  # the loop closed: the server has stopped
                loop.call_soon_threadsafe(self._release, client)

        future = self.pool.submit(functools.partial(call, *args, **kw))
        future.add_done_callback(done)
        return await asyncio.wrap_future(future)

    def _release(self, client: str) -> None:
        self.busy -= 1
        self.clients[client] -= 1
        if self.clients[client] <= 0:
            del self.clients[client]

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)


class UploadSlots:
    """Uploads in flight, at most `limit`. Taken and counted on the event loop with no await
    between the check and the count, so uploads that arrive together cannot all pass."""

    def __init__(self, limit: int) -> None:
        self.limit, self.busy = limit, 0

    @contextlib.contextmanager
    def take(self) -> Iterator[None]:
        if self.busy >= self.limit:
            raise HTTPException(
                503,
                f"the server handles {self.limit} uploads at once (its limit); try again shortly",
                headers={"Retry-After": "1"},
            )
        self.busy += 1
        try:
            yield
        finally:
            self.busy -= 1


async def _upload_body(name: str, request: Request, cap: int) -> list[bytes]:
    """The request body, refused as soon as it passes `cap` bytes; `name` checked first."""
    try:
        check_name(name)
    except SceneError as e:
        raise HTTPException(400, str(e)) from None
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > cap:
        raise HTTPException(413, f"upload of {declared} bytes is over the {cap}-byte limit")
    chunks, total = [], 0
    async for chunk in request.stream():
        total += len(chunk)
        if total > cap:
            raise HTTPException(413, f"upload is over the {cap}-byte limit")
        chunks.append(chunk)
    return chunks
