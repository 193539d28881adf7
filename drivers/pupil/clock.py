"""Pupil time on the host clock: the arithmetic alone, fed with numbers (no socket, no clock read).

Samples of every live source are stamped in host `time.monotonic_ns()` (the daemon's clock echo
maps that clock to the server's). Pupil Capture stamps gaze in Pupil time, seconds on its own
clock (`t` to Pupil Remote reads it). The offset is measured as the daemon's echo measures the
server's, with the same `ClockEstimator`: ask `t` at host t0, get the answer at t1; Pupil time
was read in between, so offset = pupil − (t0 + t1)/2 within ±RTT/2, and the best estimate is
the one of smallest RTT among the last `window` answers (a window rather than all time, so that
the drift between two machines' clocks is followed). On one machine Capture's Pupil time is the
same monotonic clock plus its timebase, so the offset is constant.

Pupil time can jump: another client sends `T` (Pupil Remote sets the timebase), or Capture
restarts. A new answer whose ±RTT/2 interval misses the best one's by more than
`JUMP_TOLERANCE_NS` means the clock changed, and the estimate restarts from it. A sample whose
mapped time is far from when it arrived (`PupilClock.plausible`) asks for a fresh answer before
it is placed.

`SampleTimes` keeps the times the source yields strictly increasing (the session log refuses
samples that go back; a binocular and a monocular datum may come out of order, a new estimate
may move the mapping by a few µs) and never later than the message that carried them arrived.
"""

from __future__ import annotations

from gazehdr.drivers.delivery import ClockEstimate, ClockEstimator
from gazehdr.drivers.errors import InputError

#: Two answers whose intervals miss each other by more than this are of two different clocks
#: (a `T`, a restart): 2 ms is 100 ppm of drift over 20 s, more than two crystals drift apart
#: over the default window.
JUMP_TOLERANCE_NS = 2_000_000
#: A sample placed this far after its message arrived, or this far before, means Pupil time has
#: moved since the last answer (gaze is published at the next world frame, ~30 ms later).
FUTURE_NS = 100_000_000
PAST_NS = 10_000_000_000


def pupil_ns(seconds: float) -> int:
    """Pupil time in seconds (a float, as Capture sends it) as integer ns."""
    return round(seconds * 1e9)


def describe(e: ClockEstimate) -> str:
    """An estimate in one line: Pupil time − host time in s, its uncertainty and RTT in µs."""
    return (
        f"pupil time = host monotonic + {e.offset_ns / 1e9:.9f} s "
        f"± {e.uncertainty_ns / 1e3:.1f} µs (RTT {e.rtt_ns / 1e3:.1f} µs)"
    )


class PupilClock:
    """Offset estimates from `t` round trips; Pupil time → host ns."""

    def __init__(self, window: int = 10) -> None:
        if window < 1:
            raise InputError(f"the clock window must hold at least one answer, got {window}")
        self._estimator = ClockEstimator(window)
        self.jumps = 0

    @property
    def best(self) -> ClockEstimate | None:
        """Pupil time ≈ host time + `offset_ns`, within `uncertainty_ns`; None before any."""
        return self._estimator.best

    def restart(self) -> None:
        """Forget every answer (a reconnect: Capture may have restarted)."""
        self._estimator.window.clear()

    def add(self, t0_ns: int, pupil_s: float, t1_ns: int) -> bool:
        """One answer to `t`: asked at host `t0_ns`, Pupil time `pupil_s`, answered at `t1_ns`.
        True when it shows that Pupil time jumped (the estimate restarted from it)."""
        before = self._estimator.best
        if self._estimator.add(t0_ns, pupil_ns(pupil_s), t1_ns) is None:
            return False  # the host clock went back: not a measurement
        new = self._estimator.window[-1]
        if before is None:
            return False
        gap = abs(new.offset_ns - before.offset_ns) - new.uncertainty_ns - before.uncertainty_ns
        if gap <= JUMP_TOLERANCE_NS:
            return False
        self.jumps += 1
        self._estimator.window.clear()
        self._estimator.window.append(new)
        return True

    def host_ns(self, pupil_s: float) -> int:
        """Where Pupil time `pupil_s` falls on the host clock (ValueError with no estimate)."""
        best = self._estimator.best
        if best is None:
            raise InputError("no Pupil time answer yet: the offset is unknown")
        return pupil_ns(pupil_s) - best.offset_ns

    def plausible(self, pupil_s: float, arrived_ns: int) -> bool:
        """Whether a datum stamped `pupil_s` that arrived at `arrived_ns` fits the estimate: not
        in the future beyond `FUTURE_NS`, nor older than `PAST_NS`."""
        best = self._estimator.best
        if best is None:
            return False
        lag = arrived_ns - self.host_ns(pupil_s)
        return -FUTURE_NS - best.uncertainty_ns <= lag <= PAST_NS


class SampleTimes:
    """The host times a source yields, in order: as mapped, but never later than the arrival of
    the message that carried the sample, and each at least 1 ns after the last."""

    def __init__(self) -> None:
        self._last: int | None = None

    def next(self, mapped_ns: int, arrived_ns: int) -> int:
        t = min(mapped_ns, arrived_ns)
        if self._last is not None and t <= self._last:
            t = self._last + 1
        self._last = t
        return t
