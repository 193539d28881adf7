"""I-VT, Tobii's velocity-threshold fixation filter, run online (its settings: `IVTParams`)."""

from __future__ import annotations

import math

from gazehdr.drivers.fixations.base import _Detector, _Group
from gazehdr.drivers.fixations.events import Event
from gazehdr.drivers.fixations.params import IVTParams, _ms_to_ns
from gazehdr.drivers.fixations.stages import _EDGE_SLACK_NS, _Smoother, _Velocity
from gazehdr.drivers.samples import ScreenGeometry


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
