"""Sessions at real time: a render loop per session, a newest-frame mailbox per viewer.

The loop steps its `Session` on a worker thread with the wall-clock time since the last step
(and, when the server records, appends what the step journaled to the session's log; when it
publishes on LSL, `serve --lsl-outlet`, pushes it to the session's outlets), then
hands the frame to every viewer's mailbox. A mailbox holds one frame: a viewer that reads
slowly skips frames (counted as dropped) instead of growing a queue, and because each viewer
sends from its own task, one stuck socket never delays another viewer or session.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import logging
import secrets
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

from gazehdr import heap
from gazehdr.drivers.errors import GazehdrError, InputError
from gazehdr.drivers.sessionlog import SessionLogWriter
from gazehdr.gaze import REMOTE_PREFIX, GazeReading, TrackerFeed, Trackers
from gazehdr.metrics import Metrics
from gazehdr.protocol import Control, Encoding, ProtocolError
from gazehdr.recordings import RecordingLibrary
from gazehdr.scenes.library import SceneLibrary
from gazehdr.session import Frame, Note, Session, SessionSettings
from gazehdr.transport import StreamViewers

log = logging.getLogger("gazehdr.live")
MAX_NOTES = 64  # JSON notes waiting for one viewer; beyond this the oldest go
MAX_PENDING_CONTROLS = 256  # per session between two frames; more is a flood
WINDOW = 2  # frames in flight to a viewer that acks: one being drawn, one on the way
MAX_IDLE_S = 0.5  # a session steps at least this often, even when no viewer takes frames
DEMAND_POLL_S = 0.002
#: Ours: how far a new gaze pulls the next step forward, in intervals (`step_start`). Half: a
#: gaze that just missed a step's late read waits for that step's compose, then at most half
#: an interval; pulled further, two steps could start back to back on a fast machine.
GAZE_PULL = 0.5
MAX_VIEWERS = 16  # per session (`SessionHub.max_viewers`): each costs a sending task and frames


class TooManySessionsError(GazehdrError):
    """The server runs as many sessions as it is allowed to (or a session has as many viewers
    as it may); the message is the WebSocket close reason, at most 123 bytes."""


_malloc_trim = heap.trimmer()
#: The threads that step sessions (one step per session at a time).
_STEPPER = concurrent.futures.ThreadPoolExecutor(thread_name_prefix="gazehdr-step")


@dataclass
class Mailbox:
    """The newest frame and the notes (never dropped, but bounded) for one viewer."""

    frame: Frame | None = None
    notes: list[Note] = field(default_factory=list)
    dropped: int = 0
    closed: bool = False  # the session ended: send what is left, then stop
    ready: asyncio.Event = field(default_factory=asyncio.Event)

    def put(self, frame: Frame | None, notes: list[Note] = ()) -> int:
        """Store; returns how many unsent frames this replaced (0 or 1)."""
        replaced = 0
        if frame is not None:
            replaced = int(self.frame is not None)
            self.dropped += replaced
            self.frame = frame
        self.notes = [*self.notes, *notes][-MAX_NOTES:]
        self.ready.set()
        return replaced

    async def take(self) -> tuple[Frame | None, list[Note]]:
        await self.ready.wait()
        self.ready.clear()
        frame, notes = self.frame, self.notes
        self.frame, self.notes = None, []
        return frame, notes


class Viewer:
    """One connected browser: sends what lands in its mailbox, in order, from its own task."""

    def __init__(
        self,
        send_bytes: Callable[[bytes], Awaitable[None]],
        send_json: Callable[[dict[str, Any]], Awaitable[None]],
        metrics: Metrics,
    ) -> None:
        self.mailbox = Mailbox()
        self._send_bytes, self._send_json, self._metrics = send_bytes, send_json, metrics
        # Flow control, on once the viewer acks: at most WINDOW frames sent and not yet taken,
        # so frames never wait in socket buffers either, and the newest one goes next.
        self.window: int | None = None
        self.sent = self.acks = 0
        self._credit = asyncio.Event()
        self.maps = False  # whether it asked for scene maps (binary notes)
        self.warp = False  # whether it asked for late-warp frames (gazehdr.warp)
        #: Its task waits on the mailbox with credit: a frame put now is on its way at once.
        self.taking = False
        #: The encoding it asked for (None: the session's); for a stream (`h264`, `av1`),
        #: whether it has every packet since its last keyframe, so the next delta packet is of
        #: use to it.
        self.encoding: Encoding | None = None
        self.keyed = False
        # The newest tracker gaze for the warp not yet sent (`forward_gaze`): one slot, sent by
        # a task of its own, so it never waits for credit or behind a frame in the mailbox.
        self._gaze: dict[str, Any] | None = None
        self._gaze_ready = asyncio.Event()

    def want_maps(self, send: bool, latest: bytes | None) -> None:
        """Scene maps on or off; on, the latest one comes at once (the page has none yet)."""
        self.maps = send
        if send and latest is not None:
            self.mailbox.put(None, [latest])

    def forward_gaze(self, note: dict[str, Any] | None) -> None:
        """Send `note` (a `gaze` note) next, in place of any not yet sent; None: drop that one."""
        self._gaze = note
        if note is not None:
            self._gaze_ready.set()

    async def pump_gaze(self) -> None:
        """Send the forwarded gaze as it comes, only ever the newest: beside `pump`, not after
        it, so a frame waiting for its ack never holds the gaze back."""
        while True:
            await self._gaze_ready.wait()
            self._gaze_ready.clear()
            note, self._gaze = self._gaze, None
            if note is not None:
                await self._send_json(note)
                self._metrics.gaze_forwarded.inc()

    def ack(self) -> None:
        self.acks = min(self.acks + 1, self.sent)
        self.window = WINDOW
        self._credit.set()

    def has_credit(self) -> bool:
        return self.window is None or self.sent - self.acks < self.window

    def wants_frame(self) -> bool:
        """Whether a frame made from now on would be sent rather than replace one still waiting
        or wait for credit: the frame in the mailbox counts as sent when this viewer's task is
        already waiting to take it (the next step then overlaps its sending)."""
        queued = self.mailbox.frame is not None
        if queued and not self.taking:
            return False
        return self.window is None or self.sent + queued - self.acks < self.window

    async def _wait_for_credit(self) -> None:
        while self.window is not None and self.sent - self.acks >= self.window:
            self._credit.clear()
            await self._credit.wait()

    async def pump(self) -> None:
        m = self._metrics
        while True:
            await self._wait_for_credit()
            self.taking = True
            try:
                frame, notes = await self.mailbox.take()
            finally:
                self.taking = False
            for note in notes:  # a scene map is binary, the rest JSON
                if not isinstance(note, bytes):
                    await self._send_json(note)
                elif self.maps:
                    await self._send_bytes(note)
            if self.mailbox.closed:
                return
            if frame is None:
                continue
            started = time.monotonic()
            message = frame.message(self.mailbox.dropped, self.warp)
            if message is None:  # made before this viewer switched warp: the next one fits
                continue
            await self._send_bytes(message)
            self.sent += 1
            sent = time.monotonic()
            m.send_seconds.observe(sent - started)
            m.frames_sent.inc()
            m.bytes_sent.inc(len(message))
            if frame.gaze_received_at is not None:
                m.gaze_latency.observe(sent - frame.gaze_received_at)


def next_due(due: float, interval: float, now: float) -> float:
    """When the step after one due at `due` is due: on a fixed cadence of `interval`, as a
    renderer paces to a display's refresh, so that a late step is made up by the next starting
    at once and the frame rate holds its setting on average whenever the machine keeps up on
    average (paced from each step's start instead, every late step lowered the rate: 54-56
    fps delivered at a setting of 60 with steps of 12-15 ms, bench-live at 1280x720). Never
    more than one interval behind `now`: a slow spell is not made up by a burst after it."""
    return max(due + interval, now - interval)


def step_start(due: float, interval: float, gaze_at: float | None) -> float:
    """When the step due at `due` starts: then, or, for a gaze that came since the last step
    read one (`gaze_at`), at once, but never more than GAZE_PULL intervals early. A gaze then
    waits for the step in progress and the next, never for the cadence (720p at 60 fps: it
    waited for a step due up to a whole interval later), while the cadence, and so the rate,
    stays the setting's: the step after one pulled forward is due when it would have been."""
    if gaze_at is None:
        return due
    return max(min(gaze_at, due), due - GAZE_PULL * interval)


