"""What the gaze daemon sends to a gazehdr server's `/ws/gaze`, when, and what the replies mean:
the daemon's delivery logic, without I/O.

`Delivery` is kept the way the `websockets` library keeps its protocol: an object fed inputs
that hands back what to do. It never reads a clock, sleeps, touches a socket, a thread or a
file, nor logs; `gazehdr.drivers.daemon` does all that around it. Its inputs: each record of
the source (`add`), the source's end (`end_of_source`), a connection welcomed (`connected`,
after `hello` and `welcome`) or lost (`connection_lost`), a reply from the server with the time
it came (`receive`), and a sending round at a given time (`send`, then `echo` once what `send`
gave is sent). Its outputs: wire texts to send, whether a round is due before `flush_interval`
has passed (`send_due`), the records for the session log (`records_to_write`), warnings for the
daemon to log (`warnings`), and the counts in `stats` (`DaemonStats`).

Its connection side has a named state (`State`), and a call its state does not allow raises
`InvalidStateError` before anything changes, so nothing buffered or counted is lost:

    IDLE --hello()--> CONNECTING --connected()--> OPEN --connection_lost()--> IDLE
                      CONNECTING --connection_lost()--> IDLE     (never welcomed: nothing counted)
    IDLE, CONNECTING, OPEN --finish()--> CLOSED

`welcome` reads replies in CONNECTING; `send`, `echo` and `receive` need OPEN. The back-off
between a lost connection and the next `hello` is the daemon's. The source's side (`add`,
`end_of_source`) is taken in every state: records join the buffer until the source ends or
the daemon finishes, and are not taken after (a source thread's last records may come late).

- every sample is recorded and goes through the fixation detector; samples and events join the
  send buffer in the order they were emitted;
- the server follows fixation events, so each one sent carries a position. A replayed
  recording whose fixation starts carry none (EyeLink `SFIX`, BIDS onsets) says where each
  fixation is (`places`: what `SessionLog.fixation_track` holds): its events are sent with
  those positions, and recorded as they were. A source whose events cannot place a single
  fixation (BIDS physioevents without positions, or only blinks) is run through the detector
  instead, as `fixation_track` runs I-VT over a log without fixations; its own events are then
  recorded, not sent. Of a binocular recording's fixations, the first fixating eye's are sent;
- the send buffer is bounded (`buffer` items). While the server is unreachable a live source
  keeps producing: when the buffer is full its oldest never-sent item is dropped, counted,
  warned of, and noted in the session log. A source that is not live (a replay) loses nothing:
  the daemon makes it wait while `unsent` fills the buffer;
- what the server would refuse (a negative time, a fixation without a position) is never sent,
  since the next echo would acknowledge it: it is counted unsendable;
- sending is paced by a token bucket below the server's limit (1900 samples/s, burst 1000,
  against the server's 2000/s, burst 4000), in batches of at most `batch` samples every
  `flush_interval` seconds (sooner when a batch is full, an event is waiting or an
  acknowledgement freed the in-flight window; never sooner while the bucket is empty);
- delivery is acknowledged by the clock echo: the server handles one connection's messages in
  order, so its reply to an `echo` sent after a batch proves the batch was handled. At most
  `max_inflight` items wait for that. Items sent but not yet acknowledged when a connection
  dies are sent again on the next one (at least once: a sample may arrive twice across a
  reconnect, never not at all unless counted dropped);
- an echo follows every round that sent something, and otherwise comes every 0.1 s while
  items are in flight and every `echo_interval` seconds when idle;
- the same echoes estimate the clock offset to the server: offset = server_ns − (t0 + t1)/2 with
  uncertainty RTT/2, keeping the estimate with the smallest RTT among the last `clock_window`
  echoes of the current connection (a reconnect may reach a restarted or rebooted server,
  whose monotonic clock is another); it is reported in `stats` and, for a live source, written
  to the session log as `clock` records, at most one a second;
- the server's rate-limit notes ("rate limit: N samples dropped") are added up in `stats`.

Past 600 lines because `Delivery` is one state machine: every input reads and changes the same
buffer, in-flight window, bucket and counts, so its methods stay together; the clock estimate,
the counts and the wire conversion beside it are the small pure parts it uses.
"""

from __future__ import annotations

import enum
import math
import re
from collections import deque
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from gazehdr.drivers import wire
from gazehdr.drivers.errors import GazehdrError, InputError
from gazehdr.drivers.fixations import DETECTORS, make_detector
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import EVENT_KINDS, ClockUpdate, Note
from gazehdr.drivers.sources import SourceInfo
from gazehdr.drivers.states import InvalidStateError

