"""The gaze daemon: a gaze source streamed to a gazehdr server's `/ws/gaze`, losing nothing
quietly.

What to send, when, and what the server's replies mean is `gazehdr.drivers.delivery`'s
`Delivery` (the send buffer and its drop policy, pacing, batching, acknowledgement by echo,
resending, the clock offset); this module is the I/O around it, on one asyncio loop:

- the source runs in a thread (tracker reads and real-time pacing block) and hands each record
  to the loop, which feeds it to the core. A source that is not live (a replay) is made to wait
  while the core's send buffer is full, so it loses nothing;
- what the core gives for the session log is written there (`record=`, or a new timestamped
  file in `record_dir=`), and published where an `outlet=` is given (`gazehdr.drivers.lsl.
  outlet.GazeOutlets`: samples on an LSL gaze stream, events and notes on a marker stream);
  its warnings are logged;
- a connection opens with the bearer token and the core's hello; then the loop runs sending
  rounds, sending what the core returns and then its echo, every `flush_interval` or sooner
  when the core says a round is due; a reader task feeds the server's replies to the core with
  the time they came;
- a lost connection, welcomed or not yet, is told to the core (`connection_lost`) and retried
  with exponential back-off (`backoff`); a refused token (close code 4401) is fatal:
  `UnauthorizedError`, no retry.

`run_daemon(source, server_url, token, ...)` runs until the source ends (and the buffer is
delivered, or `drain_timeout` passes) or `Daemon.stop()` is called. The command line is
`gazehdr.drivers.daemon_cli`. Nothing here imports `server` or pyopencl.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import threading
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from gazehdr.drivers import wire
from gazehdr.drivers.delivery import DaemonError, DaemonStats, Delivery, State, is_event
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import ClockInfo, SessionHeader, SessionLogWriter
from gazehdr.drivers.sources import SourceInfo, fixation_places_of, records_of

log = logging.getLogger("gazehdr.daemon")

CLOSE_UNAUTHORIZED = 4401


class UnauthorizedError(DaemonError):
    """The server refused the bearer token (close code 4401)."""


def gaze_url(server: str) -> str:
    """`ws://HOST:PORT` (or http://, or a bare HOST:PORT) → the `/ws/gaze` endpoint's URL."""
    text = server.strip()
    if "://" not in text:
        text = "ws://" + text
    parts = urlsplit(text)
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None or not parts.netloc:
        raise InputError(f"server {server!r}: expected ws://HOST:PORT")
    path = parts.path if parts.path not in ("", "/") else "/ws/gaze"
    return urlunsplit((scheme, parts.netloc, path, parts.query, ""))


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
    """One source, one server. `await run()`; `stop()` (on the loop) ends it cleanly.

    `name` is the tracker's name in the hello (default: the source's); give each station its
    own. `accuracy_deg`, the tracker's accuracy in degrees, goes with it (default: the
    source's, if it knows). `outlet` (anything with `push(record)`) gets every record the
    session log gets, as the core gives them, whether or not a log is written. `options` are
    the delivery core's (`Delivery`: buffer, batch, flush_interval, max_rate, burst,
    max_inflight, echo_interval, clock_window); the rest are about I/O.
    """

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
        backoff: tuple[float, float] = (0.1, 5.0),
        drain_timeout: float = 10.0,
        welcome_timeout: float = 5.0,
        status_interval: float | None = None,
        name: str | None = None,
        outlet: Any = None,
        accuracy_deg: float | None = None,
        **options: Any,
    ) -> None:
        if record is not None and record_dir is not None:
            raise InputError(
                "record (one file) and record_dir (a new file per run) exclude each other"
            )
        self.source = source
        # `name`: what the server lists this tracker under, and sessions follow it by
        # (remote:NAME); the source's own name where none is given.
        self.info: SourceInfo = replace(source.info, name=name) if name else source.info
        if accuracy_deg is not None:
            self.info = replace(self.info, accuracy_deg=accuracy_deg)
        self.url = gaze_url(server_url)
        self.token = token
        self.record_path = Path(record) if record is not None else None
        self.record_dir = Path(record_dir) if record_dir is not None else None
        self.overwrite = overwrite
        self.backoff, self.drain_timeout = backoff, drain_timeout
        self.welcome_timeout = welcome_timeout
        self.status_interval = status_interval
        self.outlet = outlet
        places = fixation_places_of(source) if self.info.has_events else None
        self.core = Delivery(self.info, places=places, detector=detector, **options)
        self.stats: DaemonStats = self.core.stats
        self._handed = 0  # records the thread handed over (written by the thread only)
        self._ingested = 0  # records the loop took in (written by the loop only)
        self._stop_flag = threading.Event()
        self._source_done_at: float | None = None
        self._writer: SessionLogWriter | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None  # set when the core says a round is due

    @property
    def connected(self) -> bool:
        """Whether a connection is open (welcomed): the core's state says."""
        return self.core.state is State.OPEN

    @property
    def backlog(self) -> int:
        return self.core.backlog

    @property
    def max_inflight(self) -> int:
        return self.core.max_inflight

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
                        self.core.unsent + self._handed - self._ingested >= self.core.buffer
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

    # --- the core's inputs and outputs (loop) --------------------------------------------------

    def _ingest(self, record: Any) -> None:
        self._ingested += 1
        self.core.add(record)
        self._outputs()

    def _outputs(self) -> None:
        """Carry out what the core asked for since the last input: write its records, log its
        warnings, and wake the sender when a round is due."""
        for record in self.core.records_to_write():
            self._write(record)
            if self.outlet is not None:
                self.outlet.push(record)
        for text in self.core.warnings():
            log.warning("%s", text)
        if self.core.send_due and self._wake is not None:
            self._wake.set()

    def _write(self, record: Any) -> None:
        if self._writer is None:
            return
        self._writer.write(record)
        if isinstance(record, GazeSample):
            self.stats.samples_recorded += 1
        elif is_event(record):
            self.stats.events_recorded += 1

    def _end_of_source(self) -> None:
        if self._source_done_at is not None and not self.core.accepting:
            return
        self.core.end_of_source()
        if self._source_done_at is None:
            self._source_done_at = time.monotonic()
        self._outputs()

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

    def _drained(self) -> bool:
        return self._source_done_at is not None and self.core.drained

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
            close = getattr(self.source, "close", None)
            if callable(close):  # a tracker's read loop ends, not left running in its thread
                close()
            if status is not None:
                status.cancel()
            self.core.finish()
            self._outputs()
            if self._writer is not None:
                self._writer.close()
        return self.stats

    def _draining_too_long(self) -> bool:
        done = self._source_done_at
        return done is not None and time.monotonic() - done > self.drain_timeout

    async def _connect_loop(self) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

        delay = self.backoff[0]
        while not self._drained() and not self._draining_too_long():
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
                if self.core.state in (State.CONNECTING, State.OPEN):  # hello was given
                    self.core.connection_lost()
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

        try:
            await ws.send(self.core.hello())
            while True:
                text = await asyncio.wait_for(ws.recv(), self.welcome_timeout)
                if self.core.welcome(text):  # DaemonError where it refuses
                    break
        except ConnectionClosed as e:
            raise self._closed(e) from None
        self.core.connected()
        log.info("connected to %s as %r", self.url, self.info.name)
        self._outputs()  # the note of what was dropped while disconnected

    def _closed(self, e: Any) -> _ClosedError:
        rcvd = getattr(e, "rcvd", None)
        if rcvd is not None:
            return _ClosedError(rcvd.code, rcvd.reason)
        return _ClosedError(None, "")

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
                for text in self.core.send(time.monotonic_ns()):
                    await ws.send(text)
                self._outputs()  # the warning of what could not be sent, if any
                echo = self.core.echo(time.monotonic_ns())
                if echo is not None:
                    await ws.send(echo)
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), self.core.flush_interval)
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
                self.core.receive(text, time.monotonic_ns())
                self._outputs()
        except ConnectionClosed as e:
            raise self._closed(e) from None
        raise _ClosedError(ws.close_code, ws.close_reason or "")

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
