"""Import (`read_bids`, and `BidsRun`, which streams): one run's recordings, one per eye, into one
native session log, with every row the run holds.

Which run: `layout.find_run` (a dataset root, a folder in it, or a file; `select` narrows). What
import assumes (of sample times: `physio`; of events: `physioevents`):

- Positions must be `gaze-on-screen` pixels (the coordinates' `Units`, or the drafts'
  `SampleCoordinateUnits`, "pixel"). The origin is the events sidecar's
  `StimulusPresentation.ScreenOrigin` (BIDS 1.11: ["top", "left"], also assumed when absent, or
  ["bottom", "left"], flipped), or the drafts' `EnvironmentCoordinates`. Recordings of both eyes
  give per-eye samples; the sample position is the cyclopean recording's if there is one, else
  the mean of the valid eyes; a time that an eye's file has no row for has no data of that eye
  (`None`). A run gazehdr exported (`GazehdrHeader`) with one eye's recording only is a
  monocular log: the gaze, no per-eye data. `pupil_size` is kept only when its `Units` is mm.
- Every row is kept: physio rows as samples (a recording with none is reported, `warnings`, and
  refused with `strict`), physioevents rows as events or notes (`physioevents`), and the rows of
  another tool's `_events.tsv` as notes `events: column=value ...` at their onset
  (`_read_run_events`). The recordings' metadata (`METADATA_KEYS`) goes to the header's
  `tracker.bids_metadata`, per eye; gazehdr's exports carry their header (`GazehdrHeader`) and
  say which recording holds an eye and which the gaze (`GazehdrRecording`).
- `ScreenSize` and `ScreenDistance` are metres in the specification; a value above 10 is taken
  as centimetres (earlier drafts used cm for the distance). A `ScreenDistance` given as the [X,
  Y, Z] offset of the screen's centre from the eye is that vector's length.
"""

from __future__ import annotations

import csv
import heapq
import itertools
import math
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.bids.files import NA, file_stem
from gazehdr.drivers.formats.bids.layout import find_run
from gazehdr.drivers.formats.bids.physio import Sidecar, _Recording, _sidecar
from gazehdr.drivers.formats.bids.physioevents import _read_events
from gazehdr.drivers.formats.common import MAX_SCREEN_PX, decimal_ns, geometry_with, mean_of_eyes
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    ClockInfo,
    FormatError,
    Note,
    Record,
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
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 < value < math.inf:
        raise FormatError(where, None, name, f"expected a positive number, got {value!r}")
    return value / 100 if value > 10 else float(value)


#: Sidecar keys of a physio recording kept in the log's header (`tracker["bids_metadata"]`,
#: per RecordedEye) and written back on export: the hardware and the eye-tracking metadata of
#: BIDS 1.11 (`rules/sidecars/continuous.yaml`, `PhysioHardware` and `EyeTrack`).
METADATA_KEYS = (
    "Manufacturer",
    "ManufacturersModelName",
    "DeviceSerialNumber",
    "SoftwareVersions",
    "EyeTrackingMethod",
    "PupilFitMethod",
    "RawDataFilters",
    "EyeTrackerDistance",
    "CalibrationType",
    "CalibrationCount",
    "CalibrationPosition",
    "CalibrationUnit",
    "AverageCalibrationError",
    "MaximalCalibrationError",
)


