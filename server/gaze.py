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
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass
from typing import Any, Protocol

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


class GazeInput(Protocol):
    """A session's gaze source: the reading for simulation time `t` (seconds)."""

    def at(self, t: float) -> GazeReading: ...


class LatestGaze:
    """The newest reading of a pushing source (written on the event loop, read anywhere)."""

    def __init__(self, reading: GazeReading | None = None) -> None:
        self.reading = reading or GazeReading()

    def at(self, t: float) -> GazeReading:
        return self.reading


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
    """A track replayed from simulation time `start`, looping every `length` seconds."""

    def __init__(self, track: GazeTrack, start: float, length: float) -> None:
        self.track, self.start, self.length = track, start, max(length, 1e-3)

    def at(self, t: float) -> GazeReading:
        x, y, eyes_open = self.track.at((t - self.start) % self.length)
        return GazeReading(x, y, eyes_open)


class TrackerFeed(LatestGaze):
    """One daemon's tracker: its newest gaze, and what the viewers are told of it."""

    def __init__(self, name: str) -> None:
        super().__init__()
        self.name = name
        self.connected = False
        self.samples = 0  # samples received, over every connection under this name
        self.events = 0  # fixation and blink events received, likewise

    def fixate(self, x: float | None, y: float | None, eyes_open: bool, now: float) -> None:
        """A new gaze (None: the place stays where it was, as during a blink)."""
        r = self.reading
        x, y = (r.x, r.y) if x is None or y is None else (x, y)
        self.reading = GazeReading(x, y, eyes_open, received_at=now)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "connected": self.connected, "samples": self.samples}


class Trackers:
    """The trackers a server has heard of, by name. Connections come and go on the event loop;
    sessions look feeds up from their threads, so the table is guarded by a lock (the readings
    themselves need none)."""

    def __init__(self) -> None:
        self._feeds: dict[str, TrackerFeed] = {}
        self._lock = threading.Lock()
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

    def disconnect(self, feed: TrackerFeed) -> None:
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

    def _new(self, name: str) -> TrackerFeed:
        if len(self._feeds) >= MAX_TRACKERS:
            raise ValueError(f"this server knows {MAX_TRACKERS} tracker names already")
        feed = self._feeds[name] = TrackerFeed(name)
        return feed
