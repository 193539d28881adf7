"""Online fixation and blink detection: I-VT with Tobii's defaults, and I-DT.

Both detectors are incremental: `feed(sample)` takes one `GazeSample` (screen pixels, monotonic
nanoseconds; an invalid sample has NaN coordinates) and returns the events that became certain
with it; `flush()` ends the stream and returns what was still pending. They are pure: the same
samples always give the same events, whatever the wall clock or the machine. Pick one by name
with `make_detector("ivt" | "idt", geometry, **params)`.

Angles come from `ScreenGeometry.pixels_per_degree` (the linear, small-angle map at the screen
centre that the model uses for its own sizes). Tobii measure the angle from the eye's position
per sample; a screen-only source has no eye position, so we use the nominal viewing distance.

Preprocessing, shared by both detectors (Olsen 2012, "The Tobii I-VT Fixation Filter",
Tobii Technology, §2.4 "Gap fill in"):

- A run of invalid samples is timed from its first invalid sample to the first valid sample
  after it (for regular sampling: the number of invalid samples times the sample interval).
  A run of at most `max_gap_ms` (75 ms) between two valid samples is filled by linear
  interpolation, and detection carries on as if nothing had happened.
- A longer run breaks the data: the fixation in progress ends at its last valid sample, and
  nothing merges across the break. If the run lasted at most `max_blink_ms` (500 ms; human
  blinks last about 100-400 ms) and had valid samples on both sides, it is a **blink**:
  `blink_start` at the first invalid sample, `blink_end` at the first valid sample after it, both
  emitted when the run ends (only then is it known not to be a longer loss). A longer run is a
  lost track and gives no blink events; so does a run at the start or end of the stream, whose
  duration is unknown.
- Valid samples more than `max_gap_ms` apart with nothing in between (a source that dropped
  samples) also break the data, without a blink.

Events (`Event`): `fixation_start` once a fixation is certain (its `t_ns` is the fixation's first
sample, so it lies in the past), `fixation_update` with the mean position so far at most every
`update_interval_ms` of sample time, `fixation_end` with the mean position, dispersion and
duration, and `blink_start`/`blink_end`. A fixation's events share one `id`, as do a blink's
two; ids increase in the order fixations and blinks are first reported. Dispersion is Salvucci
and Goldberg's: (max x − min x) + (max y − min y), in degrees. A fixation spans its first to its
last sample (`duration_ns` = last − first).

The simulation follows the current fixation, and a saccade does not smear the retinal state
(SPEC §4): a consumer should move its gaze to the `x, y` of `fixation_start` and
`fixation_update`, hold it through saccades, and not follow raw samples.

Delay is inherent: the merge and discard rules need lookahead. `max_delay_ns()` gives, per event
kind, a bound `D` such that an event with time `t_ns` has been returned by the time the detector
is fed a sample later than `t_ns + D` (see each detector's docstring for the terms).
"""

from __future__ import annotations

import math
import numbers
import statistics
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, fields
from typing import Any, Literal, Protocol, runtime_checkable

from gazehdr.drivers.samples import Fixation, GazeSample, ScreenGeometry

EventKind = Literal["fixation_start", "fixation_update", "fixation_end", "blink_start", "blink_end"]
EVENT_KINDS: tuple[str, ...] = (
    "fixation_start",
    "fixation_update",
    "fixation_end",
    "blink_start",
    "blink_end",
)

#: Window edges tolerate this much timestamp rounding (ns), so that a 300 Hz stream whose
#: timestamps were rounded to whole nanoseconds still gets the full 20 ms velocity window.
_EDGE_SLACK_NS = 1_000


@dataclass(frozen=True)
class Event:
    """A fixation or blink event. Positions are screen pixels; blinks carry NaN positions.

    `duration_ns` and `dispersion_deg` are the values so far for `fixation_start` and
    `fixation_update`, final for `fixation_end`; a blink's events both carry its duration and
    no dispersion (None).
    """

    kind: EventKind
    id: int
    t_ns: int
    x: float
    y: float
    duration_ns: int | None = None
    dispersion_deg: float | None = None


def _ms_to_ns(ms: float) -> int:
    return round(ms * 1_000_000)


