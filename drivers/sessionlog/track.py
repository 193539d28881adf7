"""A log replayed as gaze: where its fixations were, and its samples as a `GazeTrack`.

`fixation_places` reads where each recorded fixation was from its events; where none has a
position, `detected_fixations` (I-VT) or else `places_at_samples` place them, in that order,
for a daemon's replay and a render alike. `SessionTrack` holds a sequence of samples (the raw
ones, or one per fixation) on the log's time line.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable
from typing import Any, NamedTuple

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazePoint, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog.records import GazeEvent, _finite


class FixationPlace(NamedTuple):
    """Where a recorded fixation was, and when it began (None: its events do not say)."""

    start_ns: int | None
    x: float
    y: float


def fixation_places(events: Iterable[GazeEvent]) -> dict[tuple[int, str | None], FixationPlace]:
    """Each fixation of `events`, keyed by (id, eye): its start (its `fixation_start`'s time,
    else its end's less its duration) and its position, that of its last event with one (later
    events know more: the end's mean wins). Recorders such as EyeLink (`SFIX`) and BIDS
    physioevents (an onset) give a fixation's start no position; this is where it was. A
    fixation none of whose events has a position is left out. `fixation_track` holds these
    places; a daemon replaying a recording sends them (`gazehdr.drivers.replay`)."""
    found: dict[tuple[int, str | None], dict[str, Any]] = {}
    for e in sorted(events, key=lambda e: e.t_ns):
        if not e.kind.startswith("fixation"):
            continue
        f = found.setdefault((e.id, e.eye), {})
        if e.kind == "fixation_start":
            f.setdefault("t", e.t_ns)
        elif e.kind == "fixation_end" and e.duration_ns is not None:
            f.setdefault("t", e.t_ns - e.duration_ns)
        if _finite(e.x) and _finite(e.y):
            f["x"], f["y"] = e.x, e.y
    return {k: FixationPlace(f.get("t"), f["x"], f["y"]) for k, f in found.items() if "x" in f}


def detected_fixations(samples: list[GazeSample], screen: ScreenGeometry) -> list[GazeEvent]:
    """What I-VT finds in a log's samples, as a daemon replaying the log runs it. A log may
    repeat a sample time (an import holds times that went back); I-VT needs them to increase,
    so it gets the first sample of each time."""
    from gazehdr.drivers.fixations import detect  # only logs that place no fixation need it

    increasing = [s for i, s in enumerate(samples) if i == 0 or s.t_ns > samples[i - 1].t_ns]
    return [
        GazeEvent(e.kind, e.id, e.t_ns, e.x, e.y, e.duration_ns, e.dispersion_deg)
        for e in detect(increasing, "ivt", screen)
    ]


def places_at_samples(
    events: Iterable[GazeEvent], samples: list[GazeSample]
) -> tuple[dict[tuple[int, str | None], FixationPlace], int]:
    """Fixations whose events have no position (BIDS physioevents without coordinates, a
    10 Hz recording too coarse for I-VT), each placed at the mean of its eye's valid samples
    from its start to its end; and how many could not be (no start or end, or no valid sample
    inside). `samples` in time order."""
    spans: dict[tuple[int, str | None], list[int | None]] = {}
    for e in events:
        if e.kind == "fixation_start":
            spans.setdefault((e.id, e.eye), [None, None])[0] = e.t_ns
        elif e.kind == "fixation_end":
            span = spans.setdefault((e.id, e.eye), [None, None])
            span[1] = e.t_ns
            if span[0] is None and e.duration_ns is not None:
                span[0] = e.t_ns - e.duration_ns
    times = [s.t_ns for s in samples]
    places: dict[tuple[int, str | None], FixationPlace] = {}
    unplaced = 0
    for key, (start, end) in spans.items():
        points = []
        if start is not None and end is not None:
            for s in samples[bisect.bisect_left(times, start) : bisect.bisect_right(times, end)]:
                eye = s.left if key[1] == "left" else s.right if key[1] == "right" else None
                if eye is not None and math.isfinite(eye.x) and math.isfinite(eye.y):
                    points.append((eye.x, eye.y))
                elif eye is None and s.valid:
                    points.append((s.x, s.y))
        if start is None or not points:
            unplaced += 1
            continue
        x = sum(p[0] for p in points) / len(points)
        y = sum(p[1] for p in points) / len(points)
        places[key] = FixationPlace(start, x, y)
    return places, unplaced


class SessionTrack:
    """A log's samples as a `GazeTrack`: normalised coordinates, seconds since the first sample.

    Step interpolation: each sample holds until the next; before the first sample the track shows
    the first, after the last the last. The eyes are closed at an invalid sample and inside
    blink intervals; an invalid sample keeps the last valid position (the first valid one before
    any), so the eye does not jump to a made-up place. A pure function of `t`.

    `span_ns` (first, last) sets the time line, t = 0 at first and `duration` up to last
    (default: the first and last sample's times).
    """

    def __init__(
        self,
        samples: list[GazeSample],
        blinks: list[tuple[int, float]],
        screen: ScreenGeometry,
        *,
        span_ns: tuple[int, int] | None = None,
    ) -> None:
        if not samples:
            raise InputError("a session log with no samples has no gaze track")
        first, last = span_ns or (samples[0].t_ns, samples[-1].t_ns)
        self.t0_ns = first
        self.duration = (last - first) / 1e9
        self._times = [s.t_ns - self.t0_ns for s in samples]
        width, height = screen.screen_width_px, screen.screen_height_px
        first = next((s for s in samples if s.valid), None)
        x, y = (first.x / width, first.y / height) if first else (0.5, 0.5)
        self._points: list[GazePoint] = []
        for s in samples:
            if s.valid:
                x, y = s.x / width, s.y / height
            self._points.append(GazePoint(x, y, s.valid))
        merged: list[list[float]] = []
        for start, end in sorted(blinks):
            start_rel, end_rel = start - self.t0_ns, end - self.t0_ns
            if merged and start_rel <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], end_rel)
            else:
                merged.append([start_rel, end_rel])
        self._blink_starts = [b[0] for b in merged]
        self._blink_ends = [b[1] for b in merged]

    def _in_blink(self, t_rel_ns: float) -> bool:
        i = bisect.bisect_right(self._blink_starts, t_rel_ns) - 1
        return i >= 0 and t_rel_ns < self._blink_ends[i]

    def at(self, t: float) -> GazePoint:
        if not math.isfinite(t):
            raise InputError(f"gaze time must be finite, got {t}")
        q = round(t * 1e9)  # log times are integer ns
        point = self._points[max(bisect.bisect_right(self._times, q) - 1, 0)]
        if point.eyes_open and self._in_blink(q):
            return GazePoint(point.x, point.y, False)
        return point
