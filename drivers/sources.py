"""Gaze sources behind one interface: iterate for timestamped samples, read `info` for the rest.

A `Source` yields `GazeSample`s (monotonic nanoseconds on the source's clock, screen pixels,
validity, per-eye fields where the tracker reports them) and describes itself with a
`SourceInfo` (tracker name, `ScreenGeometry`, nominal rate). A source that also carries
fixation and blink events (a replayed session log) yields them from `records()`, interleaved
with its samples in the order they were first emitted; plain sources' `records()` is their
samples. A recording may also say where its fixations are before they end
(`fixation_places()`, see `fixation_places_of`).

`gazehdr.drivers.registry.open_source(spec)` opens one from a command-line spec; each kind's
opener gets a `samples.StreamRequest`. The synthetic scan path's source is here (`synthetic[:SEED]`,
`open_synthetic`); the others live in their own modules (`replay`, `hid`), which import this
one and never the other way round.

`screen` (`ScreenGeometry` field names → values, e.g. from `gazehdr daemon --screen
--diagonal --distance`) says what the user knows about the screen: it sets the synthetic
source's geometry, fills in what an imported recording does not record (as `gazehdr import`'s
flags do; a native log's header is kept), and overrides what a HID tracker reports.

Pacing goes through an injectable clock and sleep, so tests run without waiting. Nothing here
imports `server` or pyopencl.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar, runtime_checkable

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry, StreamRequest
from gazehdr.drivers.synthetic import SyntheticScanPath

T = TypeVar("T")
Clock = Callable[[], int]  # monotonic nanoseconds
Sleep = Callable[[float], None]  # seconds

#: Chunk of synthetic scan path planned at once; an endless source chains chunks.
SYNTHETIC_CHUNK_S = 600.0
DEFAULT_SYNTHETIC_RATE_HZ = 250.0


@dataclass(frozen=True)
class SourceInfo:
    """What a source is: tracker name, screen geometry, nominal rate, and how it behaves.

    `live` sources produce samples whether or not anyone reads them (a tracker): a consumer that
    falls behind must drop. A source that is not live (a replay) simply waits to be read.
    `has_events` says that `records()` carries the source's own fixation and blink events.
    `tracker` is the free-form description a session log header keeps. `accuracy_deg` is the
    tracker's accuracy in degrees (its calibration's or data sheet's; None: not known), which
    the daemon's hello passes on (`screen.accuracy_deg`, drivers/wire.py).
    """

    name: str
    geometry: ScreenGeometry = field(default_factory=ScreenGeometry)
    rate_hz: float | None = None
    live: bool = True
    has_events: bool = False
    tracker: dict[str, Any] = field(default_factory=dict)
    accuracy_deg: float | None = None

    def header_tracker(self) -> dict[str, Any]:
        """The `tracker` object of a session log header recording this source."""
        out: dict[str, Any] = {"name": self.name, **self.tracker}
        if self.rate_hz is not None:
            out.setdefault("rate_hz", self.rate_hz)
        if self.accuracy_deg is not None:
            out.setdefault("accuracy_deg", self.accuracy_deg)
        return out


@runtime_checkable
class Source(Protocol):
    """One gaze source: `info`, and iteration over its samples in time order."""

    info: SourceInfo

    def __iter__(self) -> Iterator[GazeSample]: ...


def records_of(source: Any) -> Iterator[Any]:
    """A source's records: samples and, where it has them, its own events, in emitted order."""
    records = getattr(source, "records", None)
    return records() if callable(records) else iter(source)


def fixation_places_of(source: Any) -> Mapping[tuple[int, str | None], Any] | None:
    """Where a source's fixations are, keyed by (event id, eye), each with `x` and `y` in
    pixels: what a recording (`replay.ReplaySource`) knows of a fixation before it ends.
    None for a source that does not say, whose events carry their own positions (a live
    detector's do)."""
    places = getattr(source, "fixation_places", None)
    return places() if callable(places) else None


class Pacer:
    """Holds records back until their time has come: `t_ns` maps to the wall clock at `speed`.

    The first record passes at once and anchors the mapping. Times that go back (an event
    stamped before the sample that completed it) never wait. `speed=math.inf` never waits.
    """

    def __init__(
        self, speed: float = 1.0, *, clock: Clock | None = None, sleep: Sleep | None = None
    ) -> None:
        if not (speed > 0 and not math.isnan(speed)):
            raise InputError(f"speed must be a positive number or inf, got {speed}")
        self.speed = speed
        self.clock = clock or time.monotonic_ns
        self.sleep = sleep or time.sleep
        self._anchor: tuple[int, int] | None = None  # (record t, wall t)

    def wait(self, t_ns: int) -> None:
        if math.isinf(self.speed):
            return
        if self._anchor is None:
            self._anchor = (t_ns, self.clock())
            return
        t0, wall0 = self._anchor
        due = wall0 + (t_ns - t0) / self.speed
        delay_ns = due - self.clock()
        if delay_ns > 0:
            self.sleep(delay_ns / 1e9)