def _check_params(params: Any, positive: tuple[str, ...]) -> None:
    """Every numeric field finite and non-negative; the `positive` ones strictly positive."""
    for f in fields(params):
        value = getattr(params, f.name)
        if isinstance(value, str):
            continue
        if (
            isinstance(value, bool)
            or not isinstance(value, numbers.Real)
            or not math.isfinite(value)
            or value < 0
        ):
            raise ValueError(f"{f.name} must be a finite non-negative number, got {value!r}")
        if f.name in positive and value == 0:
            raise ValueError(f"{f.name} must be positive, got {value!r}")
    if params.max_blink_ms < params.max_gap_ms:
        raise ValueError(
            f"max_blink_ms ({params.max_blink_ms}) must be at least max_gap_ms "
            f"({params.max_gap_ms}): a blink is a gap too long to fill"
        )


@dataclass(frozen=True)
class IVTParams:
    """Tobii I-VT fixation filter settings, with Tobii's defaults (Olsen 2012; the defaults are
    justified in Tobii's companion white paper "Determining the Tobii I-VT Fixation Filter's
    Default Values", 2012). Section numbers below are Olsen's §2.

    - `velocity_threshold_deg_s` (30): a sample is a fixation sample if its angular velocity is
      below this (§2.1 "I-VT filters"; the "I-VT classifier" step).
    - `velocity_window_ms` (20): the velocity of a sample is the angle between the first and the
      last sample within ±window/2 of it, over their time difference (the "velocity
      calculator" step). When the window holds no other sample (below 100 Hz for 20 ms), the
      neighbouring samples on each side are used instead.
    - `max_gap_ms` (75): gap fill-in, the longest run of invalid samples interpolated (§2.4).
    - `merge_max_gap_ms` (75) and `merge_max_angle_deg` (0.5): consecutive fixations are merged
      when less than this time lies between the last sample of one and the first of the next,
      and less than this angle between their mean positions (§2.6 "Check for fixations located
      close in time and close in space"). 0 turns merging off.
    - `min_fixation_ms` (60): a fixation shorter than this after merging is discarded; its
      samples stay unclassified (§2.7 "Check for short fixations"). 0 keeps every fixation.
    - `noise_reduction` ("none", Tobii's default; or "median" or "average") over a centred
      window of `noise_window_samples` samples (§2.2 "Noise", §2.3 "Low pass filters").
    - ours: `max_blink_ms` (500), the longest invalid run reported as a blink;
      `update_interval_ms` (50), the least sample time between `fixation_update` events.
    """

    velocity_threshold_deg_s: float = 30.0
    velocity_window_ms: float = 20.0
    max_gap_ms: float = 75.0
    merge_max_gap_ms: float = 75.0
    merge_max_angle_deg: float = 0.5
    min_fixation_ms: float = 60.0
    noise_reduction: Literal["none", "median", "average"] = "none"
    noise_window_samples: int = 3
    max_blink_ms: float = 500.0
    update_interval_ms: float = 50.0

    def __post_init__(self) -> None:
        _check_params(
            self, ("velocity_threshold_deg_s", "velocity_window_ms", "noise_window_samples")
        )
        if self.noise_reduction not in ("none", "median", "average"):
            raise ValueError(
                "noise_reduction must be 'none', 'median' or 'average', "
                f"got {self.noise_reduction!r}"
            )
        if not isinstance(self.noise_window_samples, int) or self.noise_window_samples % 2 != 1:
            raise ValueError(
                f"noise_window_samples must be an odd integer, got {self.noise_window_samples!r}"
            )


@dataclass(frozen=True)
class IDTParams:
    """I-DT settings (Salvucci & Goldberg 2000): dispersion threshold and minimum duration.

    - `dispersion_threshold_deg` (1): a window of samples is a fixation while
      (max x − min x) + (max y − min y) stays at most this, in degrees.
    - `min_fixation_ms` (100): the window must span at least this before it is a fixation.
    - `max_gap_ms`, `max_blink_ms`, `update_interval_ms`: as for `IVTParams` (I-DT itself says
      nothing about missing data; we use the same gap fill-in and blink rule).
    """

    dispersion_threshold_deg: float = 1.0
    min_fixation_ms: float = 100.0
    max_gap_ms: float = 75.0
    max_blink_ms: float = 500.0
    update_interval_ms: float = 50.0

    def __post_init__(self) -> None:
        _check_params(self, ("dispersion_threshold_deg",))


# --- Items flowing between stages: tuples, for speed. -------------------------------------------
# ("p", t, x, y)                 a valid (or gap-filled) point
# ("c", t, x, y, is_fixation)    a point classified by the velocity stage
# ("b",)                         a break: nothing before it continues after it
# ("k", start_ns, end_ns)        a blink (always right after a break)
_BREAK = ("b",)


