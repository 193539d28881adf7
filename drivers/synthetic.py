"""Scripted gaze: a seeded scan path with known ground truth, and a fixed gaze point.

The scan path stands in for a viewer when there is no tracker (figures, offline renders) and is
the ground truth for testing fixation and blink detectors. It is built from the textbook
kinematics: fixations of a few hundred milliseconds with slow drift, saccades whose peak
velocity follows the main sequence, and occasional blinks.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from drivers.samples import GazePoint, GazeSample, ScreenGeometry

#: Peak over mean velocity of a minimum-jerk movement, the saccade profile used here.
_MIN_JERK_PEAK_OVER_MEAN = 1.875
#: Spread (natural-log sigma) of the log-normal fixation durations before clipping.
_FIXATION_LOG_SIGMA = 0.3
#: Drift components per axis; their frequencies are drawn from this range (Hz).
_DRIFT_COMPONENTS = 2
_DRIFT_HZ = (0.5, 2.0)


def peak_velocity(amplitude_deg: float, v_max_deg_s: float = 600.0, c_deg: float = 7.25) -> float:
    """Main sequence: saccade peak velocity (°/s) for an amplitude, V = Vmax·(1 − e^(−A/C))."""
    return v_max_deg_s * (1.0 - math.exp(-amplitude_deg / c_deg))


@dataclass(frozen=True)
class PlannedFixation:
    """Ground truth: a fixation's interval (seconds) and its target, in normalised coordinates."""

    start: float
    end: float
    x: float
    y: float


@dataclass(frozen=True)
class PlannedBlink:
    """Ground truth: a blink's interval in seconds; the eyes are closed in [start, end)."""

    start: float
    end: float


@dataclass(frozen=True)
class _Fixating:
    start: float
    end: float
    x: float
    y: float
    #: Per axis (x, y): amplitudes (normalised units), angular frequencies, phases.
    drift: tuple[tuple[tuple[float, float, float], ...], ...]

    def position(self, t: float) -> tuple[float, float]:
        tau = t - self.start
        dx, dy = (
            sum(a * (math.sin(w * tau + p) - math.sin(p)) for a, w, p in axis)
            for axis in self.drift
        )
        return self.x + dx, self.y + dy


@dataclass(frozen=True)
class _Saccade:
    start: float
    end: float
    x0: float
    y0: float
    x1: float
    y1: float

    def position(self, t: float) -> tuple[float, float]:
        u = min(max((t - self.start) / (self.end - self.start), 0.0), 1.0)
        s = u * u * u * (10.0 + u * (-15.0 + 6.0 * u))  # minimum jerk
        return self.x0 + s * (self.x1 - self.x0), self.y0 + s * (self.y1 - self.y0)


def _check_range(name: str, value: tuple[float, float]) -> None:
    lo, hi = value
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"{name} must be (low, high) with 0 < low <= high, got {value}")


