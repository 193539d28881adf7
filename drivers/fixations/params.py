"""The detectors' settings, checked when made: Tobii's I-VT defaults, and I-DT's."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields
from typing import Any, Literal

from gazehdr.drivers.errors import InputError


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
            raise InputError(f"{f.name} must be a finite non-negative number, got {value!r}")
        if f.name in positive and value == 0:
            raise InputError(f"{f.name} must be positive, got {value!r}")
    if params.max_blink_ms < params.max_gap_ms:
        raise InputError(
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
            raise InputError(
                "noise_reduction must be 'none', 'median' or 'average', "
                f"got {self.noise_reduction!r}"
            )
        if not isinstance(self.noise_window_samples, int) or self.noise_window_samples % 2 != 1:
            raise InputError(
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