class _GapFill:
    """Validation, gap fill-in, breaks and blinks (see the module docstring)."""

    def __init__(self, max_gap_ns: int, max_blink_ns: int) -> None:
        self.max_gap_ns = max_gap_ns
        self.max_blink_ns = max_blink_ns
        self.index = 0  # index of the next sample in the stream, for error messages
        self.prev_t: int | None = None
        self.last_valid: tuple[int, float, float] | None = None
        self.run: list[int] = []  # times of the invalid samples held back
        self.run_broken = False  # the run is known to be too long to fill; break already sent

    def push(self, sample: GazeSample) -> list[tuple]:
        t = sample.t_ns
        if isinstance(t, bool) or not isinstance(t, numbers.Integral):
            raise ValueError(
                f"sample {self.index}: t_ns must be an integer number of nanoseconds, got {t!r}"
            )
        t = int(t)
        if self.prev_t is not None and t <= self.prev_t:
            raise ValueError(
                f"sample {self.index}: t_ns={t} is not after the previous sample's "
                f"t_ns={self.prev_t}; timestamps must increase strictly"
            )
        valid = bool(sample.valid) and math.isfinite(sample.x) and math.isfinite(sample.y)
        self.index += 1
        self.prev_t = t
        out: list[tuple] = []
        if not valid:
            if not self.run:
                self.run_broken = False
            self.run.append(t)
            if not self.run_broken and t - self.run[0] >= self.max_gap_ns:
                # The first valid sample comes later still: the run cannot be filled.
                self.run_broken = True
                if self.last_valid is not None:
                    out.append(_BREAK)
            return out
        x, y = float(sample.x), float(sample.y)
        if self.run:
            start = self.run[0]
            duration = t - start
            if self.last_valid is not None and duration <= self.max_gap_ns:
                t0, x0, y0 = self.last_valid
                span = t - t0
                for ti in self.run:
                    u = (ti - t0) / span
                    out.append(("p", ti, x0 + u * (x - x0), y0 + u * (y - y0)))
            elif self.last_valid is not None:
                if not self.run_broken:
                    out.append(_BREAK)
                if duration <= self.max_blink_ns:
                    out.append(("k", start, t))
            self.run = []
            self.run_broken = False
        elif self.last_valid is not None and t - self.last_valid[0] > self.max_gap_ns:
            out.append(_BREAK)
        self.last_valid = (t, x, y)
        out.append(("p", t, x, y))
        return out

    def flush(self) -> list[tuple]:
        """End of stream: an unresolved run is not filled (nor a blink: its length is unknown)."""
        self.run = []
        self.run_broken = False
        self.last_valid = None
        return [_BREAK]


class _Smoother:
    """Tobii's optional noise reduction: centred moving median or average of n samples.

    At the ends of a stretch of data the window shrinks symmetrically (the first and last
    samples pass through unchanged).
    """

    def __init__(self, kind: str, n: int) -> None:
        self.reduce = statistics.median if kind == "median" else statistics.fmean
        self.k = n // 2
        self.seg: list[tuple] = []
        self.next = 0  # index in seg of the next point to output

    def _smoothed(self, j: int) -> tuple:
        half = min(self.k, j, len(self.seg) - 1 - j)
        window = self.seg[j - half : j + half + 1]
        t = self.seg[j][1]
        return ("p", t, self.reduce(p[2] for p in window), self.reduce(p[3] for p in window))

    def process(self, items: list[tuple]) -> list[tuple]:
        out: list[tuple] = []
        for item in items:
            if item[0] == "p":
                self.seg.append(item)
                while self.next + self.k < len(self.seg):
                    out.append(self._smoothed(self.next))
                    self.next += 1
                drop = self.next - self.k
                if drop > 64:
                    del self.seg[:drop]
                    self.next -= drop
            else:
                while self.next < len(self.seg):
                    out.append(self._smoothed(self.next))
                    self.next += 1
                self.seg = []
                self.next = 0
                out.append(item)
        return out


