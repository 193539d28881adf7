"""LSL time ↔ the host's monotonic nanoseconds, and a stream's clock correction: arithmetic only.

LSL stamps each sample in seconds of `local_clock()` on the machine that pushed it. An inlet's
`time_correction()` is what to add to such a stamp to get the receiving machine's
`local_clock()`: liblsl measures it by round trips in the background and refreshes it every few
seconds, so after the first estimate reading it costs nothing. We apply it ourselves rather
than through the inlet's `proc_clocksync` flag so that the offset is known (the session log
notes it, and each change of more than `NOTE_CHANGE_S`), and so that a stream that comes back
(maybe restarted, on another machine) starts from its own correction.

gazehdr's samples are stamped in `time.monotonic_ns()` (the daemon estimates the offset of that
clock to the server's). liblsl's `local_clock()` is `std::chrono::steady_clock`, which on Linux
is the same CLOCK_MONOTONIC; `ClockLink.measure` finds the offset between the two by bracketing
one with the other, so other platforms are right too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from gazehdr.drivers.errors import InputError

NOTE_CHANGE_S = 0.001  # a correction that moves by more than this is noted in the session log


@dataclass(frozen=True)
class ClockLink:
    """monotonic ns = LSL seconds · 1e9 + `offset_ns`, give or take `uncertainty_ns`."""

    offset_ns: int
    uncertainty_ns: int

    @classmethod
    def measure(
        cls, lsl_clock: Callable[[], float], monotonic_ns: Callable[[], int], tries: int = 16
    ) -> ClockLink:
        """Read the LSL clock between two monotonic readings, `tries` times; the tightest
        bracket gives the offset (its middle) and the uncertainty (half its width)."""
        best: tuple[int, int] | None = None
        for _ in range(max(1, tries)):
            before = monotonic_ns()
            lsl = lsl_clock()
            after = monotonic_ns()
            width = max(0, after - before)
            candidate = (width, (before + after) // 2 - round(lsl * 1e9))
            if best is None or candidate[0] < best[0]:
                best = candidate
        assert best is not None
        return cls(best[1], (best[0] + 1) // 2)

    def to_ns(self, lsl_seconds: float) -> int:
        """An LSL time of this machine as monotonic ns."""
        return round(lsl_seconds * 1e9) + self.offset_ns

    def to_lsl(self, t_ns: int) -> float:
        """Monotonic ns of this machine as LSL time (seconds)."""
        return (t_ns - self.offset_ns) / 1e9


class StreamClock:
    """One inlet's stamps as monotonic ns of this machine: stamp + correction, through `link`.

    `correct(offset_s)` takes each reading of `time_correction()` and says whether the change
    is worth a note. Times never go back: a correction that moves the clock backwards holds the
    stamps at the last one given until they pass it (the session log's samples never go back).
    """

    def __init__(self, link: ClockLink, offset_s: float) -> None:
        if not math.isfinite(offset_s):
            raise InputError(f"clock correction must be a finite number, got {offset_s}")
        self.link = link
        self.offset_s = offset_s
        self.noted_s = offset_s
        self.last_ns: int | None = None

    def correct(self, offset_s: float) -> float | None:
        """A new reading of the correction; the change since the last noted one when it is
        more than `NOTE_CHANGE_S` (then noted), else None. Non-finite readings are ignored."""
        if not math.isfinite(offset_s):
            return None
        self.offset_s = offset_s
        change = offset_s - self.noted_s
        if abs(change) <= NOTE_CHANGE_S:
            return None
        self.noted_s = offset_s
        return change

    def t_ns(self, stamp_s: float) -> int:
        """A sample's LSL stamp (the sender's clock) as monotonic ns here, never going back."""
        t = self.link.to_ns(stamp_s + self.offset_s)
        if self.last_ns is not None and t < self.last_ns:
            t = self.last_ns
        self.last_ns = t
        return t