class SyntheticScanPath:
    """A seeded scan path over the screen; a `GazeTrack` with ground truth attached.

    Fixation durations are log-normal around the geometric mean of `fixation_s`, clipped to it.
    Targets are uniform inside the screen less `margin` (normalised) on every side, at least
    `min_amplitude_deg` from where the eye is. During a fixation the eye drifts smoothly (a sum
    of slow sinusoids, at most `drift_deg` per axis, starting at the target). Saccades follow a
    minimum-jerk profile whose peak velocity obeys the main sequence V = Vmax·(1 − e^(−A/C)),
    so their duration is 1.875·A/V. The defaults Vmax = 600 °/s, C = 7.25° are fitted so that
    this duration stays within 4 % of the linear law 2.2 ms/°·A + 21 ms for 2-20° saccades:
    both textbook laws hold at once. (Vmax = 500, C = 15 would put the peak below the mean
    velocity of that duration law, which no velocity profile can do.)
    Blinks, if enabled, start every `blink_interval_s` and last `blink_duration_s` (uniform).

    The path covers at least `duration` seconds; its last fixation may run past it, and times
    beyond the end hold the last position. Same seed, same path; the blinks draw from their own
    stream, so turning them off leaves the path unchanged.
    """

    def __init__(
        self,
        seed: int = 0,
        duration: float = 60.0,
        *,
        geometry: ScreenGeometry | None = None,
        margin: float = 0.1,
        fixation_s: tuple[float, float] = (0.2, 0.6),
        min_amplitude_deg: float = 2.0,
        drift_deg: float = 0.07,
        v_max_deg_s: float = 600.0,
        c_deg: float = 7.25,
        blinks: bool = True,
        blink_interval_s: tuple[float, float] = (4.0, 8.0),
        blink_duration_s: tuple[float, float] = (0.1, 0.3),
    ) -> None:
        self.geometry = geometry or ScreenGeometry()
        if seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed}")
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(
                f"duration must be a finite positive number of seconds, got {duration}"
            )
        if not 0 <= margin < 0.5:
            raise ValueError(f"margin must lie in [0, 0.5), got {margin}")
        _check_range("fixation_s", fixation_s)
        _check_range("blink_interval_s", blink_interval_s)
        _check_range("blink_duration_s", blink_duration_s)
        for name, value in (("v_max_deg_s", v_max_deg_s), ("c_deg", c_deg)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite positive number, got {value}")
        if not (math.isfinite(drift_deg) and drift_deg >= 0):
            raise ValueError(f"drift_deg must be finite and non-negative, got {drift_deg}")
        inner_deg = self.geometry.norm_to_deg(1 - 2 * margin, 1 - 2 * margin)
        if not 0 <= min_amplitude_deg <= min(inner_deg) / 2:
            raise ValueError(
                f"min_amplitude_deg must lie in [0, {min(inner_deg) / 2:.3g}] "
                f"(half the usable screen), got {min_amplitude_deg}"
            )
        self.seed = seed
        self.duration = float(duration)
        self.v_max_deg_s = v_max_deg_s
        self.c_deg = c_deg

        path_seq, drift_seq, blink_seq = np.random.SeedSequence(seed).spawn(3)
        self._segments = self._plan_path(
            np.random.default_rng(path_seq),
            np.random.default_rng(drift_seq),
            margin,
            fixation_s,
            min_amplitude_deg,
            drift_deg,
        )
        self._starts = [s.start for s in self._segments]
        self.fixations: list[PlannedFixation] = [
            PlannedFixation(s.start, s.end, s.x, s.y)
            for s in self._segments
            if isinstance(s, _Fixating)
        ]
        self.blinks: list[PlannedBlink] = (
            self._plan_blinks(np.random.default_rng(blink_seq), blink_interval_s, blink_duration_s)
            if blinks
            else []
        )
        self._blink_starts = [b.start for b in self.blinks]

    def _plan_path(
        self,
        rng: np.random.Generator,
        drift_rng: np.random.Generator,
        margin: float,
        fixation_s: tuple[float, float],
        min_amplitude_deg: float,
        drift_deg: float,
    ) -> list[_Fixating | _Saccade]:
        median = math.sqrt(fixation_s[0] * fixation_s[1])
        segments: list[_Fixating | _Saccade] = []
        t, x, y = 0.0, 0.5, 0.5  # start on a central fixation cross, as experiments do
        while True:
            length = float(
                np.clip(rng.lognormal(math.log(median), _FIXATION_LOG_SIGMA), *fixation_s)
            )
            fixation = _Fixating(t, t + length, x, y, self._drift(drift_rng, drift_deg))
            segments.append(fixation)
            t = fixation.end
            if t >= self.duration:
                return segments
            x0, y0 = fixation.position(t)
            while True:
                x, y = rng.uniform(margin, 1 - margin, size=2).tolist()
                amplitude = math.hypot(*self.geometry.norm_to_deg(x - x0, y - y0))
                if amplitude >= min_amplitude_deg:
                    break
            length = self.saccade_duration(amplitude)
            segments.append(_Saccade(t, t + length, x0, y0, x, y))
            t += length

    def _drift(
        self, rng: np.random.Generator, drift_deg: float
    ) -> tuple[tuple[tuple[float, float, float], ...], ...]:
        """Sinusoid components per axis; each moves the eye by at most `drift_deg` overall."""
        amplitude_deg = drift_deg / (2 * _DRIFT_COMPONENTS)
        amplitudes = self.geometry.deg_to_norm(amplitude_deg, amplitude_deg)
        return tuple(
            tuple(
                (
                    a,
                    2 * math.pi * float(rng.uniform(*_DRIFT_HZ)),
                    float(rng.uniform(0, 2 * math.pi)),
                )
                for _ in range(_DRIFT_COMPONENTS)
            )
            for a in amplitudes
        )

    def _plan_blinks(
        self,
        rng: np.random.Generator,
        interval_s: tuple[float, float],
        duration_s: tuple[float, float],
    ) -> list[PlannedBlink]:
        blinks: list[PlannedBlink] = []
        t = 0.0
        while True:
            t += float(rng.uniform(*interval_s))
            if t >= self.duration:
                return blinks
            length = float(rng.uniform(*duration_s))
            blinks.append(PlannedBlink(t, t + length))
            t += length

    def peak_velocity(self, amplitude_deg: float) -> float:
        """This path's main sequence: peak velocity (°/s) of a saccade of `amplitude_deg`."""
        return peak_velocity(amplitude_deg, self.v_max_deg_s, self.c_deg)

    def saccade_duration(self, amplitude_deg: float) -> float:
        """Seconds a saccade of `amplitude_deg` takes: minimum jerk at the main-sequence peak."""
        return _MIN_JERK_PEAK_OVER_MEAN * amplitude_deg / self.peak_velocity(amplitude_deg)

    def at(self, t: float) -> GazePoint:
        if not math.isfinite(t):
            raise ValueError(f"gaze time must be finite, got {t}")
        segment = self._segments[max(bisect.bisect_right(self._starts, t) - 1, 0)]
        x, y = segment.position(min(max(t, 0.0), segment.end))
        i = bisect.bisect_right(self._blink_starts, t) - 1
        eyes_open = i < 0 or t >= self.blinks[i].end
        return GazePoint(x, y, eyes_open)

    def samples(self, rate_hz: float) -> Iterator[GazeSample]:
        """What a tracker sampling at `rate_hz` would report over [0, duration], in screen px."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a finite positive number, got {rate_hz}")
        width, height = self.geometry.screen_width_px, self.geometry.screen_height_px
        for i in range(math.floor(self.duration * rate_hz) + 1):
            t = i / rate_hz
            x, y, eyes_open = self.at(t)
            t_ns = round(t * 1e9)
            if eyes_open:
                yield GazeSample(t_ns, x * width, y * height)
            else:
                yield GazeSample(t_ns, math.nan, math.nan, valid=False)


class FixationView:
    """A scan path as its fixations: each target held from its fixation's start until the next
    fixation starts, blinks as in the path. What the simulation follows (SPEC §4): a saccade
    does not sweep the retina."""

    def __init__(self, path: SyntheticScanPath) -> None:
        self.path = path
        self.duration = path.duration
        self._starts = [f.start for f in path.fixations]

    def at(self, t: float) -> GazePoint:
        eyes_open = self.path.at(t).eyes_open
        f = self.path.fixations[max(bisect.bisect_right(self._starts, t) - 1, 0)]
        return GazePoint(f.x, f.y, eyes_open)


@dataclass(frozen=True)
class FixedGaze:
    """The eye rests on one point with eyes open: for figures, tests, and gaze-less viewing."""

    x: float = 0.5
    y: float = 0.5

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) and 0 <= v <= 1 for v in (self.x, self.y)):
            raise ValueError(
                f"fixed gaze must be normalised coordinates in [0, 1], got ({self.x}, {self.y})"
            )

    def at(self, t: float) -> GazePoint:
        return GazePoint(self.x, self.y, True)
