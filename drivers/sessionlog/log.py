"""`SessionLog`: a whole log in memory, its records by kind, and the gaze it holds.

`SessionLog.fixation_track()` is the log as a `GazeTrack` (normalised coordinates, seconds since
the first sample) that follows its fixations, not its samples (SPEC §4): `gazehdr render SCENE
--gaze session.jsonl` (through `read_session_track`) and a live session replaying the log show
the same gaze. `SessionLog.track()` is the raw samples on the same time line.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog.records import (
    ClockUpdate,
    EyeReset,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    Record,
    SceneChange,
    SessionHeader,
)
from gazehdr.drivers.sessionlog.track import (
    FixationPlace,
    SessionTrack,
    detected_fixations,
    fixation_places,
    places_at_samples,
)


@dataclass
class SessionLog:
    """A whole log in memory: the header and its records by kind, each list in time order."""

    header: SessionHeader
    samples: list[GazeSample] = field(default_factory=list)
    events: list[GazeEvent] = field(default_factory=list)
    scenes: list[SceneChange] = field(default_factory=list)
    params: list[ParamsChange] = field(default_factory=list)
    models: list[ModelChange] = field(default_factory=list)
    resets: list[EyeReset] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)
    clocks: list[ClockUpdate] = field(default_factory=list)
    truncated: bool = False
    truncated_line: int | None = None
    path: Path | None = None

    def add(self, record: Record) -> None:
        """Append a record to the list of its kind."""
        if isinstance(record, GazeSample):
            self.samples.append(record)
        elif isinstance(record, SceneChange):
            self.scenes.append(record)
        elif isinstance(record, ParamsChange):
            self.params.append(record)
        elif isinstance(record, ModelChange):
            self.models.append(record)
        elif isinstance(record, EyeReset):
            self.resets.append(record)
        elif isinstance(record, Note):
            self.notes.append(record)
        elif isinstance(record, ClockUpdate):
            self.clocks.append(record)
        elif isinstance(record, GazeEvent):
            self.events.append(record)
        else:
            raise TypeError(f"not a session log record: {record!r}")

    def records(self) -> Iterator[Record]:
        """Every record, merged in time order (samples first at equal times)."""
        lists = (
            self.samples, self.events, self.scenes, self.params, self.models, self.resets,
            self.notes, self.clocks,
        )  # fmt: skip

        def keyed(rank: int, items: list[Any]) -> Iterator[tuple[int, int, int, Any]]:
            return ((r.t_ns, rank, i, r) for i, r in enumerate(items))

        for *_, record in heapq.merge(*(keyed(rank, rs) for rank, rs in enumerate(lists))):
            yield record

    def blinks(self) -> list[tuple[int, float]]:
        """Blink intervals `[start, end)` in source ns; an unfinished blink ends at +inf."""
        starts: dict[tuple[int, str | None], int] = {}
        intervals: list[tuple[int, float]] = []
        for e in sorted(self.events, key=lambda e: e.t_ns):
            key = (e.id, e.eye)
            if e.kind == "blink_start":
                starts[key] = e.t_ns
            elif e.kind == "blink_end":
                start = starts.pop(key, None)
                if start is None and e.duration_ns is not None:
                    start = e.t_ns - e.duration_ns
                if start is not None:
                    intervals.append((start, e.t_ns))
        intervals += [(start, math.inf) for start in starts.values()]
        return sorted(intervals)

    def track(self) -> SessionTrack:
        return SessionTrack(self.samples, self.blinks(), self.header.screen)

    def fixation_track(self) -> SessionTrack:
        """The gaze as the log's fixations: each fixation's mean position from its start until
        the next one starts, so a saccade never sweeps the simulated retina (SPEC §4). A log
        whose events place no fixation (none, only blinks, or fixations without positions) is
        run through I-VT first, as a daemon replaying it does; where I-VT finds none, its
        fixations are placed at their samples (`places_at_samples`), as the daemon sends them;
        a log with neither falls back to the samples. Its time line is `track()`'s: from the
        first sample to the last."""
        events = self.events
        points = _first_eye_points(events, fixation_places(events))
        if not points:
            events = detected_fixations(self.samples, self.header.screen)
            points = _first_eye_points(events, fixation_places(events))
        if not points:
            events = self.events
            points = _first_eye_points(events, places_at_samples(events, self.samples)[0])
        if not points:
            return self.track()
        held = [GazeSample(int(t), x, y) for t, x, y in points]
        span = (held[0].t_ns, held[-1].t_ns)
        if self.samples:
            span = (min(span[0], self.samples[0].t_ns), max(span[1], self.samples[-1].t_ns))
        blinks = self.blinks() or _blinks_of(events)
        return SessionTrack(held, blinks, self.header.screen, span_ns=span)


def _first_eye_points(
    events: list[GazeEvent], places: dict[tuple[int, str | None], FixationPlace]
) -> list[FixationPlace]:
    """The placed fixations of one eye (the first that fixates), in time order."""
    eye = next((e.eye for e in events if e.kind.startswith("fixation")), None)
    return sorted(p for (_, e), p in places.items() if e == eye and p.start_ns is not None)


def _blinks_of(events: list[GazeEvent]) -> list[tuple[int, float]]:
    return SessionLog(SessionHeader(), events=list(events)).blinks()
