"""I-DT, Salvucci and Goldberg's dispersion-threshold identification, run online (its settings:
`IDTParams`)."""

from __future__ import annotations

from collections import deque

from gazehdr.drivers.fixations.base import _Detector, _Group
from gazehdr.drivers.fixations.events import Event
from gazehdr.drivers.fixations.params import IDTParams
from gazehdr.drivers.samples import ScreenGeometry


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
