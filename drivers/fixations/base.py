"""What both detectors share: running the stages, a fixation's running statistics, ids, events.

Angles come from `ScreenGeometry.pixels_per_degree` (the linear, small-angle map at the screen
centre that the model uses for its own sizes). Tobii measure the angle from the eye's position
per sample; a screen-only source has no eye position, so we use the nominal viewing distance.

Delay is inherent: the merge and discard rules need lookahead. `max_delay_ns()` gives, per event
kind, a bound `D` such that an event with time `t_ns` has been returned by the time the detector
is fed a sample later than `t_ns + D` (see each detector's docstring for the terms).
"""

from __future__ import annotations

import math
from typing import Any

from gazehdr.drivers.fixations.events import Event, EventKind
from gazehdr.drivers.fixations.params import IDTParams, IVTParams, _ms_to_ns
from gazehdr.drivers.fixations.stages import _GapFill
from gazehdr.drivers.samples import GazeSample, ScreenGeometry


class _Group:
    """Running statistics of one fixation (or fixation candidate)."""

    __slots__ = (
        "active",
        "confirmed",
        "end",
        "id",
        "last_report",
        "maxx",
        "maxy",
        "minx",
        "miny",
        "n",
        "start",
        "sx",
        "sy",
    )

    def __init__(self, t: int, x: float, y: float) -> None:
        self.start = self.end = t
        self.n = 1
        self.sx, self.sy = x, y
        self.minx = self.maxx = x
        self.miny = self.maxy = y
        self.active = True  # still receiving samples
        self.confirmed = False
        self.id = 0
        self.last_report = t

    def add(self, t: int, x: float, y: float) -> None:
        self.end = t
        self.n += 1
        self.sx += x
        self.sy += y
        if x < self.minx:
            self.minx = x
        elif x > self.maxx:
            self.maxx = x
        if y < self.miny:
            self.miny = y
        elif y > self.maxy:
            self.maxy = y

    def absorb(self, other: _Group) -> None:
        self.end = other.end
        self.n += other.n
        self.sx += other.sx
        self.sy += other.sy
        self.minx = min(self.minx, other.minx)
        self.maxx = max(self.maxx, other.maxx)
        self.miny = min(self.miny, other.miny)
        self.maxy = max(self.maxy, other.maxy)
        self.active = other.active

    @property
    def mean(self) -> tuple[float, float]:
        return self.sx / self.n, self.sy / self.n


class _Detector:
    """The parts both detectors share: preprocessing, ids, and making events."""

    params: IVTParams | IDTParams

    def __init__(self, geometry: ScreenGeometry | None, params: IVTParams | IDTParams) -> None:
        self.geometry = geometry or ScreenGeometry()
        self.params = params
        self._ppd = self.geometry.pixels_per_degree
        self._max_gap_ns = _ms_to_ns(params.max_gap_ms)
        self._max_blink_ns = _ms_to_ns(params.max_blink_ms)
        self._min_ns = _ms_to_ns(params.min_fixation_ms)
        self._update_ns = _ms_to_ns(params.update_interval_ms)
        self._gapfill = _GapFill(self._max_gap_ns, self._max_blink_ns)
        self._stages: list[Any] = []
        self._next_id = 1

    def feed(self, sample: GazeSample) -> list[Event]:
        """Take the next sample; return the events that became certain with it.

        Raises `ValueError` naming the sample's index in the stream and its time if its
        timestamp is not an integer or does not increase; the detector is then unchanged.
        """
        return self._run(self._gapfill.push(sample))

    def flush(self) -> list[Event]:
        """End of stream: return the pending events. Feeding may go on (later timestamps)."""
        return self._run(self._gapfill.flush())

    def _run(self, items: list[tuple]) -> list[Event]:
        for stage in self._stages:
            if not items:
                return []
            items = stage.process(items)
        events: list[Event] = []
        for item in items:
            self._assemble(item, events)
        return events

    def _assemble(self, item: tuple, events: list[Event]) -> None:
        raise NotImplementedError

    def _blink(self, item: tuple, events: list[Event]) -> None:
        _, start, end = item
        blink_id = self._take_id()
        nan = math.nan
        events.append(Event("blink_start", blink_id, start, nan, nan, end - start))
        events.append(Event("blink_end", blink_id, end, nan, nan, end - start))

    def _take_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    def _fixation_event(self, kind: EventKind, g: _Group, t: int) -> Event:
        x, y = g.mean
        dispersion = ((g.maxx - g.minx) + (g.maxy - g.miny)) / self._ppd
        return Event(kind, g.id, t, x, y, g.end - g.start, dispersion)

    def _grown(self, g: _Group, events: list[Event]) -> None:
        """After `g` gained samples: confirm it once long enough, or report progress."""
        if not g.confirmed:
            if g.end - g.start >= self._min_ns:
                g.confirmed = True
                g.id = self._take_id()
                g.last_report = g.end
                events.append(self._fixation_event("fixation_start", g, g.start))
        elif g.end - g.last_report >= self._update_ns:
            g.last_report = g.end
            events.append(self._fixation_event("fixation_update", g, g.end))

    def _finish(self, g: _Group, events: list[Event]) -> None:
        if g.confirmed:
            events.append(self._fixation_event("fixation_end", g, g.end))

    def _gap_hold_ns(self, dt: int) -> int:
        return self._max_gap_ns + dt

    def max_delay_ns(self, sample_interval_ns: int) -> dict[str, int]:
        """Per event kind, a bound D: an event with time t_ns has been returned by the time
        the detector is fed a sample later than t_ns + D, when no two successive samples are
        more than `sample_interval_ns` apart (invalid samples included)."""
        raise NotImplementedError
