"""The Pupil Capture source: ZeroMQ I/O over the pure `protocol` and `clock`.

Everything that touches a socket is here: Pupil Remote's REQ socket (`v`, `SUB_PORT`, `t`), the
SUB socket on the IPC backbone, timeouts, and reconnecting with back-off; what the bytes mean is
decided in `protocol`, where samples fall on the host clock in `clock`.

A REQ socket whose request goes unanswered cannot send again, so each request waits at most
`timeout_s` and a silent Capture closes both sockets (a fresh REQ next time, ZeroMQ's "lazy
pirate"). A SUB socket never notices that its publisher went away, so liveness is Pupil Remote's:
the `t` round trips of each clock sync, every `sync_interval_s`. When Capture stops answering,
what the SUB socket already holds is read and yielded first, then the source reconnects with
exponential back-off, asking `SUB_PORT` again (a restarted Capture binds new ports) and
measuring the clock afresh. Nothing received is dropped, and samples are never buffered here.

`T` is never sent: it would move Pupil time for Capture's recordings and every other client.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

try:
    import zmq
except ModuleNotFoundError as e:  # pragma: no cover - depends on the installation
    raise ModuleNotFoundError(
        "the Pupil Capture source needs pyzmq and msgpack: install gazehdr[pupil]", name=e.name
    ) from None

from gazehdr.drivers.backoff import retry
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.pupil import MIN_CONFIDENCE
from gazehdr.drivers.pupil.clock import PupilClock, SampleTimes, describe
from gazehdr.drivers.pupil.protocol import (
    MessageError,
    PupilAddress,
    decode,
    parse_address,
    parse_port,
    parse_time,
)
from gazehdr.drivers.registry import SourceUnavailableError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry, StreamRequest
from gazehdr.drivers.sessionlog import Note
from gazehdr.drivers.sources import SourceInfo
from gazehdr.drivers.states import InvalidStateError, Link

log = logging.getLogger(__name__)

#: A frame larger than this makes ZeroMQ drop the connection rather than allocate it: a surface
#: message is a few kB (four 3×3 matrices and one world frame's gaze).
MAX_FRAME_BYTES = 4 << 20
#: Messages read per poll at most, so that a flood cannot hold off the clock sync.
READ_BATCH = 256


class _Connection:
    """One connection to one Capture: Pupil Remote's REQ socket and the backbone's SUB socket.
    Used by one thread at a time; errors come out as OSError."""

    def __init__(self, ctx: Any, address: PupilAddress, timeout_s: float) -> None:
        self.address = address
        self.timeout_ms = max(1, round(timeout_s * 1000))
        self.req = ctx.socket(zmq.REQ)
        self.req.setsockopt(zmq.LINGER, 0)
        self.req.connect(address.remote_url)
        self.sub: Any = ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.MAXMSGSIZE, MAX_FRAME_BYTES)

    def request(self, command: str, clock_ns: Callable[[], int]) -> tuple[bytes, int, int]:
        """Pupil Remote's reply to `command`, with the host times it was asked and answered."""
        url = self.address.remote_url
        try:
            t0 = clock_ns()
            self.req.send_string(command, zmq.NOBLOCK)
            if not self.req.poll(self.timeout_ms, zmq.POLLIN):
                raise OSError(
                    f"Pupil Remote at {url} did not answer {command!r} within "
                    f"{self.timeout_ms / 1000:g} s"
                )
            reply = self.req.recv()
            return reply, t0, clock_ns()
        except zmq.ZMQError as e:
            raise OSError(f"Pupil Remote at {url}: {e}") from None

    def subscribe(self, port: int) -> None:
        try:
            self.sub.connect(self.address.url(port))
            self.sub.setsockopt_string(zmq.SUBSCRIBE, self.address.topic)
        except zmq.ZMQError as e:
            raise OSError(f"the backbone at {self.address.url(port)}: {e}") from None

    def receive(self, wait_ms: int) -> list[list[bytes]]:
        """The messages waiting on the SUB socket (up to `READ_BATCH`), after waiting at most
        `wait_ms` for the first."""
        messages: list[list[bytes]] = []
        try:
            if wait_ms and not self.sub.poll(wait_ms, zmq.POLLIN):
                return messages
            while len(messages) < READ_BATCH:
                messages.append(self.sub.recv_multipart(zmq.NOBLOCK))
        except zmq.Again:
            pass
        except zmq.ZMQError as e:
            raise OSError(f"the backbone: {e}") from None
        return messages

    def close(self) -> None:
        self.req.close(linger=0)
        self.sub.close(linger=0)


