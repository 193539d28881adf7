"""Online fixation and blink detection: I-VT with Tobii's defaults, and I-DT.

Both detectors are incremental: `feed(sample)` takes one `GazeSample` (screen pixels, monotonic
nanoseconds; an invalid sample has NaN coordinates) and returns the events that became certain
with it; `flush()` ends the stream and returns what was still pending. They are pure: the same
samples always give the same events, whatever the wall clock or the machine. Pick one by name
with `make_detector("ivt" | "idt", geometry, **params)`.

Import everything from here (`from gazehdr.drivers.fixations import make_detector`); the
modules, in the order a sample goes through them:

- `params`: `IVTParams` (Tobii's defaults, with Olsen's sections) and `IDTParams`.
- `stages`: gap fill-in, breaks and blinks (both detectors), noise reduction and the velocity
  classifier (I-VT).
- `base`: what both detectors share: the stages run per sample, a fixation's running
  statistics, ids and events, the delay bound `max_delay_ns`.
- `ivt`: `IVTDetector`, merging and discarding fixations online.
- `idt`: `IDTDetector`, a sliding dispersion window.
- `events`: `Event`, what a consumer does with it, and `fixations_from_events`.
- `detectors`: `make_detector` and `detect` by name (`DETECTORS`).
"""

from gazehdr.drivers.fixations.detectors import (
    DETECTORS,
    FixationDetector,
    detect,
    make_detector,
)
from gazehdr.drivers.fixations.events import Event, EventKind, fixations_from_events
from gazehdr.drivers.fixations.idt import IDTDetector
from gazehdr.drivers.fixations.ivt import IVTDetector
from gazehdr.drivers.fixations.params import IDTParams, IVTParams

__all__ = [
    "DETECTORS",
    "Event",
    "EventKind",
    "FixationDetector",
    "IDTDetector",
    "IDTParams",
    "IVTDetector",
    "IVTParams",
    "detect",
    "fixations_from_events",
    "make_detector",
]