def gaze_note(reading: GazeReading) -> dict[str, Any]:
    """A tracker's gaze as forwarded to a viewer that warps (docs/protocol.md `gaze`): frame
    fractions, and `t`, when it reached the server (monotonic s: only differences count)."""
    t = reading.received_at
    return {"type": "gaze", "x": reading.x, "y": reading.y, "t": t, "eyes_open": reading.eyes_open}


class LiveSession:
    """A `Session` stepped at real time for its viewers. Its journal goes to `log` (a file) and
    to `outlet` (anything with `push_all(records)` and `close()`: LSL streams), where given."""

    def __init__(
        self,
        session: Session,
        metrics: Metrics,
        log: SessionLogWriter | None = None,
        outlet: Any = None,
    ) -> None:
        self.session = session
        self.viewers: set[Viewer] = set()
        self.controls: list[tuple[Control, float]] = []
        self.metrics = metrics
        self.task: asyncio.Task[None] | None = None
        self.closing: asyncio.TimerHandle | None = None
        self.log = log
        self.outlet = outlet
        #: The streams (`h264`, `av1`) its viewers chose, each encoded once a frame for them all.
        self.streams = StreamViewers(session.settings.encoding, session.settings.fps, metrics)
        #: The last scene map sent to the viewers that inspect (a viewer that starts to gets it).
        self.scene_map: bytes | None = None
        # A step may still be writing on its thread when the session ends and the log closes.
        self._log_lock = threading.Lock()
        #: Set on the event loop by each new pointer or tracker gaze (the loop's wait, `_run`).
        self._gaze_came = asyncio.Event()

    def _tick(
        self,
        dt: float,
        controls: list[tuple[Control, float]],
        maps: bool = False,
        warp: tuple[bool, bool] = (True, False),
    ) -> tuple[Frame, list[Note]]:
        """One step, on the worker thread, with what it journaled published and appended to the
        log; `maps`: a viewer inspects, `warp`: whether viewers want (plain frames, late-warp
        layers) (both decided on the event loop, which owns the viewers). A
        log that cannot be written stops recording, not the session; the viewers are told."""
        plain, warp_layers = warp
        frame, notes = self.session.tick(dt, controls, plain=plain, warp=warp_layers)
        if maps:  # made only for viewers that inspect
            scene_map = self.session.scene_map()
            if scene_map is not self.scene_map:
                self.scene_map = scene_map
                notes.append(scene_map)
        records = self.session.take_journal()
        with self._log_lock:
            if self.outlet is not None:
                self.outlet.push_all(records)
            if self.log is None:
                return frame, notes
            try:
                self.log.write_all(records)
            except OSError as e:
                log.error("session %s: recording stopped: %s", self.session.id, e)
                notes.append({"type": "error", "message": f"recording stopped: {e}", "in": None})
                self._close_log()
        return frame, notes

    def close_log(self) -> None:
        """End the session's log and outlet with its last records (`Session.end_journal`)."""
        with self._log_lock:
            if self.log is None and self.outlet is None:
                return
            records = self.session.end_journal()
            if self.outlet is not None:
                self.outlet.push_all(records)
                self.outlet.close()
                self.outlet = None
            if self.log is None:
                return
            try:
                self.log.write_all(records)
            except OSError as e:
                log.error("session %s: recording its end: %s", self.session.id, e)
            self._close_log()

    def _close_log(self) -> None:
        if self.log is None:
            return
        try:
            self.log.close()
        except OSError as e:
            log.error("session %s: closing its log: %s", self.session.id, e)
        self.log = None

    def submit(self, control: Control) -> None:
        """Queue `control` for the next step; the pointer and the eyes go straight to the
        session's pointer, never waiting behind other controls (each step reads the newest)."""
        now = time.monotonic()
        if self.session.pointer.take(control, now):
            self._gaze_came.set()
            return
        if len(self.controls) >= MAX_PENDING_CONTROLS:
            raise ProtocolError("too many messages; slow down", control.__class__.__name__)
        self.controls.append((control, now))

    def broadcast(self, note: dict[str, Any]) -> None:
        for viewer in self.viewers:
            viewer.mailbox.put(None, [note])

    def set_warp(self, viewer: Viewer, on: bool) -> None:
        """The late gaze warp on or off for `viewer` (a ProtocolError where it cannot be); on,
        with a tracker as the gaze, the newest gaze that tracker sent goes to it at once."""
        self.streams.warp(viewer, on)
        feed = self.tracker() if on else None
        if feed is None or feed.reading.received_at is None:  # off, or nothing heard of it yet
            viewer.forward_gaze(None)
        else:
            viewer.forward_gaze(gaze_note(feed.reading))

    def tracker(self) -> TrackerFeed | None:
        """The tracker the session follows now, if it follows one."""
        source = self.session.gaze_source  # swapped whole by the step's thread
        if not source.startswith(REMOTE_PREFIX):
            return None
        return self.session.trackers.feed(source.removeprefix(REMOTE_PREFIX))

    def forward_gaze(self, feed: TrackerFeed) -> None:
        """`feed` has a new reading: it may start the next step early (`step_start`), and goes
        to the viewers that warp, if the session follows it (they place the afterimages at it
        until the next frame, docs/protocol.md `gaze`)."""
        if self.session.gaze_source != REMOTE_PREFIX + feed.name:
            return
        self._gaze_came.set()
        warping = [v for v in self.viewers if v.warp]
        if not warping:
            return
        note = gaze_note(feed.reading)
        for viewer in warping:
            viewer.forward_gaze(note)

    async def _demand(self, patience: float) -> None:
        """Wait (up to `patience` s) until some viewer would take a new frame: frames nobody
        can take yet cost CPU that a browser on the same machine, or a stream's encoder, needs
        (`StreamViewers.wants_frame`). The eye still advances by the real elapsed time at the
        next step."""
        deadline = time.monotonic() + patience
        wants = self.streams.wants_frame
        while not any(wants(v) for v in self.viewers) and time.monotonic() < deadline:
            await asyncio.sleep(DEMAND_POLL_S)

    async def run(self) -> None:
        """Step, publish, step again. Once a step is done the next one starts before anything
        else runs on the event loop (no await between): the viewers' tasks send its frame while
        the next is simulated, and that step reads the gaze (`Session.pointer`, a tracker) when
        it starts, on its thread. Streams are encoded on a thread of their own meanwhile."""
        try:
            await self._run()
        finally:
            self.streams.close()

    async def _run(self) -> None:
        interval = 1.0 / self.session.settings.fps
        last: float | None = None
        due: float | None = None  # when this step was due (pacing, next_due)
        m = self.metrics
        while True:
            await self._demand(MAX_IDLE_S)
            started = time.monotonic()
            dt = 0.0 if last is None else started - last
            last = started
            due = started if due is None else due
            controls, self.controls = self.controls, []
            maps = any(v.maps for v in self.viewers)
            warp = (any(not v.warp for v in self.viewers), any(v.warp for v in self.viewers))
            # The step's own future, awaited directly: the task resumes at the loop's next turn
            # after the step ends (each extra hop, a task or a shield, costs a turn, and with
            # the GIL shared every turn can wait for another thread).
            work = _STEPPER.submit(self._tick, dt, controls, maps, warp)
            try:
                frame, notes = await asyncio.wrap_future(work)
            except asyncio.CancelledError:
                # The session ends: its step finishes on its thread before the task does, so
                # nothing of the session is in use once the task is done (`SessionHub._end`).
                await asyncio.wait([asyncio.wrap_future(work)])
                raise
            except Exception as e:  # a broken device or kernel: tell the viewers, then stop
                log.exception("session %s stopped", self.session.id)
                note = {"type": "error", "message": f"simulation failed: {e}", "in": None}
                for viewer in self.viewers:
                    viewer.mailbox.put(None, [note])
                    viewer.mailbox.closed = True
                self.close_log()
                return
            m.sim_seconds.observe(frame.sim_seconds)
            m.encode_seconds.observe(frame.encode_seconds)
            self.streams.publish(frame, self.viewers)
            for viewer in self.viewers:
                if self.streams.takes(viewer):  # its frame comes once encoded; the notes now
                    viewer.mailbox.put(None, notes)
                    continue
                # A viewer out of credit gets the next frame made once it acks, not this one.
                taken = frame if viewer.has_credit() else None
                m.frames_dropped.inc(viewer.mailbox.put(taken, notes) + (taken is None))
            # Sleep until the next step is due, or sooner for a new gaze (`step_start`): the
            # sockets are served while the next step runs.
            due = next_due(due, interval, time.monotonic())
            await self._until_start(due, interval)

    async def _until_start(self, due: float, interval: float) -> None:
        """Sleep until the step due at `due` starts (`step_start`), woken by a new gaze; once
        one has come, later ones cannot start it sooner (a tracker sends hundreds a second)."""
        while (wait := step_start(due, interval, came := self.session.newer_gaze_at())) > (
            now := time.monotonic()
        ):
            if came is not None:
                await asyncio.sleep(wait - now)
                return
            self._gaze_came.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait - now):
                    await self._gaze_came.wait()