class _Velocity:
    """Olsen 2012's velocity calculator and I-VT classifier: windowed angular velocity, then
    the threshold (a sample below it is a fixation sample)."""

    def __init__(self, half_window_ns: int, threshold_deg_s: float, ppd: float) -> None:
        self.half = half_window_ns + _EDGE_SLACK_NS
        # Velocity in px/ns compared against the threshold converted to px/ns.
        self.threshold = threshold_deg_s * ppd / 1e9
        self.seg: list[tuple] = []
        self.next = 0

    def _classify(self, j: int) -> tuple:
        seg = self.seg
        _, t, x, y = seg[j]
        lo = j
        while lo > 0 and seg[lo - 1][1] >= t - self.half:
            lo -= 1
        hi = j
        last = len(seg) - 1
        while hi < last and seg[hi + 1][1] <= t + self.half:
            hi += 1
        if lo == hi:  # no other sample inside the window: use the neighbours
            lo, hi = max(j - 1, 0), min(j + 1, last)
        if lo == hi:  # an isolated sample has no velocity: unclassified
            return ("c", t, x, y, False)
        a, b = seg[lo], seg[hi]
        speed = math.hypot(b[2] - a[2], b[3] - a[3]) / (b[1] - a[1])
        return ("c", t, x, y, speed < self.threshold)

    def process(self, items: list[tuple]) -> list[tuple]:
        out: list[tuple] = []
        for item in items:
            if item[0] == "p":
                self.seg.append(item)
                t_last = item[1]
                while self.next < len(self.seg) and t_last > self.seg[self.next][1] + self.half:
                    out.append(self._classify(self.next))
                    self.next += 1
                if self.next > 64:  # keep one window (and a neighbour) behind the next point
                    t_keep = self.seg[self.next][1] - self.half
                    drop = self.next - 1
                    while drop > 0 and self.seg[drop][1] >= t_keep:
                        drop -= 1
                    del self.seg[:drop]
                    self.next -= drop
            else:
                while self.next < len(self.seg):
                    out.append(self._classify(self.next))
                    self.next += 1
                self.seg = []
                self.next = 0
                out.append(item)
        return out


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