SERVER_RATE_HZ = 2000.0  # gazehdr.gaze_link.GAZE_RATE_HZ, kept equal by tests/test_server.py
DEFAULT_RATE_HZ = 1900.0  # what the daemon sends at most: below the limit, with margin
DEFAULT_BURST = 1000.0  # below the server's burst of 4000
DEFAULT_BUFFER = 20_000  # items (samples and events): 10 s of a 2000 Hz tracker
DEFAULT_MAX_INFLIGHT = 2000  # items sent, not yet acknowledged: 1 s at the server's limit
INFLIGHT_ECHO_NS = 100_000_000  # while items wait for acknowledgement, an echo at least this often
CLOCK_RECORD_NS = 1_000_000_000  # at most one `clock` record a second in the session log
_RATE_NOTE = re.compile(r"rate limit: (\d+) (samples|events|echoes) dropped")
_WIRE_TIMES = range(2**63)  # what a wire `t` may be (gazehdr.drivers.wire._int)


class DaemonError(GazehdrError, RuntimeError):
    """The daemon cannot go on; the text says why."""


class State(enum.Enum):
    """Where `Delivery` is in a connection's life (the module docstring has the diagram)."""

    IDLE = "idle"  # no connection: before the first, and from a lost one to the next hello
    CONNECTING = "connecting"  # hello given, the server's welcome awaited
    OPEN = "open"  # welcomed: sending rounds, echoes, the server's replies
    CLOSED = "closed"  # finished: what was never delivered is counted; nothing more is sent


