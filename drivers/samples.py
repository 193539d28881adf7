"""Gaze data types shared by every source: raw samples, fixations, gaze tracks, and the requests
`gazehdr.drivers.registry` hands a source's opener.

Two coordinate systems on purpose. Samples and fixations are what a tracker reports: screen
pixels of the tracker's calibrated screen, timestamps in monotonic nanoseconds on the source's
clock. A `GazeTrack` is what a renderer consumes: normalised screen coordinates and seconds since
start, so one track drives a frame of any size. Nothing here imports `server` or pyopencl: a
tracker machine installs only `gazehdr[daemon]`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple, Protocol, runtime_checkable

from gazehdr.drivers.errors import InputError


def _finite(value: float) -> bool:
    """math.isfinite, but False for an int too large for a float (a log can hold 10**400),
    where math.isfinite would raise OverflowError."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


@dataclass(frozen=True)
class ScreenGeometry:
    """Viewing geometry of the tracked screen; defaults give about 64 px per degree.

    Same fields as the server's `Geometry`, so either converts to the other with `asdict`.
    Conversions use the pixels-per-degree at the screen centre (a linear, small-angle map):
    the model's sizes in degrees are defined the same way.
    """

    screen_diagonal_m: float = 0.6
    screen_width_px: int = 1920
    screen_height_px: int = 1080
    viewing_distance_m: float = 1.0

    def __post_init__(self) -> None:
        for name in (
            "screen_diagonal_m",
            "screen_width_px",
            "screen_height_px",
            "viewing_distance_m",
        ):
            value = getattr(self, name)
            if not (_finite(value) and value > 0):
                raise InputError(f"geometry {name} must be a finite positive number, got {value}")

    @property
    def pixels_per_degree(self) -> float:
        """Screen pixels spanned by one degree of visual angle at the screen centre."""
        pitch = self.screen_diagonal_m / math.hypot(self.screen_width_px, self.screen_height_px)
        return 2.0 * self.viewing_distance_m * math.tan(math.radians(0.5)) / pitch

    def deg_to_norm(self, dx_deg: float, dy_deg: float) -> tuple[float, float]:
        """A displacement in degrees as a displacement in normalised screen coordinates."""
        ppd = self.pixels_per_degree
        return dx_deg * ppd / self.screen_width_px, dy_deg * ppd / self.screen_height_px

    def norm_to_deg(self, dx: float, dy: float) -> tuple[float, float]:
        """A displacement in normalised screen coordinates as degrees of visual angle."""
        ppd = self.pixels_per_degree
        return dx * self.screen_width_px / ppd, dy * self.screen_height_px / ppd


@dataclass(frozen=True)
class EyeSample:
    """One eye's part of a sample, for sources that report eyes separately: its gaze and,
    where the tracker measures it, its pupil: in millimetres, or else in the tracker's own
    arbitrary units (EyeLink's pupil area or diameter; the header's tracker says which), kept
    so that an import loses nothing and an export can carry it on."""

    x: float
    y: float
    pupil_mm: float | None = None
    pupil_au: float | None = None


@dataclass(frozen=True)
class GazeSample:
    """One tracker sample: where the eyes point on the screen, in pixels, and when.

    `t_ns` is monotonic nanoseconds on the source's clock (its offset to the server is estimated
    elsewhere). An invalid sample (blink, lost track) carries NaN coordinates so that nothing
    downstream can use it as a position by mistake.
    """

    t_ns: int
    x: float
    y: float
    valid: bool = True
    left: EyeSample | None = None
    right: EyeSample | None = None

    def __post_init__(self) -> None:
        if self.valid and not (math.isfinite(self.x) and math.isfinite(self.y)):
            raise InputError(f"a valid gaze sample needs finite x, y; got ({self.x}, {self.y})")


@dataclass(frozen=True)
class Fixation:
    """A detected fixation: its interval on the source clock and its centre in screen pixels."""

    start_ns: int
    end_ns: int
    x: float
    y: float


class GazePoint(NamedTuple):
    """Where the simulated eye looks: normalised screen coordinates, origin top-left."""

    x: float
    y: float
    eyes_open: bool


@runtime_checkable
class GazeTrack(Protocol):
    """Gaze as a function of time: what offline rendering and figure scripts consume.

    `t` is seconds since the start of the track. Implementations must be pure functions of `t`
    (no hidden cursor), so a renderer may query any time in any order and reproduce a frame.
    """

    def at(self, t: float) -> GazePoint: ...


@dataclass(frozen=True)
class StreamRequest:
    """A stream spec as `gazehdr.drivers.registry.open_source` hands it to the opener of its
    kind: `arg` (what follows `kind:`), the options every kind may take (each uses those that
    apply to it), and `options`, passed on to the source itself."""

    arg: str = ""
    rate_hz: float | None = None
    realtime: bool = True
    geometry: ScreenGeometry | None = None
    screen: Mapping[str, float] = field(default_factory=dict)
    wait: bool = False
    clock: Callable[[], int] | None = None  # monotonic ns
    sleep: Callable[[float], None] | None = None  # seconds
    options: Mapping[str, Any] = field(default_factory=dict)

    def screen_geometry(self) -> ScreenGeometry | None:
        """`geometry` with the `screen` fields set, for sources that take the screen as a whole
        (ValueError for a field or value that is not one)."""
        if not self.screen:
            return self.geometry
        return replace(self.geometry or ScreenGeometry(), **self.screen)


@dataclass(frozen=True)
class TrackRequest:
    """A gaze spec as `gazehdr.drivers.registry.open_track` hands it to the opener of its kind:
    the spec itself (for a file kind, its path), and the seed and duration a generated track
    (the synthetic scan path) is made with; other kinds ignore them."""

    spec: str
    seed: int = 0
    duration: float = 60.0

    @property
    def path(self) -> Path:
        return Path(self.spec)
