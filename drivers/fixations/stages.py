"""The stages samples stream through: gap fill-in, then I-VT's noise reduction and velocity.

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
"""

from __future__ import annotations

import math
import numbers
import statistics

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample

#: Window edges tolerate this much timestamp rounding (ns), so that a 300 Hz stream whose
#: timestamps were rounded to whole nanoseconds still gets the full 20 ms velocity window.
_EDGE_SLACK_NS = 1_000


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
            raise InputError(
                f"sample {self.index}: t_ns must be an integer number of nanoseconds, got {t!r}"
            )
        t = int(t)
        if self.prev_t is not None and t <= self.prev_t:
            raise InputError(
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
