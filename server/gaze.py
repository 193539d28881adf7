"""How gaze reaches a session: one interface, `GazeInput.at(t)`, for every source.

A session reads its gaze once per step, on the thread that steps it, from the one input it
follows: the viewer's pointer, a gaze daemon's tracker, or a track (the synthetic scan path, a
replayed recording) indexed by the session's simulation time. Pushing sources (the pointer, the
daemons) are written on the server's event loop; what they publish is a `GazeReading`, a frozen
object swapped in with one assignment, so a reader on another thread always sees one whole
reading (never a new x with an old y) and nothing is mutated while it is read.

Several daemons may stream to one server, one per station. Each is a `TrackerFeed` named by the
tracker in its hello; a session follows one by name (`remote:NAME`) and never another station's
eyes. `remote` alone binds to the tracker when exactly one is connected (the usual setup: one
tracker, one server), else waits for the viewer to pick one.

Each input also says how good its gaze is, `figures(frame_rate)`: the accuracy and rate that
the session gives the model as `tracker_accuracy_deg` and `tracker_rate_hz` (the Sec. 5 foveal
blind spot depends on them). The pointer and the synthetic paths are exact (0 deg, read once a
frame); a tracker's accuracy is what its daemon's hello says (`screen.accuracy_deg`) and its
rate what its feed measures from the samples' own times; a replay has its recording's. A
feed's figures are a frozen `TrackerFigures` swapped in like its readings.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeTrack
from gazehdr.protocol import Eyes, Gaze

REMOTE = "remote"
REMOTE_PREFIX = "remote:"
#: What a tracker that gave no name in its hello is called.
UNNAMED = "unnamed tracker"
#: Tracker names a server keeps (connected or named by a session): a viewer choosing ever new
#: `remote:NAME`s must not grow the table without bound.
MAX_TRACKERS = 64


def is_tracker_source(name: str) -> bool:
    """Whether `name` is a gaze source that follows one named tracker, `remote:TRACKER`."""
    return name.startswith(REMOTE_PREFIX) and name != REMOTE_PREFIX


@dataclass(frozen=True)
class GazeReading:
    """Where the eye looks (fractions of the frame, origin top-left) and whether it is open.

    `seq` is the viewer's pointer sequence number (frame headers echo it, so the page can time
    pointer-to-frame latency; 0 for other sources). `received_at` is when a pushed gaze
    reached the server (monotonic seconds; None for tracks): a step whose reading has a new
    one is the first to use that gaze, for the latency metrics."""

    x: float = 0.5
    y: float = 0.5
    eyes_open: bool = True
    seq: int = 0
    received_at: float | None = None


@dataclass(frozen=True)
class TrackerFigures:
    """How good a source's gaze is: its accuracy (degrees) and sample rate (Hz); None where
    the source does not say (the session then leaves that parameter as it is)."""

    accuracy_deg: float | None = None
    rate_hz: float | None = None


#: A tracker's rate is measured over windows of at least this many seconds of its samples; a
#: gap longer than RATE_GAP_S between two samples (a pause, a reconnection) starts a new one.
RATE_WINDOW_S = 1.0
RATE_GAP_S = 0.5
#: A measured rate is published (to three significant figures) when it differs from the one
#: published by more than this fraction: a session rebuilds its eye when the figures change,
#: so jitter in the measurement must not change them.
RATE_CHANGE = 0.02


class GazeInput(Protocol):
    """A session's gaze source: the reading for simulation time `t` (seconds), and the figures
    of its gaze when the session steps at `frame_rate` (Hz)."""

    def at(self, t: float) -> GazeReading: ...

    def figures(self, frame_rate: float) -> TrackerFigures: ...


class LatestGaze:
    """The newest reading of a pushing source (written on the event loop, read anywhere)."""

    def __init__(self, reading: GazeReading | None = None) -> None:
        self.reading = reading or GazeReading()

    def at(self, t: float) -> GazeReading:
        return self.reading

    def figures(self, frame_rate: float) -> TrackerFigures:
        """Exact: where the viewer points is where the model looks, read once a frame."""
        return TrackerFigures(0.0, frame_rate)


class PointerGaze(LatestGaze):
    """The viewer's pointer, and the eyes it closes by holding a key."""

    def take(self, message: object, now: float) -> bool:
        """Apply a viewer's `gaze` or `eyes` message received at `now`; False for any other."""
        r = self.reading
        if isinstance(message, Gaze):  # a new gaze: the latency metrics time it from `now`
            self.reading = GazeReading(message.x, message.y, r.eyes_open, message.seq, now)
        elif isinstance(message, Eyes):
            self.reading = dataclasses.replace(r, eyes_open=message.open)
        else:
            return False
        return True


class TrackGaze:
    """A track replayed from simulation time `start`, looping every `length` seconds. `known`
    are the figures of the tracker that recorded it (a synthetic path has none: exact)."""

    def __init__(
        self,
        track: GazeTrack,
        start: float,
        length: float,
        known: TrackerFigures = TrackerFigures(),
    ) -> None:
        self.track, self.start, self.length = track, start, max(length, 1e-3)
        self.known = known

    def at(self, t: float) -> GazeReading:
        x, y, eyes_open = self.track.at((t - self.start) % self.length)
        return GazeReading(x, y, eyes_open)

    def figures(self, frame_rate: float) -> TrackerFigures:
        """The recording's figures; exact (0 deg, once a frame) for what it does not give."""
        k = self.known
        return TrackerFigures(
            0.0 if k.accuracy_deg is None else k.accuracy_deg,
            frame_rate if k.rate_hz is None else k.rate_hz,
        )


