"""What the detectors report: `Event`, and the finished fixations among events.

Events (`Event`): `fixation_start` once a fixation is certain (its `t_ns` is the fixation's first
sample, so it lies in the past), `fixation_update` with the mean position so far at most every
`update_interval_ms` of sample time, `fixation_end` with the mean position, dispersion and
duration, and `blink_start`/`blink_end`. A fixation's events share one `id`, as do a blink's
two; ids increase in the order fixations and blinks are first reported. Dispersion is Salvucci
and Goldberg's: (max x − min x) + (max y − min y), in degrees. A fixation spans its first to its
last sample (`duration_ns` = last − first).

The simulation follows the current fixation, and a saccade does not smear the retinal state
(SPEC §4): a consumer should move its gaze to the `x, y` of `fixation_start` and
`fixation_update`, hold it through saccades, and not follow raw samples.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

from gazehdr.drivers.samples import Fixation

EventKind = Literal["fixation_start", "fixation_update", "fixation_end", "blink_start", "blink_end"]


@dataclass(frozen=True)
class Event:
    """A fixation or blink event. Positions are screen pixels; blinks carry NaN positions.

    `duration_ns` and `dispersion_deg` are the values so far for `fixation_start` and
    `fixation_update`, final for `fixation_end`; a blink's events both carry its duration and
    no dispersion (None).
    """

    kind: EventKind
    id: int
    t_ns: int
    x: float
    y: float
    duration_ns: int | None = None
    dispersion_deg: float | None = None


def fixations_from_events(events: Iterable[Event]) -> list[Fixation]:
    """The finished fixations among `events`, in order, as `gazehdr.drivers.samples.Fixation`."""
    starts: dict[int, int] = {}
    out: list[Fixation] = []
    for e in events:
        if e.kind == "fixation_start":
            starts[e.id] = e.t_ns
        elif e.kind == "fixation_end":
            start = starts.pop(e.id, e.t_ns - (e.duration_ns or 0))
            out.append(Fixation(start, e.t_ns, e.x, e.y))
    return out
