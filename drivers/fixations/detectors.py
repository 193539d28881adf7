"""The detectors by name: `make_detector("ivt" | "idt", ...)`, and `detect` over a recording."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import fields
from typing import Any, Protocol, runtime_checkable

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.fixations.base import _Detector
from gazehdr.drivers.fixations.events import Event
from gazehdr.drivers.fixations.idt import IDTDetector
from gazehdr.drivers.fixations.ivt import IVTDetector
from gazehdr.drivers.fixations.params import IDTParams, IVTParams
from gazehdr.drivers.samples import GazeSample, ScreenGeometry


@runtime_checkable
class FixationDetector(Protocol):
    """What `make_detector` returns."""

    geometry: ScreenGeometry

    def feed(self, sample: GazeSample) -> list[Event]: ...

    def flush(self) -> list[Event]: ...

    def max_delay_ns(self, sample_interval_ns: int) -> dict[str, int]: ...


DETECTORS: dict[str, tuple[type[_Detector], type]] = {
    "ivt": (IVTDetector, IVTParams),
    "idt": (IDTDetector, IDTParams),
}


def make_detector(
    name: str, geometry: ScreenGeometry | None = None, **params: Any
) -> FixationDetector:
    """A fresh detector by name ("ivt" or "idt"), its parameters overriding the defaults.

    Unknown names and parameters raise `ValueError` listing what is known.
    """
    try:
        detector_cls, params_cls = DETECTORS[name]
    except (KeyError, TypeError):
        raise InputError(
            f"unknown fixation detector {name!r}; known: {', '.join(DETECTORS)}"
        ) from None
    known = [f.name for f in fields(params_cls)]
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise InputError(
            f"unknown {name} parameter(s) {', '.join(unknown)}; known: {', '.join(known)}"
        )
    return detector_cls(geometry, params_cls(**params))


def detect(
    samples: Iterable[GazeSample],
    name: str = "ivt",
    geometry: ScreenGeometry | None = None,
    **params: Any,
) -> list[Event]:
    """All events of a finished recording: feed every sample, then flush."""
    detector = make_detector(name, geometry, **params)
    events: list[Event] = []
    for sample in samples:
        events.extend(detector.feed(sample))
    events.extend(detector.flush())
    return events
