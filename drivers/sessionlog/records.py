"""The session log's records in memory: the header, and one frozen dataclass per record kind.

A sample is `gazehdr.drivers.samples.GazeSample`; every other record is defined here (their JSON
form, and what each field means in a file, is `gazehdr.drivers.sessionlog.codec`'s docstring).
`FormatError` is also the error of the importers in `gazehdr.drivers.formats`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry

FORMAT = "gazehdr-session"
VERSION = 3
READS = (1, 2, 3)  # versions this reader understands
EVENT_KINDS: tuple[str, ...] = (
    "fixation_start",
    "fixation_update",
    "fixation_end",
    "blink_start",
    "blink_end",
    "saccade_start",
    "saccade_end",
)
EYES = ("left", "right")


class FormatError(InputError):
    """A file that does not follow its format; the message names file, line and field."""

    def __init__(
        self, path: str | Path, line: int | None, field_name: str | None, reason: str
    ) -> None:
        self.path = str(path)
        self.line = line
        self.field = field_name
        self.reason = reason
        where = self.path if line is None else f"{self.path}:{line}"
        what = f"field '{field_name}': " if field_name else ""
        super().__init__(f"{where}: {what}{reason}")


@dataclass(frozen=True)
class ClockInfo:
    """What the log's times are: the source clock, and its offset to the server clock."""

    source: str = "monotonic_ns"
    offset_ns: int | None = None
    offset_uncertainty_ns: int | None = None


@dataclass(frozen=True)
class SessionHeader:
    """Line 1 of a log: tracker description, screen geometry, clock."""

    tracker: dict[str, Any] = field(default_factory=dict)
    screen: ScreenGeometry = field(default_factory=ScreenGeometry)
    clock: ClockInfo = field(default_factory=ClockInfo)
    created: str = field(
        default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    )
    version: int = VERSION

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": self.version,
            "created": self.created,
            "tracker": self.tracker,
            "screen": asdict(self.screen),
            "clock": asdict(self.clock),
        }


@dataclass(frozen=True)
class GazeEvent:
    """A fixation, blink or saccade event, as `gazehdr.drivers.fixations.Event` plus the eye it
    came from.

    Unknown positions are NaN (blinks have none; an EyeLink fixation start has none either). A
    saccade's start holds where it began, its end where it landed; saccades come only from
    imported recordings (EyeLink `ESACC`, BIDS physioevents), never from the wire.
    """

    kind: str
    id: int
    t_ns: int
    x: float = math.nan
    y: float = math.nan
    duration_ns: int | None = None
    dispersion_deg: float | None = None
    eye: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise InputError(f"event kind {self.kind!r}; known: {', '.join(EVENT_KINDS)}")
        if self.eye is not None and self.eye not in EYES:
            raise InputError(f"event eye {self.eye!r}; known: left, right")


@dataclass(frozen=True)
class SceneChange:
    t_ns: int
    name: str


@dataclass(frozen=True)
class ParamsChange:
    t_ns: int
    values: dict[str, Any]


@dataclass(frozen=True)
class ModelChange:
    """The models from `t` on, as `AFTERIMAGE+ACUITY` names (`gazehdr.sim.models` checks them)."""

    t_ns: int
    model: str
    split: str | None = None


@dataclass(frozen=True)
class EyeReset:
    t_ns: int


@dataclass(frozen=True)
class Note:
    t_ns: int
    text: str


@dataclass(frozen=True)
class ClockUpdate:
    t_ns: int
    offset_ns: int | None
    offset_uncertainty_ns: int | None = None


Record = (
    GazeSample
    | GazeEvent
    | SceneChange
    | ParamsChange
    | ModelChange
    | EyeReset
    | Note
    | ClockUpdate
)


def _finite(value: float | None) -> bool:
    """A known number: unknown positions are NaN, unknown optional values None."""
    return value is not None and math.isfinite(value)
