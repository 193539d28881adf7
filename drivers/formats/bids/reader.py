"""Import (`read_bids`): a set of recordings, one per eye, into one native session log.

What import assumes (of sample times: `physio`; of events: `physioevents`):

- Positions must be `gaze-on-screen` pixels (`SampleCoordinateUnits` "pixel", or the columns'
  `Units`); `EnvironmentCoordinates` "top-left" (also assumed when absent) or "bottom-left"
  (flipped). Recordings of both eyes give per-eye samples; the sample position is the
  cyclopean recording's if there is one, else the mean of the valid eyes. `pupil_size` is kept
  only when its `Units` is mm.
- `ScreenSize` and `ScreenDistance` are metres in the current specification; a value above 10
  is taken as centimetres (earlier drafts and the example dataset use cm for the distance).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.bids.files import NA
from gazehdr.drivers.formats.bids.physio import _physio_files, _Recording, _sidecar
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


def _metres(value: Any, path: Path, name: str) -> float | None:
    if value is None or value == NA:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
        raise FormatError(path, None, name, f"expected a positive number, got {value!r}")
    return value / 100 if value > 10 else float(value)


def read_bids(path: Path, *, geometry: ScreenGeometry | None = None) -> SessionLog:
    """Read a BIDS eye-tracking physio set: name any of its `_physio.tsv.gz` files (or its dir)."""
    files = _physio_files(Path(path))
    recordings = [_Recording(f) for f in files]
    eyes = [r.eye for r in recordings]
    if len(set(eyes)) != len(eyes):
        raise FormatError(
            recordings[0]._json, None, "RecordedEye", f"two recordings of one eye: {eyes}"
        )
    first = recordings[0]
    task = {k: v for k, v in first.entities.items() if k != "recording"}
    events_json = _sidecar(first.path, "events", task)
    native = next(
        (r.sidecar["GazehdrHeader"] for r in recordings if "GazehdrHeader" in r.sidecar), None
    )
    header = decode_header(native, first._json) if native is not None else None
    screen = header.screen if header else _geometry(first, events_json, geometry)
    environment = first.sidecar.get(
        "EnvironmentCoordinates", events_json.get("EnvironmentCoordinates", "top-left")
    )
    if environment not in ("top-left", "bottom-left"):
        raise FormatError(
            first._json,
            None,
            "EnvironmentCoordinates",
            f"{environment!r}; supported: top-left, bottom-left",
        )
    flip = screen.screen_height_px if environment == "bottom-left" else None

    by_time: dict[int, dict[str, EyeSample]] = {}
    for r in recordings:
        for t, eye in r.read(flip):
            by_time.setdefault(t, {})[r.eye] = eye
    per_eye = "left" in eyes or "right" in eyes
    samples = []
    for t in sorted(by_time):
        got = by_time[t]
        left, right = got.get("left"), got.get("right")
        if "cyclopean" in got:
            c = got["cyclopean"]
            gaze = (c.x, c.y) if math.isfinite(c.x) and math.isfinite(c.y) else None
        else:
            gaze = mean_of_eyes(left, right)
        if per_eye:
            left = left if left is not None or "left" not in eyes else EyeSample(math.nan, math.nan)
            right = (
                right if right is not None or "right" not in eyes else EyeSample(math.nan, math.nan)
            )
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


def _geometry(
    first: _Recording, events_json: dict[str, Any], geometry: ScreenGeometry | None
) -> ScreenGeometry:
    side = first.sidecar
    stim = {
        **(events_json.get("StimulusPresentation") or {}),
        **{k: side[k] for k in ("ScreenResolution", "ScreenSize", "ScreenDistance") if k in side},
        **(side.get("StimulusPresentation") or {}),
    }
    resolution = stim.get("ScreenResolution")
    width = height = diagonal = None
    if resolution is not None:
        if (
            not isinstance(resolution, list)
            or len(resolution) != 2
            or not all(isinstance(v, (int, float)) and v > 0 for v in resolution)
        ):
            raise FormatError(
                first._json,
                None,
                "ScreenResolution",
                f"expected [width, height], got {resolution!r}",
            )
        width, height = (round(v) for v in resolution)
    elif geometry is None:
        raise FormatError(
            first._json,
            None,
            "StimulusPresentation.ScreenResolution",
            "the dataset does not give the screen size in pixels; pass it (--screen WxH)",
        )
    size = stim.get("ScreenSize")
    if size is not None and size != NA:
        if not isinstance(size, list) or len(size) != 2:
            raise FormatError(first._json, None, "ScreenSize", f"expected [w, h], got {size!r}")
        w, h = (_metres(v, first._json, "ScreenSize") for v in size)
        diagonal = math.hypot(w, h)
    distance = _metres(stim.get("ScreenDistance"), first._json, "ScreenDistance")
    return geometry_with(
        geometry, width_px=width, height_px=height, diagonal_m=diagonal, distance_m=distance
    )