class IVTDetector(_Detector):
    """Tobii's I-VT fixation filter (Olsen 2012, "The Tobii I-VT Fixation Filter", Tobii
    Technology), run online.

    Stages, in Olsen's order: gap fill-in (§2.4) → noise reduction, off by default (§2.3) →
    velocity calculator over a 20 ms window → I-VT classifier at 30 °/s (§2.1) → merge adjacent
    fixations less than 75 ms and 0.5° apart (§2.6) → discard fixations shorter than 60 ms
    (§2.7). No eye selection (§2.5): a `GazeSample` is already one gaze point. The merged
    fixation's position is the mean of its fixation samples (the samples between the merged
    parts are not averaged in).

    Online, the merge rule needs the next fixation's mean, which is only final when it ends. We
    decide a merge as soon as the next fixation either ends or spans `min_fixation_ms`,
    whichever comes first, with its mean so far: so the consumer learns of a new fixation
    within `min_fixation_ms` of its start, not when it ends. For the usual drift (< 0.1° per
    fixation) this gives the offline decision; a fixation drifting across the 0.5° line after
    its first 60 ms may be decided differently.

    Delays (Δ = sample interval, h = velocity_window/2, k = noise_window//2 if noise reduction
    is on, else 0; a pending invalid run may hold everything up to G = max_gap + Δ more):
    a point is classified within L = h + Δ + kΔ of its time; `fixation_start` within
    min_fixation + Δ + L + G of the fixation's first sample; `fixation_update` within L + G;
    `fixation_end` within merge_max_gap + min_fixation + Δ + L + G of its last sample;
    `blink_start` within max_blink of the blink's start and `blink_end` with the first valid
    sample after it (both are emitted together).
    """

    params: IVTParams

    def __init__(self, geometry: ScreenGeometry | None = None, params: IVTParams | None = None):
        super().__init__(geometry, params or IVTParams())
        p = self.params
        if p.noise_reduction != "none" and p.noise_window_samples > 1:
            self._stages.append(_Smoother(p.noise_reduction, p.noise_window_samples))
        self._stages.append(
            _Velocity(_ms_to_ns(p.velocity_window_ms) // 2, p.velocity_threshold_deg_s, self._ppd)
        )
        self._merge_gap_ns = _ms_to_ns(p.merge_max_gap_ms)
        self._merge_px = p.merge_max_angle_deg * self._ppd
        self._cur: _Group | None = None  # the latest fixation (merged candidates)
        self._pend: _Group | None = None  # a candidate whose merge with _cur is undecided

    def _decide(self, events: list[Event]) -> None:
        """Merge the pending candidate into the current fixation, or end the current one."""
        cur, pend = self._cur, self._pend
        assert cur is not None and pend is not None
        self._pend = None
        (x0, y0), (x1, y1) = cur.mean, pend.mean
        if math.hypot(x1 - x0, y1 - y0) < self._merge_px:
            cur.absorb(pend)
            self._grown(cur, events)
        else:
            self._finish(cur, events)
            self._cur = pend
            self._grown(pend, events)

    def _assemble(self, item: tuple, events: list[Event]) -> None:
        kind = item[0]
        if kind == "c":
            _, t, x, y, is_fixation = item
            cur, pend = self._cur, self._pend
            if is_fixation:
                if pend is not None:
                    pend.add(t, x, y)
                    if pend.end - pend.start >= self._min_ns:
                        self._decide(events)
                elif cur is not None and cur.active:
                    cur.add(t, x, y)
                    self._grown(cur, events)
                elif cur is not None and t - cur.end < self._merge_gap_ns:
                    self._pend = _Group(t, x, y)
                    if self._min_ns == 0:
                        self._decide(events)
                else:
                    if cur is not None:
                        self._finish(cur, events)
                    self._cur = _Group(t, x, y)
                    self._grown(self._cur, events)
                return
            if pend is not None:
                pend.active = False
                self._decide(events)
            cur = self._cur
            if cur is not None:
                cur.active = False
                if t - cur.end >= self._merge_gap_ns:
                    self._finish(cur, events)
                    self._cur = None
        else:  # a break, or a blink (which always follows a break)
            if self._pend is not None:
                self._pend.active = False
                self._decide(events)
            if self._cur is not None:
                self._finish(self._cur, events)
                self._cur = None
            if kind == "k":
                self._blink(item, events)

    def max_delay_ns(self, sample_interval_ns: int) -> dict[str, int]:
        p, dt = self.params, sample_interval_ns
        k = p.noise_window_samples // 2 if p.noise_reduction != "none" else 0
        lookahead = _ms_to_ns(p.velocity_window_ms) // 2 + dt + k * dt + _EDGE_SLACK_NS
        hold = self._gap_hold_ns(dt)
        return {
            "fixation_start": self._min_ns + dt + lookahead + hold,
            "fixation_update": lookahead + hold,
            "fixation_end": self._merge_gap_ns + self._min_ns + dt + lookahead + hold,
            "blink_start": self._max_blink_ns + 1,
            "blink_end": 1,
        }


class _RunningExtreme:
    """Minimum (or maximum) of a sliding window: a monotonic deque of (index, value)."""

    __slots__ = ("items", "sign")

    def __init__(self, sign: float) -> None:
        self.sign = sign  # +1: minimum, -1: maximum
        self.items: deque[tuple[int, float]] = deque()

    def push(self, i: int, v: float) -> None:
        s = self.sign * v
        while self.items and self.sign * self.items[-1][1] >= s:
            self.items.pop()
        self.items.append((i, v))

    def pop_before(self, i: int) -> None:
        while self.items and self.items[0][0] < i:
            self.items.popleft()

    @property
    def value(self) -> float:
        return self.items[0][1]


class IDTDetector(_Detector):
    """I-DT, dispersion-threshold identification (Salvucci & Goldberg 2000, "Identifying
    fixations and saccades in eye-tracking protocols", ETRA, Table 1), run online.

    A window of samples spanning at least `min_fixation_ms` whose dispersion is at most the
    threshold starts a fixation (at the window's first sample); the fixation grows while the
    dispersion with the next sample stays at most the threshold, and ends at the last sample
    that kept it so. A window spanning the minimum duration with too much dispersion drops its
    first sample. No merging, no discarding beyond the minimum duration.

    Delays (Δ, G as for `IVTDetector`): `fixation_start` within min_fixation + Δ + G of the
    fixation's first sample; `fixation_update` within G; `fixation_end` within Δ + G of its last
    sample (the next sample decides it); blinks as for `IVTDetector`.
    """

    params: IDTParams

    def __init__(self, geometry: ScreenGeometry | None = None, params: IDTParams | None = None):
        super().__init__(geometry, params or IDTParams())
        self._max_px = self.params.dispersion_threshold_deg * self._ppd
        self._window: deque[tuple[int, int, float, float]] = deque()  # (index, t, x, y)
        self._index = 0
        self._extremes = [_RunningExtreme(s) for s in (1.0, -1.0, 1.0, -1.0)]
        self._fix: _Group | None = None

    def _reset_window(self) -> None:
        self._window.clear()
        for e in self._extremes:
            e.items.clear()

    def _dispersion_px(self) -> float:
        minx, maxx, miny, maxy = (e.value for e in self._extremes)
        return (maxx - minx) + (maxy - miny)

    def _assemble(self, item: tuple, events: list[Event]) -> None:
        if item[0] != "c":
            if self._fix is not None:
                self._finish(self._fix, events)
                self._fix = None
            self._reset_window()
            if item[0] == "k":
                self._blink(item, events)
            return
        _, t, x, y, _ = item
        fix = self._fix
        if fix is not None:
            spread = (max(fix.maxx, x) - min(fix.minx, x)) + (max(fix.maxy, y) - min(fix.miny, y))
            if spread <= self._max_px:
                fix.add(t, x, y)
                self._grown(fix, events)
                return
            self._finish(fix, events)
            self._fix = None
            self._reset_window()
        i = self._index
        self._index += 1
        window = self._window
        window.append((i, t, x, y))
        minx, maxx, miny, maxy = self._extremes
        minx.push(i, x)
        maxx.push(i, x)
        miny.push(i, y)
        maxy.push(i, y)
        while window[-1][1] - window[0][1] >= self._min_ns:
            if self._dispersion_px() <= self._max_px:
                _, t0, x0, y0 = window[0]
                fix = _Group(t0, x0, y0)
                for _, ti, xi, yi in list(window)[1:]:
                    fix.add(ti, xi, yi)
                self._fix = fix
                self._reset_window()
                self._grown(fix, events)
                return
            window.popleft()
            first = window[0][0]
            for e in self._extremes:
                e.pop_before(first)

    def max_delay_ns(self, sample_interval_ns: int) -> dict[str, int]:
        dt = sample_interval_ns
        hold = self._gap_hold_ns(dt)
        return {
            "fixation_start": self._min_ns + dt + hold,
            "fixation_update": hold,
            "fixation_end": dt + hold,
            "blink_start": self._max_blink_ns + 1,
            "blink_end": 1,
        }

    def _run(self, items: list[tuple]) -> list[Event]:
        # I-DT needs no velocity: points go straight to the assembler, marked unclassified.
        return super()._run([("c", *item[1:], False) if item[0] == "p" else item for item in items])


@runtime_checkable
class FixationDetector(Protocol):
    """What `make_detector` returns."""

    geometry: ScreenGeometry

    def feed(self, sample: GazeSample) -> list[Event]: ...

    def flush(self) -> list[Event]: ...

    def max_delay_ns(self, sample_interval_ns: int) -> dict[str, int]: ...


DETECTORS: dict[str, tuple[type[_Detector], type]] = {
    "ivt": (IVTDetector, IVTParams),
    "idt": (IDTDetector, IDTParams),
}


def make_detector(
    name: str, geometry: ScreenGeometry | None = None, **params: Any
) -> FixationDetector:
    """A fresh detector by name ("ivt" or "idt"), its parameters overriding the defaults.

    Unknown names and parameters raise `ValueError` listing what is known.
    """
    try:
        detector_cls, params_cls = DETECTORS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown fixation detector {name!r}; known: {', '.join(DETECTORS)}"
        ) from None
    known = [f.name for f in fields(params_cls)]
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(
            f"unknown {name} parameter(s) {', '.join(unknown)}; known: {', '.join(known)}"
        )
    return detector_cls(geometry, params_cls(**params))


def detect(
    samples: Iterable[GazeSample],
    name: str = "ivt",
    geometry: ScreenGeometry | None = None,
    **params: Any,
) -> list[Event]:
    """All events of a finished recording: feed every sample, then flush."""
    detector = make_detector(name, geometry, **params)
    events: list[Event] = []
    for sample in samples:
        events.extend(detector.feed(sample))
    events.extend(detector.flush())
    return events


def fixations_from_events(events: Iterable[Event]) -> list[Fixation]:
    """The finished fixations among `events`, in order, as `gazehdr.drivers.samples.Fixation`."""
    starts: dict[int, int] = {}
    out: list[Fixation] = []
    for e in events:
        if e.kind == "fixation_start":
            starts[e.id] = e.t_ns
        elif e.kind == "fixation_end":
            start = starts.pop(e.id, e.t_ns - (e.duration_ns or 0))
            out.append(Fixation(start, e.t_ns, e.x, e.y))
    return out