class TrackerFeed(LatestGaze):
    """One daemon's tracker: its newest gaze, its figures, and what the viewers are told of it.

    Written on the event loop only (one connection at a time per feed); `reading` and
    `known` are frozen objects swapped in whole, so sessions read them from any thread."""

    def __init__(self, name: str, moved: Callable[[TrackerFeed], None] | None = None) -> None:
        super().__init__()
        self.name = name
        #: Called (on the event loop) with this feed after each new reading: the server
        #: forwards it to the viewers that warp (`gazehdr.live.LiveSession.forward_gaze`).
        self.moved = moved
        self.connected = False
        self.samples = 0  # samples received, over every connection under this name
        self.events = 0  # fixation and blink events received, likewise
        #: The tracker's figures as far as known: accuracy from the hello, rate measured.
        self.known = TrackerFigures()
        self._window: tuple[int, int, int] | None = None  # first and last t_ns, samples

    def hello(self, accuracy_deg: float | None) -> None:
        """A daemon said hello for this tracker: its accuracy (None: it does not say); the rate
        is measured afresh (the daemon's clock may be another)."""
        self.known = TrackerFigures(accuracy_deg, self.known.rate_hz)
        self._window = None

    def count(self, times_ns: list[int]) -> None:
        """Samples received, by their times on the daemon's clock: every RATE_WINDOW_S of them
        the rate is measured (intervals over the time they span) and, rounded, published."""
        self.samples += len(times_ns)
        for t in times_ns:
            w = self._window
            if w is None or not 0 <= t - w[1] <= RATE_GAP_S * 1e9:  # first, a gap, clock back
                self._window = (t, t, 0)
                continue
            first, _, n = w
            n += 1
            if t - first >= RATE_WINDOW_S * 1e9:
                self._publish_rate(n * 1e9 / (t - first))
                self._window = (t, t, 0)
            else:
                self._window = (first, t, n)

    def _publish_rate(self, rate: float) -> None:
        old = self.known.rate_hz
        if (
            math.isfinite(rate)
            and rate > 0
            and (old is None or abs(rate - old) > RATE_CHANGE * old)
        ):
            self.known = TrackerFigures(self.known.accuracy_deg, float(f"{rate:.3g}"))

    def figures(self, frame_rate: float) -> TrackerFigures:
        return self.known

    def fixate(self, x: float | None, y: float | None, eyes_open: bool, now: float) -> None:
        """A new gaze (None: the place stays where it was, as during a blink)."""
        r = self.reading
        x, y = (r.x, r.y) if x is None or y is None else (x, y)
        self.reading = GazeReading(x, y, eyes_open, received_at=now)
        if self.moved is not None:
            self.moved(self)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "connected": self.connected, "samples": self.samples}


class Trackers:
    """The trackers a server has heard of, by name. Connections come and go on the event loop;
    sessions look feeds up from their threads, so the table is guarded by a lock (the readings
    themselves need none)."""

    def __init__(self) -> None:
        self._feeds: dict[str, TrackerFeed] = {}
        self._lock = threading.Lock()
        #: Called (on the event loop) with a feed whenever it has a new reading (`listen`).
        self._listeners: list[Callable[[TrackerFeed], None]] = []
        #: Open daemon connections, hello or not (counted on the event loop).
        self.connections = 0

    def connect(self, name: str | None) -> TrackerFeed:
        """The feed for a daemon that said hello as `name`. A name already connected (two
        stations whose trackers report the same model) gets a number, so that the sessions of
        one never follow the other; a daemon that reconnects gets its old feed back."""
        base = name or UNNAMED
        with self._lock:
            feed, n = self._feeds.get(base), 1
            while feed is not None and feed.connected:
                n += 1
                feed = self._feeds.get(f"{base} #{n}")
            if feed is None:
                feed = self._new(base if n == 1 else f"{base} #{n}")
            feed.connected = True
            return feed

    def disconnect(self, feed: TrackerFeed) -> None:  # its figures stay: it may come back
        feed.connected = False

    def feed(self, name: str) -> TrackerFeed:
        """The feed named `name`, made now if no daemon has used it yet (a session may bind to
        a station before its daemon connects)."""
        with self._lock:
            return self._feeds.get(name) or self._new(name)

    def sole_connected(self) -> TrackerFeed | None:
        """The connected tracker, when exactly one is."""
        with self._lock:
            connected = [f for f in self._feeds.values() if f.connected]
        return connected[0] if len(connected) == 1 else None

    def feeds(self) -> list[TrackerFeed]:
        """Every tracker heard of, by name."""
        with self._lock:
            return sorted(self._feeds.values(), key=lambda f: f.name)

    def describe(self) -> list[dict[str, Any]]:
        """What the viewers' panel lists."""
        return [f.describe() for f in self.feeds()]

    def listen(self, listener: Callable[[TrackerFeed], None]) -> None:
        """Have `listener` called with each feed that has a new reading, as it arrives: the
        sessions step at their own rate, their viewers may want the gaze sooner."""
        self._listeners.append(listener)

    def _moved(self, feed: TrackerFeed) -> None:
        for listener in self._listeners:
            listener(feed)

    def _new(self, name: str) -> TrackerFeed:
        if len(self._feeds) >= MAX_TRACKERS:
            raise InputError(f"this server knows {MAX_TRACKERS} tracker names already")
        feed = self._feeds[name] = TrackerFeed(name, self._moved)
        return feed