class _Limited:
    """Warnings at most one per `interval_ns`, each saying how many were held back."""

    def __init__(self, interval_ns: int) -> None:
        self.interval_ns = interval_ns
        self._last: int | None = None
        self._held = 0
        self.count = 0

    def warn(self, text: str, now_ns: int) -> None:
        self.count += 1
        if self._last is not None and now_ns - self._last < self.interval_ns:
            self._held += 1
            return
        held = f" ({self._held} more like it not shown)" if self._held else ""
        log.warning("%s%s", text, held)
        self._last, self._held = now_ns, 0


class PupilGazeSource:
    """Gaze mapped to a surface (the screen) by Pupil Capture's Surface Tracker, live.

    Iterate it for `GazeSample`s, or `records()` for those and a `Note` at each clock sync (the
    session log keeps how Pupil time relates to its samples'). `t_ns` is host monotonic ns: the
    datum's Pupil time minus the estimated offset (`clock`), kept increasing and never later than
    the message's arrival (`clock.SampleTimes`). x/y are pixels of `geometry` (the screen the
    surface covers; Pupil reports no size, so give it: `gazehdr daemon --screen`). A datum below
    `min_confidence` (0.6, Pupil Player's default) gives an invalid sample; one off the surface
    a valid sample off the screen (`protocol.GazeOnSurface.sample`).

    `timeout_s` bounds each Pupil Remote request; the clock is measured with `sync_burst`
    requests every `sync_interval_s`, the best of the last `clock_window` answers kept.
    `give_up_after_s` ends the iteration with an OSError when Capture has not answered for that
    long (None: retry for ever). With `open_now` (the default) the constructor connects and
    raises OSError when Capture does not answer. `quiet_warning_s`: a warning when a connected
    Capture sends nothing for the surface that long (plugin off, markers out of view, another
    name). `context` (a zmq.Context), `sleep` and `clock_ns` are injectable for tests.
    """

    def __init__(
        self,
        address: PupilAddress | None = None,
        *,
        geometry: ScreenGeometry | None = None,
        min_confidence: float = MIN_CONFIDENCE,
        timeout_s: float = 1.0,
        sync_interval_s: float = 5.0,
        sync_burst: int = 5,
        clock_window: int = 10,
        backoff_initial_s: float = 0.25,
        backoff_max_s: float = 8.0,
        give_up_after_s: float | None = None,
        quiet_warning_s: float = 10.0,
        open_now: bool = True,
        poll_ms: int = 100,
        context: Any = None,
        sleep: Callable[[float], None] = time.sleep,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if not 0 <= min_confidence <= 1:
            raise InputError(f"min_confidence must lie in [0, 1], got {min_confidence}")
        for name, value in (("timeout_s", timeout_s), ("sync_interval_s", sync_interval_s)):
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name} must be a positive number of seconds, got {value}")
        if sync_burst < 1:
            raise InputError(f"sync_burst must be at least 1, got {sync_burst}")
        self.address = address or PupilAddress()
        self.geometry = geometry or ScreenGeometry()
        self.min_confidence = min_confidence
        self.timeout_s = timeout_s
        self.sync_interval_ns = round(sync_interval_s * 1e9)
        self.sync_burst = sync_burst
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.give_up_after_s = give_up_after_s
        self.quiet_warning_ns = round(quiet_warning_s * 1e9)
        self.poll_ms = poll_ms
        self._ctx = context or zmq.Context.instance()
        self._sleep = sleep
        self._clock_ns = clock_ns
        self.clock = PupilClock(clock_window)
        self._times = SampleTimes()
        self._malformed = _Limited(1_000_000_000)
        self._conn: _Connection | None = None
        self._next_sync_ns = 0
        self._forced_sync_ns: int | None = None
        self._heard_ns = 0  # when the surface last sent something (or the connection began)
        self._quiet_warned = False
        self.capture_version: str | None = None
        self.samples_yielded = 0
        self.reconnects = 0
        self._closed = False
        self._running = False
        if open_now:
            self.connect()

    @property
    def malformed(self) -> int:
        """Messages and datums left out because they did not follow the Network API."""
        return self._malformed.count

    @property
    def info(self) -> SourceInfo:
        tracker: dict[str, Any] = {
            "source": "pupil",
            "remote": self.address.remote_url,
            "surface": self.address.surface,
            "min_confidence": self.min_confidence,
            "coordinates": "surface-normalised, origin bottom-left, as screen pixels",
            "clock": "Pupil time on the host clock by Pupil Remote 't' round trips",
        }
        if self.capture_version is not None:
            tracker["capture_version"] = self.capture_version
        return SourceInfo(
            name=f"pupil {self.address}", geometry=self.geometry, live=True, tracker=tracker
        )

    # connection

    @property
    def connection_state(self) -> Link:
        """The connection's state: CLOSED once closed, else whether it is connected."""
        if self._closed:
            return Link.CLOSED
        return Link.DISCONNECTED if self._conn is None else Link.CONNECTED

    def connect(self) -> _Connection:
        """Connect once: Capture's version, its SUB port, the clock, the subscription
        (OSError when Pupil Remote does not answer, or answers what Capture would not). Refused
        while connected (its sockets would leak) and once closed (nothing would close them)."""
        if self.connection_state is not Link.DISCONNECTED:
            raise InvalidStateError(
                "PupilGazeSource", "connect", self.connection_state, "not connected"
            )
        conn = _Connection(self._ctx, self.address, self.timeout_s)
        try:
            version, _, _ = conn.request("v", self._clock_ns)
            port, _, _ = conn.request("SUB_PORT", self._clock_ns)
            conn.subscribe(parse_port(port))
            self.clock.restart()
            self._conn = conn
            self._sync()
        except (OSError, MessageError) as e:
            self._conn = None
            conn.close()
            raise OSError(str(e)) from None
        self.capture_version = version.decode("utf-8", "replace")[:80]
        self._heard_ns, self._quiet_warned = self._clock_ns(), False
        return conn

    def wait_for_capture(self) -> None:
        """Connect, waiting with back-off until Capture answers (a line per attempt); OSError
        after `give_up_after_s`. How `gazehdr daemon --source pupil:…` starts."""
        if self._reconnect() is None:
            raise OSError("the Pupil source was closed while waiting for Pupil Capture")

    def _reconnect(self) -> _Connection | None:
        """Connect, waiting with back-off; None when the source was closed meanwhile."""
        return retry(
            self.connect,
            name="Pupil Capture",
            missing="Pupil Capture",
            closed=lambda: self._closed,
            log=log,
            initial_s=self.backoff_initial_s,
            max_s=self.backoff_max_s,
            give_up_after_s=self.give_up_after_s,
            sleep=self._sleep,
            clock=lambda: self._clock_ns() / 1e9,
        )

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._conn = None

    def close(self) -> None:
        """Stop: the running iteration ends at its next poll (within `poll_ms`) and closes its
        sockets itself, so no socket is closed under a read in another thread."""
        self._closed = True
        if not self._running:
            self._drop()

    # the clock

    def _sync(self) -> Note:
        """`sync_burst` round trips of `t`; the estimate as a note for the session log."""
        assert self._conn is not None
        for _ in range(self.sync_burst):
            reply, t0, t1 = self._conn.request("t", self._clock_ns)
            if self.clock.add(t0, parse_time(reply), t1):
                log.warning("Pupil time jumped (a 'T' sent to Pupil Remote?); measuring it afresh")
        self._next_sync_ns = self._clock_ns() + self.sync_interval_ns
        return self._note()

    def _note(self) -> Note:
        """The current estimate, for the session log."""
        best = self.clock.best
        assert best is not None
        return Note(self._clock_ns(), f"pupil clock: {describe(best)}")

    # the stream

    def records(self) -> Iterator[GazeSample | Note]:
        """Samples as they come, and a `Note` per clock sync."""
        if self._running:
            raise RuntimeError("this Pupil source is already being iterated")
        self._running = True
        try:
            yield from self._stream()
        finally:
            self._running = False
            self._drop()

    def __iter__(self) -> Iterator[GazeSample]:
        return (r for r in self.records() if isinstance(r, GazeSample))

    def _stream(self) -> Iterator[GazeSample | Note]:
        announced: _Connection | None = None  # the connection whose clock the log has
        while not self._closed:
            if self._conn is None:
                if self._reconnect() is None:
                    return
                if self.reconnects:
                    log.info("Pupil Capture reconnected: %s", self.address)
            conn = self._conn
            assert conn is not None
            if conn is not announced:
                announced = conn
                yield self._note()
            try:
                if self._clock_ns() >= self._next_sync_ns:
                    yield self._sync()
                for frames in conn.receive(self.poll_ms):
                    yield from self._message(frames, self._clock_ns())
                self._check_quiet()
            except (OSError, MessageError) as e:
                self.reconnects += 1
                log.warning(
                    "Pupil Capture stopped answering (%s); %d samples recorded so far are kept; "
                    "reconnecting",
                    e,
                    self.samples_yielded,
                )
                while waiting := conn.receive(0):  # what arrived before it went is kept
                    for frames in waiting:
                        yield from self._message(frames, self._clock_ns(), resync=False)
                self._drop()

    def _message(
        self, frames: list[bytes], arrived_ns: int, *, resync: bool = True
    ) -> Iterator[GazeSample | Note]:
        try:
            message = decode(frames, self.address.surface)
        except MessageError as e:
            self._malformed.warn(f"Pupil Capture sent a malformed message: {e}", arrived_ns)
            return
        if message is None:
            return  # another surface whose name begins with ours
        self._heard_ns, self._quiet_warned = arrived_ns, False
        for problem in message.problems:
            self._malformed.warn(f"Pupil Capture sent a malformed datum: {problem}", arrived_ns)
        if resync and not all(self.clock.plausible(d.timestamp, arrived_ns) for d in message.gaze):
            yield from self._resync(arrived_ns)
        for datum in message.gaze:
            t_ns = self._times.next(self.clock.host_ns(datum.timestamp), arrived_ns)
            self.samples_yielded += 1
            yield datum.sample(t_ns, self.geometry, self.min_confidence)

    def _resync(self, now_ns: int) -> Iterator[Note]:
        """Gaze stamped far from when it came: Pupil time moved; measure it again now (at most
        once a second)."""
        if self._forced_sync_ns is not None and now_ns - self._forced_sync_ns < 1_000_000_000:
            return
        self._forced_sync_ns = now_ns
        log.warning("Pupil Capture's gaze is stamped far from when it came; measuring its clock")
        yield self._sync()

    def _check_quiet(self) -> None:
        now = self._clock_ns()
        if not self._quiet_warned and now - self._heard_ns >= self.quiet_warning_ns:
            self._quiet_warned = True
            log.warning(
                "Pupil Capture at %s has sent nothing on %r for %.0f s: is the Surface Tracker "
                "plugin on, a surface named %r defined, and its markers in the world camera's "
                "view?",
                self.address.remote_url,
                self.address.topic,
                (now - self._heard_ns) / 1e9,
                self.address.surface,
            )


def open_pupil(request: StreamRequest) -> PupilGazeSource:
    """The `pupil[:HOST[:PORT][/SURFACE]]` stream of `gazehdr.drivers.registry`: Pupil Remote
    at HOST:PORT (127.0.0.1:50020), the gaze on the surface SURFACE (`screen`); the screen's
    geometry from `geometry` and `screen`; `sleep` and `clock` for the back-off and the clock
    syncs. With `wait`, waits for Capture to answer; else
    SourceUnavailableError when it does not (the registry reports a missing pyzmq or msgpack,
    an ImportError)."""
    address = parse_address(request.arg)
    options = dict(request.options)
    options.setdefault("geometry", request.screen_geometry())
    options.setdefault("open_now", not request.wait)
    if request.sleep is not None:
        options.setdefault("sleep", request.sleep)
    if request.clock is not None:
        options.setdefault("clock_ns", request.clock)
    try:
        source = PupilGazeSource(address, **options)
        if request.wait:
            source.wait_for_capture()
        return source
    except OSError as e:
        raise SourceUnavailableError(f"Pupil source unavailable: {e}") from None
