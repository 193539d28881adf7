"""Import (`read_bids`): one run's recordings, one per eye, into one native session log.

Which run: `layout.find_run` (a dataset root, a folder in it, or a file; `select` narrows).
What import assumes (of sample times: `physio`; of events: `physioevents`):

- Positions must be `gaze-on-screen` pixels (the coordinates' `Units`, or the drafts'
  `SampleCoordinateUnits`, "pixel"). The origin is the events sidecar's
  `StimulusPresentation.ScreenOrigin` (BIDS 1.11: ["top", "left"], also assumed when absent,
  or ["bottom", "left"], flipped), or the drafts' `EnvironmentCoordinates`. Recordings of
  both eyes give per-eye samples; the sample position is the cyclopean recording's if there is
  one, else the mean of the valid eyes; a time that an eye's file has no row for has no data
  of that eye (`None`). A run gazehdr exported (`GazehdrHeader`) with one eye's recording only
  is a monocular log: the gaze, no per-eye data. `pupil_size` is kept only when its `Units`
  is mm.
- `ScreenSize` and `ScreenDistance` are metres in the specification; a value above 10 is taken
  as centimetres (earlier drafts used cm for the distance). A `ScreenDistance` given as the
  [X, Y, Z] offset of the screen's centre from the eye is that vector's length.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.bids.files import NA
from gazehdr.drivers.formats.bids.layout import find_run
from gazehdr.drivers.formats.bids.physio import Sidecar, _Recording, _sidecar
from gazehdr.drivers.formats.bids.physioevents import _read_events
from gazehdr.drivers.formats.common import geometry_with, mean_of_eyes
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    ClockInfo,
    FormatError,
    SessionHeader,
    SessionLog,
    decode_header,
)


def _metres(value: Any, where: Path, name: str) -> float | None:
    """Metres (above 10: centimetres); a 3-vector distance is its length."""
    if value is None or value == NA:
        return None
    vector = isinstance(value, list) and len(value) == 3 and name == "ScreenDistance"
    if vector and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        value = math.hypot(*value)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
        raise FormatError(where, None, name, f"expected a positive number, got {value!r}")
    return value / 100 if value > 10 else float(value)


def read_bids(
    path: Path,
    *,
    geometry: ScreenGeometry | None = None,
    select: Mapping[str, str | None] | None = None,
) -> SessionLog:
    """Read one eye-tracking run: `path` is a dataset, a folder in one, or one of the run's
    `_physio.tsv.gz` files; `select` ({"sub": "01", "run": "2"}) picks among several runs."""
    files = find_run(Path(path), {k: v for k, v in (select or {}).items() if v is not None})
    recordings = [_Recording(f) for f in files]
    eyes = [r.eye for r in recordings]
    if len(set(eyes)) != len(eyes):
        raise recordings[0].sidecar.error("RecordedEye", f"two recordings of one eye: {eyes}")
    first = recordings[0]
    task = {k: v for k, v in first.entities.items() if k != "recording"}
    events_json = _sidecar(first.path, "events", task)
    native = next(
        (r.sidecar["GazehdrHeader"] for r in recordings if "GazehdrHeader" in r.sidecar), None
    )
    header = (
        decode_header(native, first.sidecar.where("GazehdrHeader")) if native is not None else None
    )
    screen = header.screen if header else _geometry(first, events_json, geometry)
    flip = screen.screen_height_px if _bottom_origin(first, events_json) else None

    by_time: dict[int, dict[str, EyeSample]] = {}
    for r in recordings:
        for t, eye in r.read(flip):
            by_time.setdefault(t, {})[r.eye] = eye
    # a lone eye's recording that gazehdr wrote is a monocular log's gaze (no per-eye data)
    lone = header is not None and len(eyes) == 1
    samples = []
    for t in sorted(by_time):
        got = by_time[t]
        left, right = got.get("left"), got.get("right")
        if "cyclopean" in got:
            c = got["cyclopean"]
            gaze = (c.x, c.y) if math.isfinite(c.x) and math.isfinite(c.y) else None
        else:
            gaze = mean_of_eyes(left, right)
        if lone:
            left = right = None
        if gaze is None:
            samples.append(GazeSample(t, math.nan, math.nan, False, left, right))
        else:
            samples.append(GazeSample(t, gaze[0], gaze[1], True, left, right))
    if header is None:
        side = first.sidecar
        tracker = {"format": "bids-physio", "file": first.path.name}
        for key in ("Manufacturer", "ManufacturersModelName", "DeviceSerialNumber"):
            if key in side:
                tracker[key] = side[key]
        tracker["eyes"] = eyes
        header = SessionHeader(tracker, screen, ClockInfo(source="BIDS physio timestamp"))
    log = SessionLog(header, samples, path=Path(path))
    _read_events(log, recordings, flip)
    return log


def _bottom_origin(first: _Recording, events_json: Sidecar) -> bool:
    """Whether y grows upwards. The physio sidecar's own `EnvironmentCoordinates` (drafts)
    says it for its samples; else the events sidecar's `StimulusPresentation.ScreenOrigin`
    (BIDS 1.11) ["bottom", "left"], or its `EnvironmentCoordinates`; else top-left."""
    stim = events_json.get("StimulusPresentation")
    origin = stim.get("ScreenOrigin") if isinstance(stim, dict) else None
    if origin is not None and "EnvironmentCoordinates" not in first.sidecar:
        if isinstance(origin, list) and sorted(origin) in (["left", "top"], ["bottom", "left"]):
            return "bottom" in origin
        raise events_json.error(
            "StimulusPresentation.ScreenOrigin",
            f'{origin!r}; supported: ["top", "left"], ["bottom", "left"]',
        )
    side = first.sidecar if "EnvironmentCoordinates" in first.sidecar else events_json
    environment = side.get("EnvironmentCoordinates", "top-left")
    if environment not in ("top-left", "bottom-left"):
        raise side.error(
            "EnvironmentCoordinates", f"{environment!r}; supported: top-left, bottom-left"
        )
    return environment == "bottom-left"


def _geometry(
    first: _Recording, events_json: Sidecar, geometry: ScreenGeometry | None
) -> ScreenGeometry:
    """The screen from `StimulusPresentation` (the events sidecar's; the physio sidecar's, as
    drafts put it, wins), each value with the file it came from, for errors."""
    side = first.sidecar
    stim: dict[str, tuple[Any, Path]] = {}
    nested = events_json.get("StimulusPresentation")
    if isinstance(nested, dict):
        stim.update((k, (v, events_json.where("StimulusPresentation"))) for k, v in nested.items())
    for key in ("ScreenResolution", "ScreenSize", "ScreenDistance"):
        if key in side:
            stim[key] = (side[key], side.where(key))
    nested = side.get("StimulusPresentation")
    if isinstance(nested, dict):
        stim.update((k, (v, side.where("StimulusPresentation"))) for k, v in nested.items())
    default = events_json.where("StimulusPresentation")
    resolution, where = stim.get("ScreenResolution", (None, default))
    width = height = diagonal = None
    if resolution is not None:
        if (
            not isinstance(resolution, list)
            or len(resolution) != 2
            or not all(isinstance(v, (int, float)) and v > 0 for v in resolution)
        ):
            raise FormatError(
                where, None, "ScreenResolution", f"expected [width, height], got {resolution!r}"
            )
        width, height = (round(v) for v in resolution)
    elif geometry is None:
        raise FormatError(
            where,
            None,
            "StimulusPresentation.ScreenResolution",
            "the dataset does not give the screen size in pixels; pass it (--screen WxH)",
        )
    size, where = stim.get("ScreenSize", (None, default))
    if size is not None and size != NA:
        if not isinstance(size, list) or len(size) != 2:
            raise FormatError(where, None, "ScreenSize", f"expected [w, h], got {size!r}")
        w, h = (_metres(v, where, "ScreenSize") for v in size)
        diagonal = math.hypot(w, h)
    distance = _metres(*stim.get("ScreenDistance", (None, default)), "ScreenDistance")
    return geometry_with(
        geometry, width_px=width, height_px=height, diagonal_m=diagonal, distance_m=distance
    )