class BidsRun:
    """One eye-tracking run, opened: `header`, `warnings` (empty recordings), and `records()`,
    every record in time order (samples first at equal times), the samples streamed from the
    physio files so that memory does not grow with them. `strict` refuses an empty run."""

    def __init__(
        self,
        path: Path,
        *,
        geometry: ScreenGeometry | None = None,
        select: Mapping[str, str | None] | None = None,
        strict: bool = False,
    ) -> None:
        self.path = Path(path)
        files = find_run(self.path, {k: v for k, v in (select or {}).items() if v is not None})
        recordings = [_Recording(f) for f in files]
        eyes = [r.eye for r in recordings]
        if len(set(eyes)) != len(eyes):
            raise recordings[0].sidecar.error("RecordedEye", f"two recordings of one eye: {eyes}")
        self.warnings: list[str] = []
        for r in recordings:
            r.scan()
            if not r.times:
                self.warnings.append(f"{r.path}: no rows (an empty recording)")
        if strict and self.warnings:
            empty = [r for r in recordings if not r.times]
            raise FormatError(empty[0].path, None, None, "no rows: an empty recording (--strict)")
        first = recordings[0]
        task = {k: v for k, v in first.entities.items() if k != "recording"}
        events_json = _sidecar(first.path, "events", task)
        native = next(
            (r.sidecar["GazehdrHeader"] for r in recordings if "GazehdrHeader" in r.sidecar), None
        )
        header = (
            decode_header(native, first.sidecar.where("GazehdrHeader"))
            if native is not None
            else None
        )
        screen = header.screen if header else _geometry(first, events_json, geometry)
        self.flip = screen.screen_height_px if _bottom_origin(first, events_json) else None
        self.recordings = recordings
        # the recording that holds the gaze of a log without per-eye data (gazehdr's exports:
        # `GazehdrRecording` "gaze"; before it, a lone eye's recording)
        roles = [r.sidecar.get("GazehdrRecording") for r in recordings]
        if any(roles):
            self.lone = len(recordings) == 1 and roles[0] == "gaze"
        else:
            self.lone = header is not None and len(eyes) == 1
        if header is None:
            side = first.sidecar
            tracker: dict[str, Any] = {"format": "bids-physio", "file": first.path.name}
            for key in ("Manufacturer", "ManufacturersModelName", "DeviceSerialNumber"):
                if key in side:
                    tracker[key] = side[key]
            tracker["eyes"] = eyes
            metadata = {
                r.eye: {k: r.sidecar[k] for k in METADATA_KEYS if k in r.sidecar}
                for r in recordings
            }
            if any(metadata.values()):
                tracker["bids_metadata"] = metadata
            rates = [r.fs for r in recordings if r.fs is not None]
            if rates:
                tracker["rate_hz"] = rates[0]
            header = SessionHeader(tracker, screen, ClockInfo(source="BIDS physio timestamp"))
        self.header = header
        self.native = native is not None
        self.extra = SessionLog(header, path=self.path)
        _read_events(self.extra, recordings, self.flip, self.native)
        if not self.native:
            _read_run_events(self.extra, first, task)
        self.extra.notes.sort(key=lambda r: r.t_ns)

    def samples(self) -> Iterator[GazeSample]:
        """The run's samples in time order: the recordings merged by time (a time an eye's file
        has no row for has no data of that eye)."""

        def labelled(r: _Recording) -> Iterator[tuple[int, str, EyeSample]]:
            return ((t, r.eye, eye) for t, eye in r.samples(self.flip))

        streams = [labelled(r) for r in self.recordings]
        merged = heapq.merge(*streams, key=lambda item: item[0])
        for t, group in itertools.groupby(merged, key=lambda item: item[0]):
            got = {label: eye for _, label, eye in group}
            left, right = got.get("left"), got.get("right")
            if "cyclopean" in got:
                c = got["cyclopean"]
                gaze = (c.x, c.y) if math.isfinite(c.x) and math.isfinite(c.y) else None
            else:
                gaze = mean_of_eyes(left, right)
            if self.lone:
                left = right = None
            if gaze is None:
                yield GazeSample(t, math.nan, math.nan, False, left, right)
            else:
                yield GazeSample(t, gaze[0], gaze[1], True, left, right)

    def records(self) -> Iterator[Record]:
        """Every record in time order, samples first at equal times (`SessionLog.records`)."""
        samples = ((s.t_ns, 0, s) for s in self.samples())
        others = ((r.t_ns, 1, r) for r in self.extra.records())
        for *_, record in heapq.merge(samples, others, key=lambda item: item[:2]):
            yield record


def read_bids(
    path: Path,
    *,
    geometry: ScreenGeometry | None = None,
    select: Mapping[str, str | None] | None = None,
    strict: bool = False,
) -> SessionLog:
    """Read one eye-tracking run: `path` is a dataset, a folder in one, or one of the run's
    `_physio.tsv.gz` files; `select` ({"sub": "01", "run": "2"}) picks among several runs;
    `strict` refuses a run with an empty recording (else an `EmptyRecordingWarning` says so)."""
    run = BidsRun(Path(path), geometry=geometry, select=select, strict=strict)
    for text in run.warnings:
        warnings.warn(text, EmptyRecordingWarning, stacklevel=2)
    log = run.extra
    log.samples = list(run.samples())
    return log


class EmptyRecordingWarning(UserWarning):
    """A run's recording with no rows (`gazehdr import` prints it; `--strict` refuses it)."""


def _read_run_events(log: SessionLog, first: _Recording, task: dict[str, str]) -> None:
    """The run's `_events.tsv` (a header row, then one row per event; BIDS "Task events"):
    each row a note at its onset on the physio clock (the first sample's time plus `onset`
    less the physio `StartTime`, seconds), `events: column=value ...` with the row's values
    that are not n/a. gazehdr's own exports are not read so: their rows are in physioevents."""
    path = first.path.with_name(file_stem(task, "events") + ".tsv")
    if not path.exists():
        return
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            rows = list(csv.reader(f, delimiter="\t"))
    except UnicodeDecodeError as e:
        raise FormatError(path, None, None, f"not UTF-8 text: {e.reason}") from None
    if not rows:
        return
    columns = [c.strip() for c in rows[0]]
    if "onset" not in columns:
        raise FormatError(path, 1, "onset", "an events file's first column is onset")
    start = first.sidecar.get("StartTime", 0)
    start = start if isinstance(start, (int, float)) and not isinstance(start, bool) else 0
    t0 = first.times[0] if first.times else 0
    for line, values in enumerate(rows[1:], 2):
        if not any(v.strip() for v in values):
            continue
        if len(values) != len(columns):
            raise FormatError(
                path, line, None, f"{len(values)} fields; the header names {len(columns)}"
            )
        row = dict(zip(columns, (v.strip() for v in values), strict=True))
        try:
            t = t0 + decimal_ns(row["onset"], 10**9) - round(start * 10**9)
        except ValueError:
            raise FormatError(
                path, line, "onset", f"expected seconds, got {row['onset']!r}"
            ) from None
        text = " ".join(f"{c}={row[c]}" for c in columns if c != "onset" and row[c] not in (NA, ""))
        log.notes.append(Note(t, f"events: {text}" if text else "events: (a row of n/a)"))


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
            or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and 1 <= v <= MAX_SCREEN_PX
                for v in resolution
            )
        ):
            raise FormatError(
                where,
                None,
                "ScreenResolution",
                f"expected [width, height], 1 to {MAX_SCREEN_PX} pixels each, got {resolution!r}",
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
