"""Tracker timestamps on the host clock: the arithmetic alone, fed with numbers (no clock read).

Timestamps are host `time.monotonic_ns()`, the clock of every live source (the daemon's clock
echo maps it to the server's). The Sensor Timestamp (a counter narrower than 64 bits unwrapped)
gives the spacing; `TrackerClock` places it on the host clock. Each report is read at
host = sensor + offset + latency with latency ≥ 0 (the tracker's work after stamping, USB
polling, the OS), so the smallest host − sensor over the last `clock_window_s` (2 s) of reads is
the offset plus the least latency in that window: a sample lands late by that least latency,
typically well under a millisecond on USB HID at 1 kHz polling, and the spacing of samples is the
tracker's own except where the window's minimum changes. The window, rather than all time,
follows the drift between the two crystals: a tracker running fast is followed at once, one
running slow by r lags by at most r · window (0.2 ms at 100 ppm). The estimate restarts after a
re-plug and when the tracker's clock goes back (it rebooted); times are kept strictly increasing
and never later than the read. A tracker without a Sensor Timestamp gets the host time of the read.
"""

from __future__ import annotations

import logging
import math
from collections import deque

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.hid.descriptor import Value

log = logging.getLogger(__name__)


class TrackerClock:
    """Tracker time → host time: the sensor gives the spacing, the window's minimum the placement.

    A report stamped `sensor_ns` and read at `host_ns` has host − sensor = offset + latency, the
    latency ≥ 0 and varying; the smallest difference over the last `window_ns` of host time is
    the offset plus the least latency in the window (a monotone deque of the candidates, O(1)
    amortised per report). A window rather than all time follows crystal drift. The mapped time
    is never later than its read: the current report is in the window.
    """

    def __init__(self, window_ns: int) -> None:
        if window_ns <= 0:
            raise InputError(f"the clock window must be positive, got {window_ns} ns")
        self.window_ns = window_ns
        self._mins: deque[tuple[int, int]] = deque()  # (host ns, host − sensor), both increasing

    def restart(self) -> None:
        """Forget the offset (a re-plug, or a tracker clock that went back)."""
        self._mins.clear()

    def to_host(self, sensor_ns: int, host_ns: int) -> int:
        d = host_ns - sensor_ns
        mins = self._mins
        while mins and mins[-1][1] >= d:
            mins.pop()
        mins.append((host_ns, d))
        while mins[0][0] <= host_ns - self.window_ns:
            mins.popleft()
        return sensor_ns + mins[0][1]


class ReportClock:
    """The host time of each report of one source, in the order they are read.

    Unwraps a Sensor Timestamp narrower than 64 bits, re-anchors the `TrackerClock` after a
    reconnect and when the tracker's clock goes back, and keeps times strictly increasing (a
    coarse host clock, a repeated timestamp), across reconnects too.
    """

    def __init__(self, window_ns: int) -> None:
        self.tracker_clock = TrackerClock(window_ns)
        self._last_raw: int | None = None
        self._wraps = 0
        self._last_sensor_ns: int | None = None
        self._last_t_ns: int | None = None
        #: The Sensor Timestamp's step from the previous report to the last one (ns); None
        #: for the first since a (re)start, or without a timestamp.
        self.step_ns: int | None = None

    def _sensor_ns(self, ts: Value) -> int:
        """The Sensor Timestamp in ns, unwrapped when the counter is narrower than 64 bits."""
        raw = ts.raw & ((1 << ts.bits) - 1) if ts.bits < 64 else ts.raw
        if (
            self._last_raw is not None
            and ts.bits < 64
            and self._last_raw - raw > (1 << (ts.bits - 1))
        ):
            self._wraps += 1
        self._last_raw = raw
        unwrapped = raw + (self._wraps << ts.bits) if ts.bits < 64 else raw
        scale = ts.value / ts.raw if ts.value is not None and ts.raw else 1.0
        return round(unwrapped * scale * 1000.0)

    def time_ns(self, ts: Value | None, host_ns: int, reconnected: bool = False) -> int:
        """Host time of a report with Sensor Timestamp `ts` (None: the tracker has none) read at
        `host_ns`, the first since a reconnect when `reconnected`."""
        self.step_ns = None
        if ts is None:
            t_ns = host_ns  # tracker without a Sensor Timestamp
        else:
            if reconnected:  # the tracker's clock may have restarted: anchor afresh
                self._last_raw, self._wraps, self._last_sensor_ns = None, 0, None
                self.tracker_clock.restart()
            sensor_ns = self._sensor_ns(ts)
            if self._last_sensor_ns is not None and sensor_ns < self._last_sensor_ns:
                log.warning(
                    "tracker clock went back by %d ns; re-anchoring it on the host clock",
                    self._last_sensor_ns - sensor_ns,
                )
                self.tracker_clock.restart()
            elif self._last_sensor_ns is not None:
                self.step_ns = sensor_ns - self._last_sensor_ns
            self._last_sensor_ns = sensor_ns
            t_ns = self.tracker_clock.to_host(sensor_ns, host_ns)
        if self._last_t_ns is not None and t_ns <= self._last_t_ns:
            t_ns = self._last_t_ns + 1  # a coarse host clock, or a repeated timestamp
        self._last_t_ns = t_ns
        return t_ns


class ReportGaps:
    """Reports that never reached the reader, and reports closer together than the tracker's
    declared rate, from the steps of its Sensor Timestamp at its Sampling Frequency.

    Linux keeps at most 64 unread reports per open hidraw node (drivers/hid/hidraw.c) and drops
    what comes beyond them without a word: a reader that stalls for half a second of a 120 Hz
    tracker, or a tracker that sends a backlog at once, loses reports nobody counts. A step of
    k periods (k ≥ 2, rounded) is k − 1 reports lost; a step under half a period is a report
    faster than declared (the tracker's rate is wrong, or it sends a backlog with honest
    timestamps: then what the kernel drops cannot be counted). Nothing is counted for a tracker
    that declares no rate or has no Sensor Timestamp.
    """

    def __init__(self) -> None:
        self.period_ns: float | None = None
        self.lost = 0
        self.early = 0

    def declared(self, rate_hz: float | None) -> None:
        """The tracker's declared Sampling Frequency (a new connection may declare another)."""
        ok = rate_hz is not None and math.isfinite(rate_hz) and rate_hz > 0
        self.period_ns = 1e9 / rate_hz if ok and rate_hz is not None else None

    def add(self, step_ns: int | None) -> int:
        """Count one report whose timestamp stepped `step_ns` from the previous one: the
        number of reports lost between them."""
        p = self.period_ns
        if step_ns is None or p is None:
            return 0
        if step_ns > 1.5 * p:
            lost = round(step_ns / p) - 1
            self.lost += lost
            return lost
        if step_ns < 0.5 * p:
            self.early += 1
        return 0