_WHEN = {  # what each connection-side method needs, said in InvalidStateError's text
    "hello": ((State.IDLE,), "a connection starts from IDLE (after connection_lost)"),
    "welcome": ((State.CONNECTING,), "only after hello(), before connected()"),
    "connected": ((State.CONNECTING,), "only after hello(), once welcome() said so"),
    "connection_lost": (
        (State.CONNECTING, State.OPEN),
        "only while a connection is CONNECTING or OPEN",
    ),
    "receive": ((State.OPEN,), "replies are read only while OPEN (after connected())"),
    "send": ((State.OPEN,), "rounds run only while OPEN (after connected())"),
    "echo": ((State.OPEN,), "echoes are sent only while OPEN (after connected())"),
    "finish": ((State.IDLE, State.CONNECTING, State.OPEN), "the delivery has finished already"),
}


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
    #: (round time in seconds, samples sent) of the latest sending rounds
    sent_times: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=4096))

    def summary(self) -> str:
        clock = (
            f"clock offset {self.clock.offset_ns / 1e6:+.3f} ms "
            f"± {self.clock.uncertainty_ns / 1e3:.0f} µs"
            if self.clock
            else "clock offset unknown"
        )
        undelivered = _counted(self.samples_undelivered, self.events_undelivered, "never delivered")
        unsendable = _counted(
            self.samples_unsendable, self.events_unsendable, "not sendable (recorded only)"
        )
        return (
            f"{self.samples_produced} samples, {self.events_produced} events from the source; "
            f"delivered {self.samples_delivered} samples, {self.events_delivered} events; "
            f"dropped {self.samples_dropped} samples, {self.events_dropped} events "
            f"(buffer full){undelivered}{unsendable}; "
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


def _counted(samples: int, events: int, what: str) -> str:
    """A summary's clause on items that were not delivered, said only when there were any."""
    return f"; {samples} samples, {events} events {what}" if samples or events else ""


# --- the wire form ---------------------------------------------------------------------------


def is_event(item: Any) -> bool:
    """Whether a record is a fixation or blink event (of a detector, or of a recording)."""
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


# --- delivery --------------------------------------------------------------------------------


class Delivery:
    """One source's records on their way to one server at a time (see the module docstring).

    `places` is what `fixation_places_of(source)` says (None: the source does not say); the
    other options are `Daemon`'s. Times are nanoseconds on the daemon's monotonic clock.
    `state` is where it is in a connection's life (`State`).
    """

    def __init__(
        self,
        info: SourceInfo,
        *,
        places: Mapping[tuple[int, str | None], Any] | None = None,
        detector: str | None = "ivt",
        buffer: int = DEFAULT_BUFFER,
        batch: int = 50,
        flush_interval: float = 0.02,
        max_rate: float = DEFAULT_RATE_HZ,
        burst: float = DEFAULT_BURST,
        max_inflight: int = DEFAULT_MAX_INFLIGHT,
        echo_interval: float = 1.0,
        clock_window: int = 32,
    ) -> None:
        if buffer < 1 or batch < 1 or max_inflight < batch:
            raise InputError("buffer and batch must be positive, max_inflight at least batch")
        if max_rate > SERVER_RATE_HZ:
            raise InputError(f"max_rate {max_rate} is over the server's {SERVER_RATE_HZ:g}/s")
        if detector is not None and detector not in DETECTORS:
            raise InputError(f"unknown detector {detector!r}; known: {', '.join(DETECTORS)}")
        self.info = info
        self.buffer, self.batch, self.flush_interval = buffer, batch, flush_interval
        self.max_rate, self.burst, self.max_inflight = max_rate, burst, max_inflight
        self.echo_interval = echo_interval
        self.stats = DaemonStats()
        self.clock = ClockEstimator(clock_window)
        # The source's own events pass through when they place its fixations; otherwise the
        # detector runs (see the module docstring).
        self._places = places or {}
        self._sends_own_events = info.has_events and (places is None or bool(places))
        self._eye: str | None = None  # the eye whose fixations are sent (see _follows)
        self._eye_chosen = False
        self.detector = (
            make_detector(detector, info.geometry)
            if detector is not None and not self._sends_own_events
            else None
        )
        self.state = State.IDLE
        self._source_ended = False
        self._unsent: deque[Any] = deque()
        self._retry: deque[Any] = deque()
        self._inflight: deque[tuple[int, Any]] = deque()
        self._marks: dict[int, int] = {}  # echo t0 -> last seq sent before it
        self._seq = 0
        self._pending_samples = 0  # samples in _unsent
        self._last_t = 0  # the latest sample time: where notes go in the session log
        self._drop_note = [0, 0]  # samples, events dropped since the last note
        self._bucket = TokenBucket(max_rate, burst)
        self._last_echo_ns: int | None = None  # this connection's last echo: none yet
        self._sent_in_round = False
        self._wake = False  # input that makes a round due now
        self._held = False  # the last round found the bucket empty
        self._clock_written: tuple[int, ClockEstimate] | None = None
        self._to_record: list[Any] = []
        self._warnings: list[str] = []

    def _expect(self, method: str) -> None:
        """Refuse `method` (InvalidStateError) unless the state allows it; before any change."""
        allowed, why = _WHEN[method]
        if self.state not in allowed:
            raise InvalidStateError("Delivery", method, self.state, why)

    # --- outputs ---------------------------------------------------------------------------------

    @property
    def accepting(self) -> bool:
        """Whether the source's records are taken: until the source ends or the daemon does."""
        return not self._source_ended and self.state is not State.CLOSED

    def records_to_write(self) -> list[Any]:
        """The session log's records since the last call, in order (samples, events, notes,
        clock records); the daemon writes them when it records, and drops them otherwise."""
        out, self._to_record = self._to_record, []
        return out

    def warnings(self) -> list[str]:
        """What went wrong or was lost since the last call, for the daemon to log."""
        out, self._warnings = self._warnings, []
        return out

    @property
    def send_due(self) -> bool:
        """Whether a round should run now rather than `flush_interval` after the last: a full
        batch or an event waits, the source ended, or an acknowledgement freed the window;
        never while the token bucket is empty."""
        return self._wake and not self._held

    @property
    def unsent(self) -> int:
        """Items in the send buffer, never sent: a live source's stay within `buffer`, a
        replay is made to wait while they fill it."""
        return len(self._unsent)

    @property
    def backlog(self) -> int:
        """Items not yet delivered: never sent, to be sent again, or awaiting acknowledgement."""
        return len(self._unsent) + len(self._retry) + len(self._inflight)

    @property
    def drained(self) -> bool:
        """The source has ended and everything it gave is delivered (or counted lost)."""
        return not self.accepting and self.backlog == 0

    # --- the source's side ---------------------------------------------------------------------

    def add(self, record: Any) -> None:
        """A record from the source: a sample, an event, or anything else a replayed log holds
        (scene, params, note, clock records: recorded only)."""
        if not self.accepting:
            return
        if isinstance(record, GazeSample):
            self.stats.samples_produced += 1
            self._last_t = max(self._last_t, record.t_ns)
            self._to_record.append(record)
            self._enqueue(record)
            if self.detector is not None:
                self._detected(self.detector.feed(record))
        elif is_event(record) and self._sends_own_events and self._follows(record):
            self._event(record)
        else:  # scene, params, note, clock records of a replayed log, unused events
            self._to_record.append(record)

    def end_of_source(self) -> None:
        """The source gave its last record: the detector's last events join, nothing more does.
        Again, or after `finish`: nothing changes."""
        if not self.accepting:
            return
        if self.detector is not None:
            self._detected(self.detector.flush())
        self._source_ended = True
        self._wake = True

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
            self._to_record.append(event)
        self._enqueue(event)

    def _detected(self, events: list[Any]) -> None:
        """The detector's events: sent, and recorded unless the source has events of its own
        (the log then keeps exactly the source's records; replaying it runs the detector
        again, to the same events)."""
        for event in events:
            self._event(event, record=not self.info.has_events)

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
                self._warnings.append(
                    f"send buffer full ({self.buffer} items): dropping the oldest"
                )
        self._unsent.append(item)
        if sample:
            self._pending_samples += 1
        if not sample or self._pending_samples >= self.batch:
            self._wake = True

    def _note_drops(self, why: str) -> None:
        samples, events = self._drop_note
        if not (samples or events):
            return
        self._drop_note = [0, 0]
        text = (
            f"send buffer full ({self.buffer} items) {why}: "
            f"dropped {samples} samples, {events} events"
        )
        self._warnings.append(text)
        self._to_record.append(Note(self._last_t, text))

    def finish(self) -> None:
        """The daemon ends: nothing more is taken in, and what was never delivered is counted
        (it is in the session log, when one is written). CLOSED from then on; InvalidStateError
        when it is already."""
        self._expect("finish")
        self.state = State.CLOSED
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
            self._warnings.append(
                f"gave up: {self.stats.samples_undelivered} samples and "
                f"{self.stats.events_undelivered} events were never delivered (they are in the "
                "local recording if one was asked for)"
            )
        self._note_drops("before the end")

    # --- the server's side ---------------------------------------------------------------------

    def hello(self) -> str:
        """The first message of a connection: the protocol, the tracker, its screen and, when
        known, its accuracy. IDLE → CONNECTING."""
        self._expect("hello")
        screen = {k: float(v) for k, v in asdict(self.info.geometry).items()}
        if self.info.accuracy_deg is not None:
            screen[wire.ACCURACY] = float(self.info.accuracy_deg)
        text = wire.dumps(wire.Hello(wire.PROTOCOL, self.info.name, screen))
        self.state = State.CONNECTING
        return text

    def welcome(self, text: str) -> bool:
        """Whether a reply to `hello` welcomes us (False: not yet, wait for the next one);
        `DaemonError` where the server refused or replied nonsense (the connection is then
        lost: `connection_lost`)."""
        self._expect("welcome")
        try:
            reply = wire.parse_reply(text)
        except wire.WireError as e:
            raise DaemonError(f"the server's reply to hello: {e}") from None
        if isinstance(reply, wire.Notice):
            raise DaemonError(f"the server refused hello: {reply.message}")
        return isinstance(reply, wire.Welcome)

    def connected(self) -> None:
        """The server welcomed us: a fresh bucket, echo cadence and clock (this may be another
        server, or the same one rebooted), and the note of what the outage dropped.
        CONNECTING → OPEN."""
        self._expect("connected")
        self.state = State.OPEN
        self.stats.connects += 1
        self.clock = ClockEstimator(self.clock.window.maxlen or 1)
        self._bucket = TokenBucket(self.max_rate, self.burst)
        self._last_echo_ns = None
        self._note_drops("while disconnected")

    def connection_lost(self) -> None:
        """The connection ended: what it left unacknowledged goes first on the next one.
        OPEN → IDLE; CONNECTING → IDLE counts nothing (it was never welcomed, sent nothing)."""
        self._expect("connection_lost")
        was, self.state = self.state, State.IDLE
        if was is State.CONNECTING:
            return
        self.stats.disconnects += 1
        self._marks.clear()
        if self._inflight:
            self.stats.resent += len(self._inflight)
            self._retry.extendleft(item for _, item in reversed(self._inflight))
            self._inflight.clear()

    def receive(self, text: str, now_ns: int) -> None:
        """A reply from the server, come at `now_ns`: an echo (clock and acknowledgement) or a
        notice (counted where it reports what a rate limit dropped, warned of always)."""
        self._expect("receive")
        try:
            reply = wire.parse_reply(text)
        except wire.WireError as e:
            self._warnings.append(f"ignoring a reply from the server: {e}")
            return
        if isinstance(reply, wire.EchoReply):
            self._echoed(reply, now_ns)
        elif isinstance(reply, wire.Notice):
            m = _RATE_NOTE.search(reply.message)
            if m:
                limited = self.stats.server_rate_limited
                limited[m.group(2)] = limited.get(m.group(2), 0) + int(m.group(1))
            self._warnings.append(f"server: {reply.message}")

    def _echoed(self, reply: wire.EchoReply, t1: int) -> None:
        best = self.clock.add(reply.t0_ns, reply.server_ns, t1)
        self.stats.clock = best
        if best is not None:
            self._record_clock(best, t1)
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
        self._wake = True

    def _record_clock(self, best: ClockEstimate, now_ns: int) -> None:
        """A `clock` record when the estimate changed, at most one a second; only a live
        source's log gets them (a replay's times are the recording's, not this clock's)."""
        if not self.info.live:
            return
        last = self._clock_written
        if last is not None and (last[1] == best or now_ns - last[0] < CLOCK_RECORD_NS):
            return
        self._clock_written = (now_ns, best)
        self._to_record.append(ClockUpdate(now_ns, best.offset_ns, best.uncertainty_ns))

    # --- sending ---------------------------------------------------------------------------------

    def send(self, now_ns: int) -> list[str]:
        """A sending round at `now_ns`: what the token bucket and the in-flight window allow,
        as wire texts to send in this order. Call `echo` once they are sent."""
        self._expect("send")
        self._wake = self._held = self._sent_in_round = False
        now = now_ns / 1e9
        texts: list[str] = []
        while (queue := self._next()) is not None:
            room = self.max_inflight - len(self._inflight)
            if room <= 0:
                break
            if isinstance(queue[0], GazeSample):
                n = min(self.batch, room, self._bucket.available(now))
                if n <= 0:
                    self._held = True
                    break
                text = self._samples(queue, n, now)
            else:
                text = self._one_event(queue.popleft())
            if text is not None:
                texts.append(text)
        self._sent_in_round = bool(texts)
        return texts

    def echo(self, now_ns: int) -> str | None:
        """The echo that ends a round, stamped `now_ns` (when it is sent: its round trip is the
        clock's), or None when none is due."""
        self._expect("echo")
        last = self._last_echo_ns
        due = (
            last is None
            or self._sent_in_round
            or (bool(self._inflight) and now_ns - last > INFLIGHT_ECHO_NS)
            or now_ns - last > self.echo_interval * 1e9
        )
        self._sent_in_round = False
        if not due:
            return None
        # t0 names the echo's mark: a clock that has not moved since the last must not reuse it
        t0 = now_ns if last is None else max(now_ns, last + 1)
        self._marks[t0] = self._seq
        self._last_echo_ns = t0
        return wire.dumps(wire.Echo(t0))

    def _next(self) -> deque[Any] | None:
        if self._retry:
            return self._retry
        if self._unsent:
            return self._unsent
        return None

    def _samples(self, queue: deque[Any], n: int, now: float) -> str | None:
        """Up to `n` samples from the head of `queue` as one message (None: none sendable)."""
        items = []
        while queue and len(items) < n and isinstance(queue[0], GazeSample):
            items.append(queue.popleft())
        if queue is self._unsent:
            self._pending_samples -= len(items)
        wired = [(s, _to_wire(s, self.info, self._places)) for s in items]
        sendable = [(s, m) for s, m in wired if m is not None]
        self._count_unsendable(len(items) - len(sendable), 0)
        if not sendable:
            return None
        self._bucket.take(len(sendable))
        self._track([s for s, _ in sendable])
        self.stats.samples_sent += len(sendable)
        self.stats.sent_times.append((now, len(sendable)))
        return wire.dumps(wire.Samples(tuple(m for _, m in sendable)))

    def _one_event(self, item: Any) -> str | None:
        message = _to_wire(item, self.info, self._places)
        if message is None:
            self._count_unsendable(0, 1)
            return None
        self._track([item])
        return wire.dumps(message)

    def _count_unsendable(self, samples: int, events: int) -> None:
        if not (samples or events):
            return
        if not (self.stats.samples_unsendable or self.stats.events_unsendable):
            self._warnings.append(
                "not sending records the server would refuse (a negative time, or a fixation "
                "without a position); they are counted, and recorded if --record is given"
            )
        self.stats.samples_unsendable += samples
        self.stats.events_unsendable += events

    def _track(self, items: list[Any]) -> None:
        for item in items:
            self._seq += 1
            self._inflight.append((self._seq, item))
