"""The `lsl[:QUERY]` gaze source: a tracker's LSL stream through a pylsl inlet.

I/O only; what the stream's description and values mean is `meta`'s, and the clock arithmetic
`clock`'s. The source resolves one stream (`meta.stream_predicate`: a gaze type, a name,
`PROPERTY=VALUE` or an XPath predicate) and refuses when several match, naming them. It reads
the full description from the inlet, so the channel layout is the outlet's own, and stamps each
sample with its LSL time corrected by `time_correction()` and put on this machine's monotonic
clock.

When the stream goes (its app quits, the tracker's machine reboots) the inlet raises LostError:
the source notes it, and resolves the same stream again (by its source_id, else its name and
host) with exponential back-off, forever unless `give_up_after_s`; a stream that comes back is
read from its new start, with a new clock correction. Samples already yielded stay yielded (the
generator never buffers), and what happened goes into the session log as notes (`records()`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from typing import Any

from gazehdr.drivers.backoff import retry
from gazehdr.drivers.errors import GazehdrError, InputError
from gazehdr.drivers.lsl import load_pylsl
from gazehdr.drivers.lsl.clock import ClockLink, StreamClock
from gazehdr.drivers.lsl.meta import (
    MIN_CONFIDENCE,
    ChannelLayout,
    StreamDescription,
    channel_layout,
    stream_predicate,
)
from gazehdr.drivers.registry import SourceUnavailableError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry, StreamRequest
from gazehdr.drivers.sessionlog import Note
from gazehdr.drivers.sources import SourceInfo
from gazehdr.drivers.states import InvalidStateError, Link

log = logging.getLogger(__name__)

CORRECTION_EVERY_S = 1.0  # how often the clock correction is read (liblsl refreshes it itself)


class AmbiguousStreamError(GazehdrError, LookupError):
    """Several streams match the query; the text names them."""


class LslGazeSource:
    """Gaze samples from an LSL stream, reconnecting when it goes and comes back.

    `query` is what follows `lsl:`. `geometry` is the screen (normalised channels scale by its
    size in pixels; default `ScreenGeometry()`), `screen` overrides single fields of it.
    Samples whose stream confidence is below `min_confidence` are invalid. With `open_now` the
    constructor resolves the stream and raises OSError when there is none (LookupError when
    several match, LayoutError when it carries no usable gaze); else the first read waits for
    it. `give_up_after_s` ends the iteration with an OSError when no stream was found for that
    long (None: keep trying). `clock`/`sleep` (seconds, the back-off) and `clock_ns` (the
    monotonic clock samples are stamped in) are injectable.
    """

    def __init__(
        self,
        query: str = "",
        *,
        geometry: ScreenGeometry | None = None,
        screen: Mapping[str, float] | None = None,
        min_confidence: float = MIN_CONFIDENCE,
        resolve_timeout_s: float = 1.0,
        open_timeout_s: float = 5.0,
        pull_timeout_s: float = 0.2,
        backoff_initial_s: float = 0.25,
        backoff_max_s: float = 5.0,
        give_up_after_s: float | None = None,
        open_now: bool = True,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.predicate = stream_predicate(query)
        self.lsl = load_pylsl()
        base = geometry or ScreenGeometry()
        self.geometry = replace(base, **dict(screen or {}))
        if not 0 <= min_confidence <= 1:
            raise InputError(f"min_confidence must lie in [0, 1], got {min_confidence}")
        self.min_confidence = min_confidence
        self.resolve_timeout_s, self.open_timeout_s = resolve_timeout_s, open_timeout_s
        self.pull_timeout_s = pull_timeout_s
        self.backoff_initial_s, self.backoff_max_s = backoff_initial_s, backoff_max_s
        self.give_up_after_s = give_up_after_s
        self._clock, self._sleep, self._clock_ns = clock, sleep, clock_ns
        self.link = ClockLink.measure(self.lsl.local_clock, clock_ns)
        self.layout: ChannelLayout | None = None
        self.inlet: Any = None
        self.stream_clock: StreamClock | None = None
        self._pinned: str | None = None  # the stream found first, found again after a loss
        self.samples_yielded = 0
        self.reconnects = 0
        self._closed = False
        self._notes: list[Note] = []
        if open_now:
            self.connect()

    @property
    def info(self) -> SourceInfo:
        """Name, screen, nominal rate and the stream's details, for the session log header."""
        if self.layout is None:
            return SourceInfo(name="lsl", geometry=self.geometry, live=True)
        stream = self.layout.stream
        tracker: dict[str, Any] = {
            "source": "lsl",
            "stream": stream.name,
            "type": stream.type,
            "source_id": stream.source_id,
            "hostname": stream.hostname,
            "channels": self.layout.describe(),
            **{k: v for k, v in stream.acquisition().items() if v},
        }
        rate = stream.nominal_srate or None
        return SourceInfo(f"lsl {stream.name}", self.geometry, rate, tracker=tracker)

    # connection

    def _resolve(self) -> Any:
        """The one stream the query names (pinned after the first); OSError when none."""
        predicate = self._pinned or self.predicate
        # two are waited for on the first resolve, so that a second match is seen
        wanted = 1 if self._pinned else 2
        found = self.lsl.resolve_bypred(predicate, wanted, self.resolve_timeout_s)
        if not found:
            raise OSError(f"no LSL stream matches {predicate}")
        if len({(s.source_id() or s.uid()) for s in found}) > 1:
            names = "; ".join(
                f"'{s.name()}' ({s.type()}) on {s.hostname()}, source_id {s.source_id()!r}"
                for s in found
            )
            raise AmbiguousStreamError(
                f"several LSL streams match {predicate}: {names}; name one, e.g. "
                f"lsl:source_id=ID or lsl:NAME"
            )
        return found[0]

    @property
    def connection_state(self) -> Link:
        """The connection's state: CLOSED once closed, else whether it is connected."""
        if self._closed:
            return Link.CLOSED
        return Link.DISCONNECTED if self.inlet is None else Link.CONNECTED

    def connect(self) -> ChannelLayout:
        """Resolve, open an inlet and read its description (its layout, returned) and clock
        correction once. Refused while an inlet is open (it would leak) and once closed."""
        if self.connection_state is not Link.DISCONNECTED:
            raise InvalidStateError(
                "LslGazeSource", "connect", self.connection_state, "not connected"
            )
        found = self._resolve()
        inlet = self.lsl.StreamInlet(found, max_buflen=360, recover=False)
        try:
            full = inlet.info(self.open_timeout_s)
            stream = StreamDescription.from_xml(full.as_xml())
            layout = channel_layout(stream)
            inlet.open_stream(self.open_timeout_s)
            offset = inlet.time_correction(self.open_timeout_s)
        except (self.lsl.util.TimeoutError, self.lsl.util.LostError) as e:
            inlet.close_stream()
            raise OSError(f"LSL stream '{found.name()}' did not answer: {e}") from None
        except BaseException:
            inlet.close_stream()
            raise
        self.inlet, self.layout = inlet, layout
        self.stream_clock = StreamClock(self.link, offset)
        self._pinned = stream.pinned_predicate()
        self._note(
            f"LSL stream {stream.title()} connected; clock correction {offset * 1e3:+.3f} ms"
        )
        log.info("LSL stream %s connected", stream.title())
        return layout

    def _note(self, text: str) -> None:
        self._notes.append(Note(self._clock_ns(), text))

    def wait_for_stream(self) -> None:
        """Connect, waiting with back-off until the stream is there (a message per attempt);
        OSError after `give_up_after_s`. How `gazehdr daemon --source lsl` starts."""
        if not self._reconnect():
            raise OSError("the LSL source was closed while waiting for its stream")

    def _reconnect(self) -> bool:
        """Connect with back-off; False when the source was closed meanwhile."""
        layout = retry(
            self.connect,
            name="LSL stream",
            missing="LSL stream",
            closed=lambda: self._closed,
            log=log,
            initial_s=self.backoff_initial_s,
            max_s=self.backoff_max_s,
            give_up_after_s=self.give_up_after_s,
            sleep=self._sleep,
            clock=self._clock,
        )
        return layout is not None

    def _drop(self, why: str) -> None:
        self.reconnects += 1
        text = (
            f"LSL stream lost ({why}); {self.samples_yielded} samples received so far are kept; "
            "reconnecting"
        )
        log.warning("%s", text)
        self._note(text)
        inlet, self.inlet = self.inlet, None
        if inlet is not None:
            inlet.close_stream()

    def close(self) -> None:
        """Stop: the running iteration ends at its next read (within `pull_timeout_s`)."""
        self._closed = True

    # the stream

    def records(self) -> Iterator[GazeSample | Note]:
        """Samples, and notes of what happened to the stream (connected, lost, clock)."""
        next_correction = 0.0
        while not self._closed:
            yield from self._take_notes()  # before waiting for a lost stream: the loss
            if self.inlet is None:
                if not self._reconnect():
                    break
                continue
            try:
                chunk, stamps = self.inlet.pull_chunk(
                    timeout=self.pull_timeout_s, max_samples=1024, min_samples=1
                )
                if self._clock() >= next_correction:
                    next_correction = self._clock() + CORRECTION_EVERY_S
                    self._correct()
            except self.lsl.util.LostError as e:
                self._drop(str(e))
                continue
            yield from self._samples(chunk, stamps)
        yield from self._take_notes()
        if self.inlet is not None:
            self.inlet.close_stream()
            self.inlet = None

    def _take_notes(self) -> Iterator[Note]:
        notes, self._notes = self._notes, []
        yield from notes

    def _correct(self) -> None:
        assert self.stream_clock is not None
        if self.inlet.was_clock_reset():
            self._note("the LSL stream's clock was reset")
        change = self.stream_clock.correct(self.inlet.time_correction(self.open_timeout_s))
        if change is not None:
            self._note(
                f"LSL clock correction now {self.stream_clock.offset_s * 1e3:+.3f} ms "
                f"({change * 1e3:+.3f} ms)"
            )

    def _samples(self, chunk: list[Any], stamps: list[float]) -> Iterator[GazeSample]:
        assert self.layout is not None and self.stream_clock is not None
        for values, stamp in zip(chunk, stamps, strict=True):
            if not math.isfinite(stamp):
                continue
            t_ns = self.stream_clock.t_ns(stamp)
            self.samples_yielded += 1
            yield self.layout.sample(values, t_ns, self.geometry, self.min_confidence)

    def __iter__(self) -> Iterator[GazeSample]:
        return (r for r in self.records() if isinstance(r, GazeSample))


def open_lsl(request: StreamRequest) -> LslGazeSource:
    """The `lsl[:QUERY]` stream of `gazehdr.drivers.registry`; with `wait`, waits for the
    stream to appear. SourceUnavailableError when there is none, several match, or it carries
    no usable gaze (the registry reports a missing pylsl, an ImportError)."""
    options = dict(request.options)
    options.setdefault("geometry", request.geometry)
    options.setdefault("screen", request.screen)
    options.setdefault("open_now", not request.wait)
    try:
        source = LslGazeSource(request.arg, **options)
        if request.wait:
            source.wait_for_stream()
        return source
    except (OSError, LookupError, ValueError) as e:
        raise SourceUnavailableError(f"LSL source unavailable: {e}") from None