class SessionHub:
    """All live sessions of a server, by id, and the gaze daemons' trackers they may follow."""

    def __init__(
        self,
        settings: SessionSettings,
        scenes: SceneLibrary,
        metrics: Metrics,
        recordings: RecordingLibrary | None = None,
        *,
        grace_s: float = 10.0,
        max_sessions: int = 8,
        max_viewers: int = MAX_VIEWERS,
        publish: Callable[[Session], Any] | None = None,
    ) -> None:
        self.settings = settings
        # `publish` makes a session's outlets; a session that publishes keeps a journal even
        # when the server does not record. Others keep none: they pay nothing.
        self.publish = publish
        self.scenes = scenes
        self.recordings = recordings or RecordingLibrary(None)
        self.metrics = metrics
        self.trackers = Trackers()
        self.trackers.listen(self._tracker_moved)
        self.sessions: dict[str, LiveSession] = {}
        self.grace_s = grace_s
        self.max_sessions = max_sessions
        self.max_viewers = max_viewers
        self.starting = 0  # sessions being built: their slots are taken (`join`)
        if settings.record and self.recordings.folder is None:
            raise InputError("recording sessions needs a data directory")

    async def join(self, session_id: str | None, viewer: Viewer) -> LiveSession:
        """The session `session_id` if it still runs, else a new one; `viewer` is added.

        Limits are checked and taken in one go, with no await between (the event loop runs
        one coroutine at a time): a new session's slot is reserved before it is built on a
        worker thread and given back if building fails, so many viewers arriving at once
        never open more than `max_sessions`."""
        live = self.sessions.get(session_id or "")
        if live is not None:
            if len(live.viewers) >= self.max_viewers:
                raise TooManySessionsError(
                    f"server busy: session {live.session.id} has {self.max_viewers} viewers "
                    "(the limit); try again later"
                )
        else:
            if len(self.sessions) + self.starting >= self.max_sessions:
                raise TooManySessionsError(
                    f"server busy: it runs {self.max_sessions} sessions (the limit); "
                    "try again later or join one with ?session=ID"
                )
            self.starting += 1  # the slot is ours from here on
            try:
                live = await self._start()
            finally:
                self.starting -= 1
            self.sessions[live.session.id] = live
        if live.closing:
            live.closing.cancel()
            live.closing = None
        live.viewers.add(viewer)
        self._count()
        return live

    async def _start(self) -> LiveSession:
        new_id = secrets.token_urlsafe(9)
        settings = self.settings
        if self.publish is not None:
            settings = dataclasses.replace(settings, record=True)
        session = await asyncio.to_thread(
            Session, new_id, settings, self.scenes, clock=time.perf_counter,
            trackers=self.trackers, recordings=self.recordings,
        )  # fmt: skip
        recording = await asyncio.to_thread(self._record, session) if self.settings.record else None
        outlet = self.publish(session) if self.publish is not None else None
        live = LiveSession(session, self.metrics, recording, outlet)
        live.task = asyncio.create_task(live.run(), name=f"session {new_id}")
        live.task.add_done_callback(lambda _: self._ended(live))
        return live

    def _record(self, session: Session) -> SessionLogWriter:
        """The session's log in the recordings, so a viewer can replay it (`replay:NAME`)."""
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        return self.recordings.create(f"session-{stamp}-{session.id}", session.log_header())

    def leave(self, live: LiveSession, viewer: Viewer) -> None:
        live.viewers.discard(viewer)
        if not live.viewers and live.closing is None:
            loop = asyncio.get_running_loop()
            live.closing = loop.call_later(self.grace_s, self._end, live)
        self._count()

    def broadcast(self, note: dict[str, Any]) -> None:
        for live in self.sessions.values():
            live.broadcast(note)

    def _tracker_moved(self, feed: TrackerFeed) -> None:
        for live in self.sessions.values():
            live.forward_gaze(feed)

    async def close(self) -> None:
        """Stop every session (server shutdown), whether or not viewers remain."""
        lives, self.sessions = list(self.sessions.values()), {}
        for live in lives:
            if live.closing:
                live.closing.cancel()
            if live.task:
                live.task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await live.task
            live.close_log()
        self._count()

    def _end(self, live: LiveSession) -> None:
        live.closing = None  # a fired handle keeps its arguments: no cycle through it
        if live.viewers:
            return
        if live.task:
            live.task.cancel()
        live.close_log()
        self.sessions.pop(live.session.id, None)
        self._count()

    def _ended(self, live: LiveSession) -> None:
        """A session's task is done (ended, failed, or the server stops). Nothing may keep the
        session from being freed at once by reference counting: its device buffers, frames and
        scene go back now, not at some later garbage collection. The task (its exception's
        traceback holds the task's frames, and so the session) is dropped by the session, and
        the C heap is trimmed once the task is gone (`gazehdr.heap`)."""
        live.task = None
        if _malloc_trim is not None:
            loop = asyncio.get_running_loop()
            loop.call_soon(lambda: loop.run_in_executor(None, _malloc_trim))

    def _count(self) -> None:
        self.metrics.sessions.set(len(self.sessions))
        self.metrics.viewers.set(sum(len(s.viewers) for s in self.sessions.values()))
