"""The FastAPI application: REST, the two WebSocket endpoints, and the viewer's static files.

Endpoints only translate between the network and the pure parts: `protocol` / `gazehdr.drivers.wire`
parse messages, `live.SessionHub` runs the sessions, `scenes.library` holds the scenes.
`create_app(config)` builds everything from one `ServerConfig`, so tests start a real server
with exactly the settings they need.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import secrets
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, FastAPI, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi import Path as PathParam
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles

from gazehdr.drivers import wire
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.gaze import TrackerFeed
from gazehdr.live import LiveSession, SessionHub, TooManySessionsError, Viewer
from gazehdr.metrics import Counter, Metrics
from gazehdr.params_schema import ParamsChange, changed
from gazehdr.protocol import (
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
from gazehdr.scenes.library import (
    MAX_UPLOAD_BYTES,
    NoSuchSceneError,
    SceneExistsError,
    SceneLibrary,
    check_name,
)
from gazehdr.security import install as install_guard
from gazehdr.session import Session, SessionSettings
from gazehdr.sim import Params
from gazehdr.sim.params import OURS, SECTIONS, check_remote_change
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


@dataclass(frozen=True)
class GazeLimit:
    """A per-connection rate limit on one kind of `/ws/gaze` message."""

    unit: str  # what it counts, as the note to the daemon names it
    rate: float
    burst: float


# Per-connection limits on /ws/gaze, per kind of message. What passes a limit is dropped, counted
# in /metrics and noted to the daemon (at most every NOTE_INTERVAL_S), and the connection is not
# read until the limit has taken the excess back (_GazeLink.run). Each sits well above what a
# real daemon sends, measured against this server with a 1200 Hz live synthetic source and with
# 30 and 60 Hz recordings replayed at full speed.
GAZE_RATE_HZ = 2000.0  # samples per second per daemon connection, sustained
GAZE_BURST = 4000.0
SAMPLE_LIMIT = GazeLimit("samples", GAZE_RATE_HZ, GAZE_BURST)
# Events: live, about 20/s (I-VT: a fixation_update per 50 ms of sample time, a start and an end
# per fixation, blinks). Only a recording replayed at full speed makes them follow the sample
# rate, which the daemon keeps below GAZE_RATE_HZ: a 30 Hz one measured 800 events/s (2400/s over
# a quarter second). The sample limit covers that with room to spare.
EVENT_LIMIT = GazeLimit("events", 2000.0, 4000.0)
# Echoes: the daemon echoes after each sending round (every 20 ms at most, plus a round per event)
# to acknowledge delivery and follow the clock: measured at most 64/s. 500/s is eight times that.
ECHO_LIMIT = GazeLimit("echoes", 500.0, 1000.0)
NOTE_INTERVAL_S = 1.0  # one rate-limit note a second per kind and connection tells enough


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
    scenes = SceneLibrary(config.data_dir, config.scenes)
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

    app = FastAPI(
        title="gazehdr",
        summary="Gaze-adaptive HDR display: live simulation of the viewer's eye",
        lifespan=lifespan,
    )
    app.state.hub = hub
    app.state.metrics = metrics
    app.state.config = config
    uploads = app.state.uploads = UploadSlots(config.max_uploads)

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
                await asyncio.to_thread(scenes.store, name, chunks, overwrite=overwrite)
            except SceneExistsError as e:
                raise HTTPException(409, str(e)) from None
            except SceneError as e:
                raise HTTPException(422, str(e)) from None
        hub.broadcast({"type": "scenes", "scenes": scenes.names()})
        return {"name": name}

    @app.get("/api/scenes/{name}", responses={404: {"description": "no such scene"}})
    async def describe_scene(name: Name) -> dict[str, Any]:
        """A scene's format, size, layers and scale (cd/m² per unit) with its source."""
        return await _scene_call(scenes.describe, name)

    @app.patch(
        "/api/scenes/{name}",
        responses={
            400: {"description": "the body is not JSON"},
            404: {"description": "no such scene"},
        },
    )
    async def configure_scene(
        name: Name,
        values: dict[str, Any] = Body(...),  # noqa: B008
    ) -> dict[str, Any]:
        """Set a scene's `scale` (cd/m² per unit), estimate `kind` or EXR `layer` (null: the
        default); every session showing it changes at once."""
        return await _scene_call(scenes.configure, name, values)

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
        """Parameters new sessions start with; `defaults` is the paper's preset."""
        return {
            "params": defaults["params"].to_dict(),
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
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            try:
                text = message.get("text")
                if text is None:
                    raise ProtocolError("binary messages are not accepted; send JSON text")
                control = parse_control(text)
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
                viewer.mailbox.put(None, [{"type": "error", "message": str(e), "in": e.in_type}])

    # --- /ws/gaze -----------------------------------------------------------------------------

    @app.websocket("/ws/gaze")
    async def gaze(ws: WebSocket) -> None:
        await ws.accept()  # the bearer token: checked by gazehdr.security's Guard
        hub.trackers.connections += 1
        metrics.trackers.set(hub.trackers.connections)
        link = _GazeLink(ws, hub, metrics)
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


async def _scene_call(call: Callable[..., dict[str, Any]], name: str, *args: Any) -> dict[str, Any]:
    """A scene library call off the event loop; an unknown name is 404, bad input 422."""
    try:
        return await asyncio.to_thread(call, name, *args)
    except SceneError as e:
        raise HTTPException(404 if isinstance(e, NoSuchSceneError) else 422, str(e)) from None


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


class _Limiter:
    """One `GazeLimit` on one connection: what it drops is counted at once and reported to the
    daemon at most every `NOTE_INTERVAL_S`, as the number dropped since the previous note (the
    daemon adds them up)."""

    def __init__(self, limit: GazeLimit, dropped: Counter) -> None:
        self.limit, self.dropped = limit, dropped
        self.bucket = TokenBucket(limit.rate, limit.burst)
        self.unreported = 0
        self.noted_at = -math.inf

    def admit(self, n: int, now: float) -> tuple[int, wire.Notice | None]:
        """How many of `n` items pass, and the note to send, if one is due."""
        allowed = self.bucket.admit(n, now)
        if allowed == n:
            return allowed, None
        self.dropped.inc(n - allowed)
        self.unreported += n - allowed
        if now - self.noted_at < NOTE_INTERVAL_S:
            return allowed, None
        unit, rate = self.limit.unit, self.limit.rate
        note = wire.Notice(
            f"rate limit: {self.unreported} {unit} dropped; at most {rate:g} {unit}/s are accepted"
        )
        self.noted_at, self.unreported = now, 0
        return allowed, note


class _GazeLink:
    """One daemon connection: its tracker's feed follows the daemon's fixations (or its raw
    samples, if it sends no events). The feed is the tracker its hello names; a daemon that
    sends gaze before any hello is an unnamed tracker."""

    def __init__(self, ws: WebSocket, hub: SessionHub, metrics: Metrics) -> None:
        self.ws, self.hub, self.metrics = ws, hub, metrics
        self.limits = {
            wire.Samples: _Limiter(SAMPLE_LIMIT, metrics.gaze_rate_limited),
            wire.Event: _Limiter(EVENT_LIMIT, metrics.gaze_events_rate_limited),
            wire.Echo: _Limiter(ECHO_LIMIT, metrics.gaze_echoes_rate_limited),
        }
        self.uses_events = False
        self.said_hello = False
        self.feed: TrackerFeed | None = None
        self.hold_s = 0.0  # how long to stop reading, after a message that went over a limit

    async def run(self) -> None:
        while True:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            try:
                text = message.get("text")
                if text is None:
                    raise wire.WireError("binary messages are not accepted; send JSON text")
                reply = self.handle(wire.parse(text), time.monotonic())
            except wire.WireError as e:
                self.metrics.protocol_errors.inc()
                reply = wire.Notice(str(e))
            if reply:
                try:
                    await self.ws.send_text(wire.dumps(reply))
                except WebSocketDisconnect:  # gone while we answered: nothing left to do
                    return
            if self.hold_s:
                # Dropping is not enough: receiving and parsing cost more than the limit saves,
                # so a daemon flooding small messages would take this server's event loop from
                # every session. Reading nothing for as long as the bucket needs to take back
                # what went over lets the socket's flow control hold the daemon back instead.
                await asyncio.sleep(self.hold_s)
                self.hold_s = 0.0

    def close(self) -> None:
        """The connection ended: its tracker is no longer connected; the viewers are told."""
        self.metrics.trackers.set(self.hub.trackers.connections)
        if self.feed is not None:
            self.hub.trackers.disconnect(self.feed)
            self._tell_viewers(self.feed)

    def handle(self, msg: wire.Message, now: float) -> wire.Reply | None:
        if isinstance(msg, wire.Hello):
            return self._hello(msg)
        count = len(msg.samples) if isinstance(msg, wire.Samples) else 1
        limiter = self.limits[type(msg)]
        allowed, note = limiter.admit(count, now)
        self.hold_s = (count - allowed) / limiter.limit.rate
        if isinstance(msg, wire.Samples):
            self._samples(msg.samples[:allowed], now)
        elif allowed and isinstance(msg, wire.Echo):
            return wire.EchoReply(msg.t0_ns, time.monotonic_ns())
        elif allowed:
            self._event(msg, now)
        return note

    def _hello(self, msg: wire.Hello) -> wire.Welcome:
        # Every hello is broadcast to every viewer of every session: a second one on the same
        # connection is refused, so that a flood of them cannot reach the other sessions.
        if self.said_hello:
            raise wire.WireError("hello: this connection has said hello already")
        self.said_hello = True
        if self.feed is not None:  # gaze came first, as an unnamed tracker: that one ends
            self.close()
            self.feed = None
        self.feed = self._connect(msg.tracker)
        self.feed.hello(msg.accuracy_deg)
        return wire.Welcome(wire.PROTOCOL)

    def _connect(self, name: str | None) -> TrackerFeed:
        try:
            feed = self.hub.trackers.connect(name)
        except ValueError as e:  # the table of tracker names is full
            raise wire.WireError(str(e)) from None
        self._tell_viewers(feed)
        return feed

    def _tell_viewers(self, feed: TrackerFeed) -> None:
        self.hub.broadcast({"type": "tracker", **feed.describe()})

    def _tracker(self) -> TrackerFeed:
        if self.feed is None:
            self.feed = self._connect(None)
        return self.feed

    def _event(self, msg: wire.Event, now: float) -> None:
        self.uses_events = True
        self._tracker().events += 1
        if msg.kind in ("fixation_start", "fixation_update"):
            self._tracker().fixate(msg.x, msg.y, True, now)
        elif msg.kind in ("blink_start", "blink_end"):
            self._tracker().fixate(None, None, msg.kind == "blink_end", now)

    def _samples(self, samples: tuple[wire.Sample, ...], now: float) -> None:
        self.metrics.gaze_samples.inc(len(samples))
        feed = self._tracker()
        feed.count([s.t_ns for s in samples])  # the tracker's rate, from the samples' times
        if not self.uses_events:
            valid = [s for s in samples if s.valid]
            if valid:
                feed.fixate(valid[-1].x, valid[-1].y, True, now)
