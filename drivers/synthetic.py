"""Scripted gaze: a seeded scan path with known ground truth, and a fixed gaze point.

The scan path stands in for a viewer when there is no tracker (figures, offline renders) and is
the ground truth for testing fixation and blink detectors. It is built from the textbook
kinematics: fixations of a few hundred milliseconds with slow drift and ocular tremor, saccades
whose peak velocity follows the main sequence, and occasional blinks that split a fixation.
Its tracker-style `samples()` may add measurement noise, as a real tracker would.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazePoint, GazeSample, ScreenGeometry

#: Peak over mean velocity of a minimum-jerk movement, the saccade profile used here.
_MIN_JERK_PEAK_OVER_MEAN = 1.875
#: Spread (natural-log sigma) of the log-normal fixation durations before clipping.
_FIXATION_LOG_SIGMA = 0.3
#: Drift components per axis; their frequencies are drawn from this range (Hz).
_DRIFT_COMPONENTS = 2
_DRIFT_HZ = (0.5, 2.0)
#: Tremor components per axis and their frequency band (Hz); ours, after the ~40-100 Hz, ~90 Hz
#: peak tremor in Martinez-Conde, Macknik & Hubel 2004, Nat. Rev. Neurosci. 5, 229-240.
_TREMOR_COMPONENTS = 8
_TREMOR_HZ = (40.0, 100.0)
#: Samples computed at once by `samples()`: bounded memory for a long (live) path.
_BLOCK = 4096


def peak_velocity(amplitude_deg: float, v_max_deg_s: float = 600.0, c_deg: float = 7.25) -> float:
    """Main sequence: saccade peak velocity (°/s) for an amplitude, V = Vmax·(1 − e^(−A/C))."""
    return v_max_deg_s * (1.0 - math.exp(-amplitude_deg / c_deg))


@dataclass(frozen=True)
class PlannedFixation:
    """Ground truth: a fixation's interval (seconds) and its target, in normalised coordinates.

    A blink splits a fixation into two of these with the same target, one ending where the
    blink starts and one starting where it ends: what a tracker sees, and what detectors report.
    """

    start: float
    end: float
    x: float
    y: float


@dataclass(frozen=True)
class PlannedSaccade:
    """Ground truth: a saccade's interval (seconds), end points (normalised) and amplitude."""

    start: float
    end: float
    x0: float
    y0: float
    x1: float
    y1: float
    amplitude_deg: float

    def position(self, t: float) -> tuple[float, float]:
        u = min(max((t - self.start) / (self.end - self.start), 0.0), 1.0)
        s = u * u * u * (10.0 + u * (-15.0 + 6.0 * u))  # minimum jerk
        return self.x0 + s * (self.x1 - self.x0), self.y0 + s * (self.y1 - self.y0)


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


def _check_range(name: str, value: tuple[float, float]) -> None:
    lo, hi = value
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise InputError(f"{name} must be (low, high) with 0 < low <= high, got {value}")