class IterableSource:
    """Any iterable of samples (and events) as a source, optionally paced on its times."""

    def __init__(
        self,
        records: Iterable[Any],
        info: SourceInfo,
        *,
        speed: float = math.inf,
        clock: Clock | None = None,
        sleep: Sleep | None = None,
    ) -> None:
        self.info = info
        self._records = records
        self._pacing = (speed, clock, sleep)

    def records(self) -> Iterator[Any]:
        speed, clock, sleep = self._pacing
        pacer = Pacer(speed, clock=clock, sleep=sleep)
        for record in self._records:
            pacer.wait(record.t_ns)
            yield record

    def __iter__(self) -> Iterator[GazeSample]:
        return (r for r in self.records() if isinstance(r, GazeSample))


class SyntheticSource:
    """A seeded synthetic scan path as a live source at `rate_hz`.

    Sample times are `start_ns` (default: the clock when iteration starts) plus the path's own
    time, so a real-time source stamps samples on the monotonic clock like a tracker would.
    `duration=None` runs for ever, chaining independently seeded chunks of the path
    (`seed`, `seed + 1`, ...); `realtime=False` emits as fast as the reader takes them.
    `paths` holds the chunks planned so far (their fixations and blinks are the ground truth,
    shifted by `chunk * SYNTHETIC_CHUNK_S`).
    """

    def __init__(
        self,
        seed: int = 0,
        rate_hz: float = DEFAULT_SYNTHETIC_RATE_HZ,
        *,
        duration: float | None = None,
        realtime: bool = True,
        geometry: ScreenGeometry | None = None,
        start_ns: int | None = None,
        clock: Clock | None = None,
        sleep: Sleep | None = None,
        **path_options: Any,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"rate_hz must be a finite positive number, got {rate_hz}")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise InputError("duration must be a finite positive number of seconds or None")
        self.seed = seed
        self.rate_hz = float(rate_hz)
        self.duration = duration
        self.realtime = realtime
        self.geometry = geometry or ScreenGeometry()
        self.start_ns = start_ns
        self.clock = clock or time.monotonic_ns
        self.sleep = sleep
        self.path_options = path_options
        self.paths: list[SyntheticScanPath] = []
        self.info = SourceInfo(
            name=f"synthetic (seed {seed})",
            geometry=self.geometry,
            rate_hz=self.rate_hz,
            live=True,
            tracker={"source": "synthetic", "seed": seed},
        )

    def _chunk(self, index: int) -> SyntheticScanPath:
        while len(self.paths) <= index:
            n = len(self.paths)
            length = SYNTHETIC_CHUNK_S
            if self.duration is not None:
                length = min(SYNTHETIC_CHUNK_S, self.duration - n * SYNTHETIC_CHUNK_S)
            self.paths.append(
                SyntheticScanPath(
                    self.seed + n, length, geometry=self.geometry, **self.path_options
                )
            )
        return self.paths[index]

    def _unpaced(self, start_ns: int) -> Iterator[GazeSample]:
        chunk = 0
        while True:
            path = self._chunk(chunk)
            base = start_ns + round(chunk * SYNTHETIC_CHUNK_S * 1e9)
            last = self.duration is not None and (chunk + 1) * SYNTHETIC_CHUNK_S >= self.duration
            end_ns = round(path.duration * 1e9)
            for s in path.samples(self.rate_hz):
                if s.t_ns >= end_ns and not last:
                    break  # the next chunk starts here
                yield GazeSample(base + s.t_ns, s.x, s.y, s.valid)
            if last:
                return
            chunk += 1

    def __iter__(self) -> Iterator[GazeSample]:
        start_ns = self.clock() if self.start_ns is None else self.start_ns
        pacer = Pacer(1.0 if self.realtime else math.inf, clock=self.clock, sleep=self.sleep)
        for sample in self._unpaced(start_ns):
            pacer.wait(sample.t_ns)
            yield sample

    def records(self) -> Iterator[GazeSample]:
        return iter(self)


def open_synthetic(request: StreamRequest) -> SyntheticSource:
    """The `synthetic[:SEED]` stream: `rate_hz` (default 250 Hz), paced in real time unless
    `realtime` is False."""
    try:
        seed = int(request.arg) if request.arg else 0
    except ValueError:
        raise InputError(f"synthetic:SEED needs an integer seed, got {request.arg!r}") from None
    return SyntheticSource(
        seed,
        request.rate_hz or DEFAULT_SYNTHETIC_RATE_HZ,
        realtime=request.realtime,
        geometry=request.screen_geometry(),
        clock=request.clock,
        sleep=request.sleep,
        **request.options,
    )
