"""`gazehdr daemon`: stream a gaze source to a gazehdr server's `/ws/gaze`, losing nothing quietly.

The source runs in a thread (tracker reads and real-time pacing block); everything else runs on
one asyncio loop:

- every sample goes first to the local session log (`record=`, or a new timestamped file in
  `record_dir=`), then through the fixation detector, and samples and events join the send
  buffer in the order they were emitted;
- the server follows fixation events, so each one sent carries a position. A replayed
  recording whose fixation starts carry none (EyeLink `SFIX`, BIDS onsets) says where each
  fixation is (`fixation_places()`, the places `SessionLog.fixation_track` holds): its events
  are sent with those positions, and recorded as they were. A source whose events cannot place a
  single fixation (BIDS physioevents without positions, or only blinks) is run through the
  detector instead, as `fixation_track` runs I-VT over a log without fixations; its own events
  are then recorded, not sent;
- the send buffer is bounded (`buffer` items). While the server is unreachable a live source
  keeps producing: when the buffer is full its oldest never-sent item is dropped, counted,
  logged, and noted in the session log. A source that is not live (a replay) is made to wait
  instead, and loses nothing;
- sending is paced by a token bucket below the server's limit (1900 samples/s, burst 1000,
  against the server's 2000/s, burst 4000), in batches of at most `batch` samples every
  `flush_interval` seconds (sooner when a batch is full or an event is waiting);
- delivery is acknowledged by the clock echo: the server handles one connection's messages in
  order, so its reply to an `echo` sent after a batch proves the batch was handled. Items sent
  but not yet acknowledged when a connection dies are sent again on the next one (at least
  once: a sample may arrive twice across a reconnect, never not at all unless counted dropped);
- the same echoes estimate the clock offset to the server: offset = server_ns − (t0 + t1)/2 with
  uncertainty RTT/2, keeping the estimate with the smallest RTT among the last `clock_window`
  echoes of the current connection (a reconnect may reach a restarted or rebooted server,
  whose monotonic clock is another); it is reported in `stats` and written to the session log
  as `clock` records;
- a lost connection is retried with exponential back-off (`backoff`); a refused token (close
  code 4401) is fatal: `UnauthorizedError`, no retry.

`run_daemon(source, server_url, token, ...)` runs until the source ends (and the buffer is
delivered, or `drain_timeout` passes) or `Daemon.stop()` is called. `daemon_main(argv)` is the
command line; SIGTERM and Ctrl-C stop it the same way, with its summary. Nothing here imports
`server` or pyopencl.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import os
import random
import re
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from gazehdr.drivers import wire
from gazehdr.drivers.cli_args import positive_arg, screen_size_arg
from gazehdr.drivers.fixations import DETECTORS, make_detector
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import EVENT_KINDS, ClockInfo, SessionHeader, SessionLogWriter
from gazehdr.drivers.sources import (
    SourceInfo,
    SourceUnavailableError,
    fixation_places_of,
    open_source,
    records_of,
)

log = logging.getLogger("gazehdr.daemon")

CLOSE_UNAUTHORIZED = 4401
SERVER_RATE_HZ = 2000.0  # the server's sustained limit per connection (gazehdr.app.GAZE_RATE_HZ)
DEFAULT_RATE_HZ = 1900.0  # what the daemon sends at most: below the limit, with margin
DEFAULT_BURST = 1000.0  # below the server's burst of 4000
DEFAULT_BUFFER = 20_000  # items (samples and events): 10 s of a 2000 Hz tracker
DEFAULT_MAX_INFLIGHT = 2000  # items sent, not yet acknowledged: 1 s at the server's limit
#: After SIGTERM or Ctrl-C, how long the buffer may still drain: well inside the 10 s that
#: `docker stop` waits before SIGKILL, so the summary is printed and the log closed.
SIGNAL_DRAIN_S = 3.0
RECORD_DIR_ENV = "GAZEHDR_RECORD_DIR"
_RATE_NOTE = re.compile(r"rate limit: (\d+) (samples|events|echoes) dropped")
_WIRE_TIMES = range(
    2**63
)  # what a wire `t` may be (gazehdr.drivers.wire._int); the server refuses others


class DaemonError(RuntimeError):
    """The daemon cannot go on; the text says why."""


class UnauthorizedError(DaemonError):
    """The server refused the bearer token (close code 4401)."""


# --- clock offset ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockEstimate:
    """server clock ≈ daemon clock + `offset_ns`, give or take `uncertainty_ns` (= RTT/2)."""

    offset_ns: int
    uncertainty_ns: int
    rtt_ns: int
    at_ns: int  # daemon clock when the echo came back


class ClockEstimator:
    """Round-trip echo estimates; the best is the smallest RTT among the last `window`."""

    def __init__(self, window: int = 32) -> None:
        self.window: deque[ClockEstimate] = deque(maxlen=window)

    def add(self, t0_ns: int, server_ns: int, t1_ns: int) -> ClockEstimate | None:
        rtt = t1_ns - t0_ns
        if rtt < 0:
            return None
        offset = server_ns - (t0_ns + t1_ns) // 2
        self.window.append(ClockEstimate(offset, (rtt + 1) // 2, rtt, t1_ns))
        return self.best

    @property
    def best(self) -> ClockEstimate | None:
        return min(self.window, key=lambda e: e.rtt_ns) if self.window else None


# --- statistics ------------------------------------------------------------------------------


@dataclass
class DaemonStats:
    samples_produced: int = 0  # from the source
    events_produced: int = 0  # from the detector (or the replayed log)
    samples_recorded: int = 0  # written to the local session log
    events_recorded: int = 0
    samples_sent: int = 0  # messages handed to the socket, resends included
    samples_delivered: int = 0  # acknowledged by the server
    events_delivered: int = 0
    samples_dropped: int = 0  # buffer full while disconnected (a live source)
    events_dropped: int = 0
    samples_undelivered: int = 0  # still buffered when the daemon gave up draining
    events_undelivered: int = 0
    resent: int = 0  # items sent again after a connection died unacknowledged
    samples_unsendable: int = 0  # times the wire cannot carry (negative: some imports)
    events_unsendable: int = 0  # the same, or fixation events without a position
    #: what the server said its rate limits dropped, by kind (samples, events, echoes): the
    #: daemon paces itself below them, so this should stay empty
    server_rate_limited: dict[str, int] = field(default_factory=dict)
    connects: int = 0
    disconnects: int = 0
    clock: ClockEstimate | None = None
    last_error: str | None = None
    source_error: str | None = None
    record_path: Path | None = None  # the local session log, when one is written
    sent_times: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=4096))

    def summary(self) -> str:
        clock = (
            f"clock offset {self.clock.offset_ns / 1e6:+.3f} ms "
            f"± {self.clock.uncertainty_ns / 1e3:.0f} µs"
            if self.clock
            else "clock offset unknown"
        )
        return (
            f"{self.samples_produced} samples, {self.events_produced} events from the source; "
            f"delivered {self.samples_delivered} samples, {self.events_delivered} events; "
            f"dropped {self.samples_dropped} samples, {self.events_dropped} events "
            f"(buffer full){self._undelivered()}{self._unsendable()}; "
            f"{self.connects} connection(s); {clock}{self._limited()}{self._recorded()}"
        )

    def _limited(self) -> str:
        if not self.server_rate_limited:
            return ""
        dropped = ", ".join(f"{n} {kind}" for kind, n in sorted(self.server_rate_limited.items()))
        return f"; the server's rate limits dropped {dropped}"

    def _recorded(self) -> str:
        if self.record_path is None:
            return ""
        return (
            f"; recorded {self.samples_recorded} samples, {self.events_recorded} events "
            f"to {self.record_path}"
        )

    def _unsendable(self) -> str:
        if not (self.samples_unsendable or self.events_unsendable):
            return ""
        return (
            f"; {self.samples_unsendable} samples, {self.events_unsendable} events not sendable "
            "(recorded only)"
        )

    def _undelivered(self) -> str:
        if not (self.samples_undelivered or self.events_undelivered):
            return ""
        return (
            f"; {self.samples_undelivered} samples, {self.events_undelivered} events "
            "never delivered"
        )


# --- helpers ---------------------------------------------------------------------------------


def gaze_url(server: str) -> str:
    """`ws://HOST:PORT` (or http://, or a bare HOST:PORT) → the `/ws/gaze` endpoint's URL."""
    text = server.strip()
    if "://" not in text:
        text = "ws://" + text
    parts = urlsplit(text)
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None or not parts.netloc:
        raise ValueError(f"server {server!r}: expected ws://HOST:PORT")
    path = parts.path if parts.path not in ("", "/") else "/ws/gaze"
    return urlunsplit((scheme, parts.netloc, path, parts.query, ""))


def _is_event(item: Any) -> bool:
    return getattr(item, "kind", None) in EVENT_KINDS


def _fraction(value: float, size: int) -> float:
    return min(4.0, max(-3.0, value / size))


def _to_wire(
    item: Any, info: SourceInfo, places: Mapping[tuple[int, str | None], Any]
) -> wire.Sample | wire.Event | None:
    """The wire form of a sample or event, or None where the server would refuse it: a message
    it refuses is still acknowledged by the next echo, so it must never be sent. A fixation
    event without a position takes its fixation's from `places` (see `fixation_places_of`)."""
    w, h = info.geometry.screen_width_px, info.geometry.screen_height_px
    if int(item.t_ns) not in _WIRE_TIMES:
        return None
    if isinstance(item, GazeSample):
        if item.valid:
            return wire.Sample(int(item.t_ns), _fraction(item.x, w), _fraction(item.y, h), True)
        return wire.Sample(int(item.t_ns), math.nan, math.nan, False)
    if item.kind.startswith("fixation"):
        x, y = item.x, item.y
        if not (math.isfinite(x) and math.isfinite(y)):
            place = places.get((item.id, getattr(item, "eye", None)))
            if place is None:
                return None
            x, y = place.x, place.y
        return wire.Event(item.kind, int(item.id), int(item.t_ns), _fraction(x, w), _fraction(y, h))
    return wire.Event(item.kind, int(item.id), int(item.t_ns), math.nan, math.nan)


def open_record_dir(
    directory: str | Path, header: SessionHeader, now: datetime | None = None
) -> SessionLogWriter:
    """A new session log in `directory` (made if missing), `gaze-YYYYmmddTHHMMSSZ.jsonl` at
    `now` (UTC), `-2`, `-3`, ... after the stamp where that exists: a daemon restarted within
    the same second, or two sharing the directory. Never an existing file (the writer creates
    exclusively, so even a race cannot overwrite)."""
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    stamp = (now or datetime.now(timezone.utc)).astimezone(timezone.utc)
    name = f"gaze-{stamp:%Y%m%dT%H%M%SZ}"
    path, n = folder / f"{name}.jsonl", 1
    while True:
        try:
            return SessionLogWriter(path, header)
        except FileExistsError:
            n += 1
            path = folder / f"{name}-{n}.jsonl"


class _ClosedError(Exception):
    """The connection ended; `code` and `reason` say how."""

    def __init__(self, code: int | None, reason: str) -> None:
        super().__init__(f"connection closed ({code}: {reason})" if code else "connection lost")
        self.code, self.reason = code, reason


# --- the daemon ------------------------------------------------------------------------------


class Daemon:
    """One source, one server. `await run()`; `stop()` (on the loop) ends it cleanly."""

    def __init__(
        self,
        source: Any,
        server_url: str,
        token: str,
        *,
        record: str | Path | None = None,
        record_dir: str | Path | None = None,
        overwrite: bool = False,
        detector: str | None = "ivt",
        buffer: int = DEFAULT_BUFFER,
        batch: int = 50,
        flush_interval: float = 0.02,
        max_rate: float = DEFAULT_RATE_HZ,
        burst: float = DEFAULT_BURST,
        max_inflight: int = DEFAULT_MAX_INFLIGHT,
        backoff: tuple[float, float] = (0.1, 5.0),
        drain_timeout: float = 10.0,
        welcome_timeout: float = 5.0,
        echo_interval: float = 1.0,
        clock_window: int = 32,
        status_interval: float | None = None,
    ) -> None:
        if buffer < 1 or batch < 1 or max_inflight < batch:
            raise ValueError("buffer and batch must be positive, max_inflight at least batch")
        if max_rate > SERVER_RATE_HZ:
            raise ValueError(f"max_rate {max_rate} is over the server's {SERVER_RATE_HZ:g}/s")
        if detector is not None and detector not in DETECTORS:
            raise ValueError(f"unknown detector {detector!r}; known: {', '.join(DETECTORS)}")
        if record is not None and record_dir is not None:
            raise ValueError(
                "record (one file) and record_dir (a new file per run) exclude each other"
            )
        self.source = source
        self.info: SourceInfo = source.info
        self.url = gaze_url(server_url)
        self.token = token
        self.record_path = Path(record) if record is not None else None
        self.record_dir = Path(record_dir) if record_dir is not None else None
        self.overwrite = overwrite
        self.buffer, self.batch, self.flush_interval = buffer, batch, flush_interval
        self.max_rate, self.burst, self.max_inflight = max_rate, burst, max_inflight
        self.backoff, self.drain_timeout = backoff, drain_timeout
        self.welcome_timeout, self.echo_interval = welcome_timeout, echo_interval
        self.status_interval = status_interval
        self.stats = DaemonStats()
        self.clock = ClockEstimator(clock_window)
        # The source's own events (a replayed log) pass through when they place its fixations;
        # otherwise the detector runs (see the module docstring).
        places = fixation_places_of(source) if self.info.has_events else None
        self._places = places or {}
        self._sends_own_events = self.info.has_events and (places is None or bool(places))
        self._eye: str | None = None  # the eye whose fixations are sent (see _follows)
        self._eye_chosen = False
        self.detector = (
            make_detector(detector, self.info.geometry)
            if detector is not None and not self._sends_own_events
            else None
        )
        self._unsent: deque[Any] = deque()
        self._retry: deque[Any] = deque()
        self._inflight: deque[tuple[int, Any]] = deque()
        self._marks: dict[int, int] = {}  # echo t0 -> last seq sent before it
        self._seq = 0
        self._pending_samples = 0
        self._handed = 0  # records the thread handed over (written by the thread only)
        self._ingested = 0  # records the loop took in (written by the loop only)
        self._stop_flag = threading.Event()
        self._accepting = True
        self._source_done_at: float | None = None
        self._writer: SessionLogWriter | None = None
        self._last_t = 0
        self._drop_note = [0, 0]  # samples, events dropped since the last note
        self._clock_written: tuple[float, ClockEstimate] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self.connected = False

    # --- source side (thread) ------------------------------------------------------------------

    def _produce(self) -> None:
        loop = self._loop
        assert loop is not None
        try:
            for record in records_of(self.source):
                if self._stop_flag.is_set():
                    break
                if not self.info.live:  # a replay waits for room instead of losing samples
                    while (
                        len(self._unsent) + self._handed - self._ingested >= self.buffer
                        and not self._stop_flag.is_set()
                    ):
                        time.sleep(0.002)
                self._handed += 1
                loop.call_soon_threadsafe(self._ingest, record)
        except Exception as e:  # a broken source ends the run; what it gave is delivered
            log.error("source failed: %s", e)
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._source_failed, f"{type(e).__name__}: {e}")
        finally:
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._end_of_source)

    def _source_failed(self, text: str) -> None:
        self.stats.source_error = text

    # --- intake (loop) -------------------------------------------------------------------------

    def _ingest(self, record: Any) -> None:
        self._ingested += 1
        if not self._accepting:
            return
        if isinstance(record, GazeSample):
            self.stats.samples_produced += 1
            self._last_t = max(self._last_t, record.t_ns)
            self._write(record)
            self._enqueue(record)
            if self.detector is not None:
                self._detected(self.detector.feed(record))
        elif _is_event(record) and self._sends_own_events and self._follows(record):
            self._event(record)
        else:  # scene, params, note, clock records of a replayed log, unused events: recorded
            self._write(record)

    def _follows(self, event: Any) -> bool:
        """Whether a recorded event is sent. Of a binocular recording's fixations, one eye's
        are: the first eye that fixates, as `SessionLog.fixation_track` follows (sending both
        would move the gaze between the eyes' slightly different places). Blinks all are."""
        if not event.kind.startswith("fixation"):
            return True
        eye = getattr(event, "eye", None)
        if not self._eye_chosen:
            self._eye, self._eye_chosen = eye, True
        return eye == self._eye

    def _event(self, event: Any, *, record: bool = True) -> None:
        self.stats.events_produced += 1
        if record:
            self._write(event)
        self._enqueue(event)

    def _detected(self, events: list[Any]) -> None:
        """The detector's events: sent, and recorded unless the source has events of its own
        (the log then keeps exactly the source's records; replaying it runs the detector
        again, to the same events)."""
        for event in events:
            self._event(event, record=not self.info.has_events)

    def _write(self, record: Any) -> None:
        if self._writer is None:
            return
        self._writer.write(record)
        if isinstance(record, GazeSample):
            self.stats.samples_recorded += 1
        elif _is_event(record):
            self.stats.events_recorded += 1

    def _enqueue(self, item: Any) -> None:
        sample = isinstance(item, GazeSample)
        if self.info.live and len(self._unsent) >= self.buffer:
            old = self._unsent.popleft()
            if isinstance(old, GazeSample):
                self._pending_samples -= 1
                self.stats.samples_dropped += 1
                self._drop_note[0] += 1
            else:
                self.stats.events_dropped += 1
                self._drop_note[1] += 1
            if sum(self._drop_note) == 1:
                log.warning("send buffer full (%d items): dropping the oldest", self.buffer)
        self._unsent.append(item)
        if sample:
            self._pending_samples += 1
        if not sample or self._pending_samples >= self.batch:
            self._wake_sender()

    def _end_of_source(self) -> None:
        if self._source_done_at is not None and not self._accepting:
            return
        if self.detector is not None and self._accepting:
            self._detected(self.detector.flush())
        self._accepting = False
        if self._source_done_at is None:
            self._source_done_at = time.monotonic()
        self._wake_sender()

    def stop(self, drain_timeout: float | None = None) -> None:
        """End the run: the source stops, what is buffered is delivered (up to `drain_timeout`
        from now, when given: less than the configured one, never more)."""
        self._stop_flag.set()
        if drain_timeout is not None:
            since = self._source_done_at or time.monotonic()
            limit = time.monotonic() - since + drain_timeout
            self.drain_timeout = min(self.drain_timeout, limit)
        if self._loop is not None:
            self._end_of_source()

    def stop_threadsafe(self) -> None:
        self._stop_flag.set()
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._end_of_source)

    def _wake_sender(self) -> None:
        if self._wake is not None:
            self._wake.set()

    def _note_drops(self, why: str) -> None:
        samples, events = self._drop_note
        if not (samples or events):
            return
        self._drop_note = [0, 0]
        text = (
            f"send buffer full ({self.buffer} items) {why}: "
            f"dropped {samples} samples, {events} events"
        )
        log.warning(text)
        if self._writer is not None:
            self._writer.note(self._last_t, text)

    @property
    def backlog(self) -> int:
        return len(self._unsent) + len(self._retry) + len(self._inflight)

    def _drained(self) -> bool:
        return self._source_done_at is not None and not self._accepting and self.backlog == 0

    # --- network side --------------------------------------------------------------------------

    async def run(self) -> DaemonStats:
        self._loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        header = SessionHeader(
            tracker=self.info.header_tracker(),
            screen=self.info.geometry,
            clock=ClockInfo("monotonic_ns" if self.info.live else "replayed"),
        )
        if self.record_path is not None:
            self._writer = SessionLogWriter(self.record_path, header, overwrite=self.overwrite)
        elif self.record_dir is not None:
            self._writer = open_record_dir(self.record_dir, header)
        if self._writer is not None:
            self.stats.record_path = self._writer.path
            log.info("recording to %s", self._writer.path)
        thread = threading.Thread(target=self._produce, name="gazehdr-source", daemon=True)
        thread.start()
        status = asyncio.create_task(self._status()) if self.status_interval else None
        try:
            await self._connect_loop()
        finally:
            self._stop_flag.set()
            self._accepting = False
            close = getattr(self.source, "close", None)
            if callable(close):  # a tracker's read loop ends, not left running in its thread
                close()
            if status is not None:
                status.cancel()
            self._give_up()
            self._note_drops("before the end")
            if self._writer is not None:
                self._writer.close()
        return self.stats

    def _give_up(self) -> None:
        for item in (*self._retry, *(i for _, i in self._inflight), *self._unsent):
            if isinstance(item, GazeSample):
                self.stats.samples_undelivered += 1
            else:
                self.stats.events_undelivered += 1
        self._retry.clear()
        self._inflight.clear()
        self._unsent.clear()
        self._pending_samples = 0
        if self.stats.samples_undelivered or self.stats.events_undelivered:
            log.warning(
                "gave up: %d samples and %d events were never delivered (they are in the "
                "local recording if one was asked for)",
                self.stats.samples_undelivered,
                self.stats.events_undelivered,
            )

    def _draining_too_long(self) -> bool:
        done = self._source_done_at
        return done is not None and time.monotonic() - done > self.drain_timeout

    async def _connect_loop(self) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

        delay = self.backoff[0]
        while not self._drained() and not self._draining_too_long():
            welcomed = False
            try:
                async with connect(
                    self.url,
                    additional_headers={"Authorization": f"Bearer {self.token}"},
                    proxy=None,
                    open_timeout=self.welcome_timeout,
                    close_timeout=1.0,
                    max_size=wire.MAX_MESSAGE_BYTES,
                    compression=None,
                ) as ws:
                    await self._hello(ws)
                    welcomed = True
                    delay = self.backoff[0]
                    await self._session(ws)
            except UnauthorizedError:
                raise
            except InvalidURI as e:
                raise DaemonError(f"server URL {self.url}: {e}") from None
            except (
                OSError,
                asyncio.TimeoutError,
                InvalidHandshake,
                ConnectionClosed,
                _ClosedError,
            ) as e:
                self.stats.last_error = str(e) or type(e).__name__
                if isinstance(e, _ClosedError) and e.code == CLOSE_UNAUTHORIZED:
                    raise UnauthorizedError(self._refused(e.reason)) from None
            finally:
                if welcomed:
                    self._connection_lost()
            if self._drained() or self._draining_too_long():
                break
            log.info(
                "server %s unreachable (%s); retrying in %.2g s",
                self.url,
                self.stats.last_error,
                delay,
            )
            await self._sleep_or_done(delay * random.uniform(0.9, 1.1))
            delay = min(delay * 2, self.backoff[1])

    async def _sleep_or_done(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not self._draining_too_long():
            await asyncio.sleep(min(0.05, max(0.0, deadline - time.monotonic())))

    def _refused(self, reason: str) -> str:
        return (
            f"the server at {self.url} refused the token ({reason or 'close code 4401'}); "
            "check --token or $GAZEHDR_TOKEN against the token 'gazehdr serve' printed"
        )

    async def _hello(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        screen = {k: float(v) for k, v in asdict(self.info.geometry).items()}
        try:
            await ws.send(wire.dumps(wire.Hello(wire.PROTOCOL, self.info.name, screen)))
            while True:
                text = await asyncio.wait_for(ws.recv(), self.welcome_timeout)
                reply = wire.parse_reply(text)
                if isinstance(reply, wire.Welcome):
                    break
                if isinstance(reply, wire.Notice):
                    raise DaemonError(f"the server refused hello: {reply.message}")
        except ConnectionClosed as e:
            raise self._closed(e) from None
        except wire.WireError as e:
            raise DaemonError(f"the server's reply to hello: {e}") from None
        self.stats.connects += 1
        self.connected = True
        self._marks.clear()
        self.clock = ClockEstimator(self.clock.window.maxlen or 1)  # maybe another server clock
        self._bucket = TokenBucket(self.max_rate, self.burst)
        self._last_echo = 0.0
        log.info("connected to %s as %r", self.url, self.info.name)
        self._note_drops("while disconnected")

    def _closed(self, e: Any) -> _ClosedError:
        rcvd = getattr(e, "rcvd", None)
        if rcvd is not None:
            return _ClosedError(rcvd.code, rcvd.reason)
        return _ClosedError(None, "")

    def _connection_lost(self) -> None:
        self.connected = False
        self.stats.disconnects += 1
        self._marks.clear()
        if self._inflight:
            self.stats.resent += len(self._inflight)
            self._retry.extendleft(item for _, item in reversed(self._inflight))
            self._inflight.clear()

    async def _session(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        assert self._wake is not None
        reader = asyncio.create_task(self._read(ws))
        try:
            while True:
                if reader.done():
                    reader.result()  # raises _ClosedError / DaemonError
                    raise _ClosedError(None, "")
                if self._drained():
                    await ws.close()
                    return
                if self._draining_too_long():
                    return
                self._wake.clear()
                limited = await self._send_round(ws)
                if limited:
                    await asyncio.sleep(self.flush_interval)
                else:
                    with contextlib.suppress(asyncio.TimeoutError):
                        await asyncio.wait_for(self._wake.wait(), self.flush_interval)
        except ConnectionClosed as e:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.shield(reader), 0.5)
            if reader.done() and not reader.cancelled() and reader.exception() is not None:
                raise reader.exception() from None
            raise self._closed(e) from None
        finally:
            reader.cancel()
            with contextlib.suppress(BaseException):
                await reader

    async def _read(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            async for text in ws:
                t1 = time.monotonic_ns()
                try:
                    reply = wire.parse_reply(text)
                except wire.WireError as e:
                    log.warning("ignoring a reply from the server: %s", e)
                    continue
                if isinstance(reply, wire.EchoReply):
                    self._echoed(reply, t1)
                elif isinstance(reply, wire.Notice):
                    m = _RATE_NOTE.search(reply.message)
                    if m:
                        limited = self.stats.server_rate_limited
                        limited[m.group(2)] = limited.get(m.group(2), 0) + int(m.group(1))
                    log.warning("server: %s", reply.message)
        except ConnectionClosed as e:
            raise self._closed(e) from None
        raise _ClosedError(ws.close_code, ws.close_reason or "")

    def _echoed(self, reply: wire.EchoReply, t1: int) -> None:
        best = self.clock.add(reply.t0_ns, reply.server_ns, t1)
        self.stats.clock = best
        if best is not None:
            self._write_clock(best)
        mark = self._marks.pop(reply.t0_ns, None)
        if mark is None:
            return
        for t0 in [t for t in self._marks if t < reply.t0_ns]:
            del self._marks[t0]
        while self._inflight and self._inflight[0][0] <= mark:
            _, item = self._inflight.popleft()
            if isinstance(item, GazeSample):
                self.stats.samples_delivered += 1
            else:
                self.stats.events_delivered += 1
        self._wake_sender()

    def _write_clock(self, best: ClockEstimate) -> None:
        if self._writer is None or not self.info.live:
            return
        now = time.monotonic()
        last = self._clock_written
        if last is not None and (last[1] == best or now - last[0] < 1.0):
            return
        self._clock_written = (now, best)
        self._writer.clock(time.monotonic_ns(), best.offset_ns, best.uncertainty_ns)

    def _next(self) -> deque[Any] | None:
        if self._retry:
            return self._retry
        if self._unsent:
            return self._unsent
        return None

    async def _send_round(self, ws: Any) -> bool:
        """Send what the bucket and the in-flight window allow; True when the bucket held it."""
        sent = False
        limited = False
        while (queue := self._next()) is not None:
            room = self.max_inflight - len(self._inflight)
            if room <= 0:
                break
            if isinstance(queue[0], GazeSample):
                tokens = self._bucket.available(time.monotonic())
                n = min(self.batch, room, tokens)
                if n <= 0:
                    limited = True
                    break
                items = []
                while queue and len(items) < n and isinstance(queue[0], GazeSample):
                    items.append(queue.popleft())
                if queue is self._unsent:
                    self._pending_samples -= len(items)
                wired = [(s, _to_wire(s, self.info, self._places)) for s in items]
                sendable = [(s, m) for s, m in wired if m is not None]
                self._count_unsendable(len(items) - len(sendable), 0)
                if not sendable:
                    continue
                self._bucket.take(len(sendable))
                self._track([s for s, _ in sendable])
                await ws.send(wire.dumps(wire.Samples(tuple(m for _, m in sendable))))
                self.stats.samples_sent += len(sendable)
                self.stats.sent_times.append((time.monotonic(), len(sendable)))
            else:
                item = queue.popleft()
                message = _to_wire(item, self.info, self._places)
                if message is None:
                    self._count_unsendable(0, 1)
                    continue
                self._track([item])
                await ws.send(wire.dumps(message))
            sent = True
        now = time.monotonic()
        if (
            sent
            or (self._inflight and now - self._last_echo > 0.1)
            or now - self._last_echo > self.echo_interval
        ):
            t0 = time.monotonic_ns()
            self._marks[t0] = self._seq
            self._last_echo = now
            await ws.send(wire.dumps(wire.Echo(t0)))
        return limited

    def _count_unsendable(self, samples: int, events: int) -> None:
        if not (samples or events):
            return
        if not (self.stats.samples_unsendable or self.stats.events_unsendable):
            log.warning(
                "not sending records the server would refuse (a negative time, or a fixation "
                "without a position); they are counted, and recorded if --record is given"
            )
        self.stats.samples_unsendable += samples
        self.stats.events_unsendable += events

    def _track(self, items: list[Any]) -> None:
        for item in items:
            self._seq += 1
            self._inflight.append((self._seq, item))

    async def _status(self) -> None:
        assert self.status_interval
        while True:
            await asyncio.sleep(self.status_interval)
            state = "connected" if self.connected else "disconnected"
            log.info("%s; %s; %d buffered", state, self.stats.summary(), self.backlog)


async def run_daemon(
    source: Any,
    server_url: str,
    token: str,
    *,
    record: str | Path | None = None,
    detector: str | None = "ivt",
    **options: Any,
) -> DaemonStats:
    """Stream `source` to the server until it ends; returns what happened (`DaemonStats`).

    Raises `UnauthorizedError` when the server refuses the token. See `Daemon` for the options.
    """
    return await Daemon(
        source, server_url, token, record=record, detector=detector, **options
    ).run()


# --- command line ----------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gazehdr daemon",
        description="Stream gaze from a tracker (or a recording, or a synthetic scan path) to a "
        "gazehdr server; sessions with gaze source 'remote' follow its fixations. SIGTERM and "
        f"Ctrl-C stop it after at most {SIGNAL_DRAIN_S:g} s more of delivery, with a summary.",
        epilog="examples:\n"
        "  gazehdr daemon --source synthetic --server ws://127.0.0.1:8000 --token T\n"
        "  gazehdr daemon --source replay:session.jsonl@2 --server ws://HOST:8000\n"
        "  gazehdr daemon --source hid --record today.jsonl   # token from $GAZEHDR_TOKEN\n"
        "  gazehdr daemon --source hid --screen 2560x1440 --distance 0.65 --record-dir /data",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--source",
        default="synthetic",
        help="hid[:PATH], replay:FILE[@SPEED] (SPEED a factor or max), or synthetic[:SEED] "
        "(default: synthetic). hid waits for a tracker to be plugged in",
    )
    p.add_argument(
        "--server",
        default=os.environ.get("GAZEHDR_SERVER"),
        help="the server, ws://HOST:PORT (default: $GAZEHDR_SERVER)",
    )
    p.add_argument(
        "--token",
        default=os.environ.get("GAZEHDR_TOKEN"),
        help="bearer token 'gazehdr serve' printed (default: $GAZEHDR_TOKEN)",
    )
    record = p.add_mutually_exclusive_group()
    record.add_argument(
        "--record", metavar="FILE", help="also write every sample and event here (a new file)"
    )
    record.add_argument(
        "--record-dir",
        metavar="DIR",
        help="also write every sample and event to a new DIR/gaze-YYYYmmddTHHMMSSZ.jsonl (UTC) "
        f"each run (default: ${RECORD_DIR_ENV}, unless --record is given)",
    )
    p.add_argument("--detector", choices=sorted(DETECTORS), default="ivt", help="default: ivt")
    p.add_argument(
        "--screen",
        type=screen_size_arg,
        metavar="WxH",
        help="the tracked screen's size in pixels (default 1920x1080)",
    )
    p.add_argument(
        "--diagonal",
        type=positive_arg,
        metavar="M",
        help="its diagonal in metres (default: a HID tracker's calibrated size, else 0.6)",
    )
    p.add_argument(
        "--distance",
        type=positive_arg,
        metavar="M",
        help="viewing distance in metres (default 1.0)",
    )
    p.add_argument(
        "--buffer",
        type=int,
        default=DEFAULT_BUFFER,
        metavar="N",
        help=f"items (samples and events) kept while the server is away, the oldest dropped "
        f"first (default: {DEFAULT_BUFFER}); with the up to {DEFAULT_MAX_INFLIGHT} sent but not "
        f"yet acknowledged, at most N + {DEFAULT_MAX_INFLIGHT} items are held in memory",
    )
    p.add_argument("--rate", type=float, metavar="HZ", help="synthetic source's sampling rate")
    p.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    return p


def _screen_flags(args: argparse.Namespace) -> dict[str, float]:
    """--screen, --diagonal, --distance as `ScreenGeometry` fields (see `open_source`)."""
    screen: dict[str, float] = {}
    if args.screen is not None:
        screen["screen_width_px"], screen["screen_height_px"] = args.screen
    if args.diagonal is not None:
        screen["screen_diagonal_m"] = args.diagonal
    if args.distance is not None:
        screen["viewing_distance_m"] = args.distance
    return screen


def _warn_unused_screen(info: SourceInfo, screen: Mapping[str, float]) -> None:
    used = asdict(info.geometry)
    kept = [f"{name} {used[name]:g}" for name, value in screen.items() if used[name] != value]
    if kept:
        log.warning(
            "the recording's own screen geometry is used (%s): --screen, --diagonal and "
            "--distance fill in only what a recording does not record",
            ", ".join(kept),
        )


async def _run_until_signalled(daemon: Daemon) -> tuple[DaemonStats, int | None]:
    """Run `daemon`; SIGTERM or Ctrl-C stops it as `stop()` does, the buffer draining for at
    most `SIGNAL_DRAIN_S`; a second one stops it at once. Returns the stats and the signal."""
    loop = asyncio.get_running_loop()
    got: list[int] = []

    def on_signal(signum: int) -> None:
        log.warning("%s: stopping%s", signal.Signals(signum).name, " now" if got else "")
        daemon.stop(drain_timeout=0.0 if got else SIGNAL_DRAIN_S)
        got.append(signum)

    installed = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(signum, on_signal, signum)
        except (NotImplementedError, RuntimeError):  # Windows, or not the main thread
            continue
        installed.append(signum)
    try:
        stats = await daemon.run()
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)
    return stats, got[0] if got else None


def daemon_main(argv: Sequence[str] | None = None) -> int:
    """`gazehdr daemon ...`: 0 when the source ended or SIGTERM stopped it, 1 on a failing
    source, 2 on bad input or a refused token, 130 on Ctrl-C."""
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = "gazehdr daemon"
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{prog}: %(message)s"))
    loggers = (
        log,
        logging.getLogger("gazehdr.drivers.hid"),
    )  # the tracker's waits and unplugs, too
    before = [(logger.level, logger.propagate) for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(logging.WARNING if args.quiet else logging.INFO)
        logger.propagate = False
    signalled: int | None = None
    try:
        if not args.server:
            parser.error("--server (or $GAZEHDR_SERVER) is required")
        if not args.token:
            parser.error("--token (or $GAZEHDR_TOKEN) is required")
        if args.buffer < 1:
            parser.error(f"--buffer must be a positive number of items, got {args.buffer}")
        record_dir = args.record_dir
        if record_dir is None and args.record is None:
            record_dir = os.environ.get(RECORD_DIR_ENV) or None
        screen = _screen_flags(args)
        try:
            replace(ScreenGeometry(), **screen)
        except ValueError as e:  # --screen 0x1080; --diagonal and --distance are checked already
            parser.error(f"--screen: {e}")
        source = open_source(args.source, rate_hz=args.rate, screen=screen, wait=True)
        _warn_unused_screen(source.info, screen)
        daemon = Daemon(
            source,
            args.server,
            args.token,
            record=args.record,
            record_dir=record_dir,
            detector=args.detector,
            buffer=args.buffer,
            status_interval=10.0,
        )
        stats, signalled = asyncio.run(_run_until_signalled(daemon))
    except UnauthorizedError as e:
        sys.stderr.write(f"{prog}: error: {e}\n")
        return 2
    except (DaemonError, SourceUnavailableError, ValueError, OSError) as e:
        what = f"{e.filename}: {e.strerror}" if isinstance(e, OSError) and e.strerror else str(e)
        sys.stderr.write(f"{prog}: error: {what}\n")
        return 2
    except KeyboardInterrupt:  # before the daemon ran (waiting for a tracker)
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130
    finally:
        for logger, (level, propagate) in zip(loggers, before, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)
            logger.propagate = propagate
    sys.stderr.write(f"{prog}: {stats.summary()}\n")
    if stats.source_error:
        sys.stderr.write(f"{prog}: error: source failed: {stats.source_error}\n")
        return 1
    return 130 if signalled == signal.SIGINT else 0