class SyntheticScanPath:
    """A seeded scan path over the screen; a `GazeTrack` with ground truth attached.

    Fixation durations are log-normal around the geometric mean of `fixation_s`, clipped to it.
    Targets are uniform inside the screen less `margin` (normalised) on every side, at least
    `min_amplitude_deg` from the last target. During a fixation the eye drifts smoothly (a sum
    of slow sinusoids, at most `drift_deg` per axis, starting at the target). Saccades follow a
    minimum-jerk profile whose peak velocity obeys the main sequence V = Vmax·(1 − e^(−A/C)),
    so their duration is 1.875·A/V. The defaults Vmax = 600 °/s, C = 7.25° are fitted so that
    this duration stays within 4 % of the linear law 2.2 ms/°·A + 21 ms for 2-20° saccades:
    both textbook laws hold at once. (Vmax = 500, C = 15 would put the peak below the mean
    velocity of that duration law, which no velocity profile can do.)

    Fixational jitter: ocular tremor, band-limited noise (8 sinusoids per axis spread over
    40-100 Hz, random phases) of `jitter_deg` RMS per axis on top of everything, default 0.008°
    (ours: about one foveal cone, the tremor amplitude Martinez-Conde et al. 2004 give).
    Microsaccades are not modelled. `at()` is the eye itself: drift and tremor included, no
    measurement noise.

    Blinks, if enabled, fall inside fixations: once `blink_interval_s` (uniform) has passed since
    the last blink's end (the path's start for the first), the first fixation piece to end after
    that is followed by a blink of `blink_duration_s` (uniform), after which the eye, which kept
    drifting on the same target, is seen again for a second piece of a freshly drawn fixation
    duration. `fixations` lists the two pieces separately (a tracker sees two fixations); a
    blink is only planned if it ends before `duration`.

    `samples(rate_hz)` is what a tracker reports: `at()` sampled, plus white Gaussian
    measurement noise of `noise_deg` RMS per axis (default 0, ours: trackers range from about
    0.01° to over 0.1°, so tests choose; with 0 the samples are the ground truth exactly).

    The path covers at least `duration` seconds; its last fixation may run past it, and times
    outside [0, end] hold the first or last position. Same seed, same path and same samples.
    The path, its drift, blinks, tremor and noise draw from separate streams: blinks lengthen
    the fixations they split but never change the targets, and noise never changes the plan.
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
        jitter_deg: float = 0.008,
        noise_deg: float = 0.0,
        v_max_deg_s: float = 600.0,
        c_deg: float = 7.25,
        blinks: bool = True,
        blink_interval_s: tuple[float, float] = (4.0, 8.0),
        blink_duration_s: tuple[float, float] = (0.1, 0.3),
    ) -> None:
        self.geometry = geometry or ScreenGeometry()
        if seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {seed}")
        if not (math.isfinite(duration) and duration > 0):
            raise InputError(
                f"duration must be a finite positive number of seconds, got {duration}"
            )
        if not 0 <= margin < 0.5:
            raise InputError(f"margin must lie in [0, 0.5), got {margin}")
        _check_range("fixation_s", fixation_s)
        _check_range("blink_interval_s", blink_interval_s)
        _check_range("blink_duration_s", blink_duration_s)
        for name, value in (("v_max_deg_s", v_max_deg_s), ("c_deg", c_deg)):
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name} must be a finite positive number, got {value}")
        for name, value in (
            ("drift_deg", drift_deg),
            ("jitter_deg", jitter_deg),
            ("noise_deg", noise_deg),
        ):
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"{name} must be finite and non-negative, got {value}")
        inner_deg = self.geometry.norm_to_deg(1 - 2 * margin, 1 - 2 * margin)
        if not 0 <= min_amplitude_deg <= min(inner_deg) / 2:
            raise InputError(
                f"min_amplitude_deg must lie in [0, {min(inner_deg) / 2:.3g}] "
                f"(half the usable screen), got {min_amplitude_deg}"
            )
        self.seed = seed
        self.duration = float(duration)
        self.v_max_deg_s = v_max_deg_s
        self.c_deg = c_deg
        self.jitter_deg = jitter_deg
        self.noise_deg = noise_deg
        self._fixation_s = fixation_s

        path_seq, drift_seq, blink_seq, jitter_seq, self._noise_seq = np.random.SeedSequence(
            seed
        ).spawn(5)
        self.fixations: list[PlannedFixation] = []
        self.saccades: list[PlannedSaccade] = []
        self.blinks: list[PlannedBlink] = []
        self._segments = self._plan(
            np.random.default_rng(path_seq),
            np.random.default_rng(drift_seq),
            np.random.default_rng(blink_seq) if blinks else None,
            margin,
            min_amplitude_deg,
            drift_deg,
            blink_interval_s,
            blink_duration_s,
        )
        self._starts = [s.start for s in self._segments]
        self._blink_starts = [b.start for b in self.blinks]
        self._jitter = self._tremor(np.random.default_rng(jitter_seq), jitter_deg)

    def _fixation_length(self, rng: np.random.Generator) -> float:
        lo, hi = self._fixation_s
        return float(
            np.clip(rng.lognormal(math.log(math.sqrt(lo * hi)), _FIXATION_LOG_SIGMA), lo, hi)
        )

    def _plan(
        self,
        rng: np.random.Generator,
        drift_rng: np.random.Generator,
        blink_rng: np.random.Generator | None,
        margin: float,
        min_amplitude_deg: float,
        drift_deg: float,
        blink_interval_s: tuple[float, float],
        blink_duration_s: tuple[float, float],
    ) -> list[_Fixating | PlannedSaccade]:
        """Fixations, saccades and blinks in one pass; fills the ground-truth lists."""
        segments: list[_Fixating | PlannedSaccade] = []
        due = float(blink_rng.uniform(*blink_interval_s)) if blink_rng else math.inf
        t, x, y = 0.0, 0.5, 0.5  # start on a central fixation cross, as experiments do
        while True:
            start, end = t, t + self._fixation_length(rng)
            if blink_rng is not None and end >= due:
                blink_end = end + float(blink_rng.uniform(*blink_duration_s))
                if blink_end < self.duration:
                    self.fixations.append(PlannedFixation(start, end, x, y))
                    self.blinks.append(PlannedBlink(end, blink_end))
                    start, end = blink_end, blink_end + self._fixation_length(blink_rng)
                    due = blink_end + float(blink_rng.uniform(*blink_interval_s))
            self.fixations.append(PlannedFixation(start, end, x, y))
            fixation = _Fixating(t, end, x, y, self._drift(drift_rng, drift_deg))
            segments.append(fixation)
            t = fixation.end
            if t >= self.duration:
                return segments
            x0, y0 = fixation.position(t)
            while True:
                tx, ty = rng.uniform(margin, 1 - margin, size=2).tolist()
                if math.hypot(*self.geometry.norm_to_deg(tx - x, ty - y)) >= min_amplitude_deg:
                    break
            x, y = tx, ty
            amplitude = math.hypot(*self.geometry.norm_to_deg(x - x0, y - y0))
            length = self.saccade_duration(amplitude)
            saccade = PlannedSaccade(t, t + length, x0, y0, x, y, amplitude)
            segments.append(saccade)
            self.saccades.append(saccade)
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

    def _tremor(
        self, rng: np.random.Generator, rms_deg: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per axis: amplitude (normalised), angular frequencies and phases of the tremor.

        K sinusoids of amplitude a at distinct frequencies have RMS a·sqrt(K/2). Each one's
        frequency is drawn from the middle half of its own K-th of the band, so no two lie
        closer than half a K-th (3.75 Hz): none beat so slowly as to upset that RMS.
        """
        amplitude_deg = rms_deg * math.sqrt(2 / _TREMOR_COMPONENTS)
        amplitudes = np.array(self.geometry.deg_to_norm(amplitude_deg, amplitude_deg))
        lo, hi = _TREMOR_HZ
        slot = (hi - lo) / _TREMOR_COMPONENTS
        offsets = rng.uniform(0.25, 0.75, size=(2, _TREMOR_COMPONENTS))
        omegas = 2 * np.pi * (lo + slot * (np.arange(_TREMOR_COMPONENTS) + offsets))
        phases = rng.uniform(0, 2 * np.pi, size=(2, _TREMOR_COMPONENTS))
        return amplitudes, omegas, phases

    def peak_velocity(self, amplitude_deg: float) -> float:
        """This path's main sequence: peak velocity (°/s) of a saccade of `amplitude_deg`."""
        return peak_velocity(amplitude_deg, self.v_max_deg_s, self.c_deg)

    def saccade_duration(self, amplitude_deg: float) -> float:
        """Seconds a saccade of `amplitude_deg` takes: minimum jerk at the main-sequence peak."""
        return _MIN_JERK_PEAK_OVER_MEAN * amplitude_deg / self.peak_velocity(amplitude_deg)

    def _positions(self, times: np.ndarray) -> np.ndarray:
        """The eye at each time, (n, 2) normalised: the planned movement plus tremor."""
        out = np.empty((len(times), 2))
        for k, t in enumerate(times.tolist()):
            segment = self._segments[max(bisect.bisect_right(self._starts, t) - 1, 0)]
            out[k] = segment.position(min(max(t, 0.0), segment.end))
        amplitudes, omegas, phases = self._jitter
        held = np.clip(times, 0.0, self._segments[-1].end)  # outside the path the eye rests
        out += np.sin(held[:, None, None] * omegas + phases).sum(axis=2) * amplitudes
        return out

    def _eyes_open(self, t: float) -> bool:
        i = bisect.bisect_right(self._blink_starts, t) - 1
        return i < 0 or t >= self.blinks[i].end

    def at(self, t: float) -> GazePoint:
        if not math.isfinite(t):
            raise InputError(f"gaze time must be finite, got {t}")
        x, y = self._positions(np.array([t]))[0].tolist()
        return GazePoint(x, y, self._eyes_open(t))

    def samples(self, rate_hz: float) -> Iterator[GazeSample]:
        """What a tracker sampling at `rate_hz` would report over [0, duration], in screen px:
        the eye, plus `noise_deg` of measurement noise (the same for the same seed and rate)."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"rate_hz must be a finite positive number, got {rate_hz}")
        width, height = self.geometry.screen_width_px, self.geometry.screen_height_px
        noise_rng = np.random.default_rng(self._noise_seq)
        sigma_px = self.noise_deg * self.geometry.pixels_per_degree
        n = math.floor(self.duration * rate_hz) + 1
        for first in range(0, n, _BLOCK):
            times = [i / rate_hz for i in range(first, min(first + _BLOCK, n))]
            xy = self._positions(np.array(times)) * (width, height)
            if sigma_px > 0:
                xy += noise_rng.normal(0.0, sigma_px, size=xy.shape)
            for t, (x, y) in zip(times, xy.tolist(), strict=True):
                if self._eyes_open(t):
                    yield GazeSample(round(t * 1e9), x, y)
                else:
                    yield GazeSample(round(t * 1e9), math.nan, math.nan, valid=False)


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
            raise InputError(
                f"fixed gaze must be normalised coordinates in [0, 1], got ({self.x}, {self.y})"
            )

    def at(self, t: float) -> GazePoint:
        return GazePoint(self.x, self.y, True)
