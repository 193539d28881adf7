"""BIDS eye-tracking physio (BEP020, merged in BIDS 1.11) ↔ the native session log.

Written from the BIDS specification (bids-standard/bids-specification,
`src/modality-specific-files/physiological-and-other-continuous-recordings.md`, sections
"Continuous physiological recordings", "Physiology events" and "Eye-tracking"; the schema
`src/schema/rules/tabular_data/physio.yaml` and `src/schema/rules/sidecars/continuous.yaml`)
its example dataset `eyetracking_binocular` (bids-standard/bids-examples), which also shows the
inheritance of sidecars from the dataset root, and the reference converter eye2bids
(bids-standard/eye2bids, `eye2bids/edf2bids.py`, `eye2bids/_base.py`) for what real files hold.

What the files are:

- `<matches>_recording-<label>_physio.tsv.gz`: gzip, tab-separated, **no header line**; the
  column names are the sidecar's `Columns`. With `"PhysioType": "eyetrack"` the columns start
  `timestamp, x_coordinate, y_coordinate`, then optional `pupil_size`; `n/a` marks a missing
  value. One recording per eye: `recording-eye1`, `eye2` (and `eye3` for a cyclopean signal),
  the eye in the sidecar's `RecordedEye` (`left`, `right`, `cyclopean`).
- `<matches>_recording-<label>_physio.json`: `SamplingFrequency`, `StartTime` (s), `Columns`,
  `PhysioType`, `RecordedEye`, `SampleCoordinateUnits`, `SampleCoordinateSystem`,
  `EnvironmentCoordinates`, and per column a `Units`. Sidecars are inherited: a
  `task-x_physio.json` at the dataset root applies to every file whose entities include its
  own, the more specific file winning (BIDS inheritance principle).
- `<matches>_recording-<label>_physioevents.tsv.gz` + `.json`: columns `onset` (first, the
  schema requires it), `duration`, `trial_type`, `message`, ... With `ForeignIndexColumn` (or
  `OnsetSource`, as in the example dataset) naming the physio file's `timestamp` column, the
  events' column of that name (the specification's "Explicit indexing": each value MUST be one
  of the physio file's timestamps), or `onset` (eye2bids), is in that column's units. Without
  it, a `foreign_index` column is the zero-based row of the physio file, negative before its
  first row (the specification's "Implicit indexing"); lacking one, `onset` is taken as the
  one-based row.
- The screen: `StimulusPresentation` (`ScreenResolution` px, `ScreenSize`, `ScreenDistance`)
  in the sidecars or in the task's `_events.json`.

Import, and what it assumes:

- Sample time: the `timestamp` column in its sidecar `Units` (s, ms, us/µs, ns). Without a
  unit (eye2bids writes none) it is the one of s/ms/µs/ns whose median step matches
  `SamplingFrequency`. Without a `timestamp` column: `StartTime + (row − 1) / SamplingFrequency`.
- Positions must be `gaze-on-screen` pixels (`SampleCoordinateUnits` "pixel", or the columns'
  `Units`); `EnvironmentCoordinates` "top-left" (also assumed when absent) or "bottom-left"
  (flipped). Recordings of both eyes give per-eye samples; the sample position is the
  cyclopean recording's if there is one, else the mean of the valid eyes. `pupil_size` is kept
  only when its `Units` is mm.
- `ScreenSize` and `ScreenDistance` are metres in the current specification; a value above 10
  is taken as centimetres (earlier drafts and the example dataset use cm for the distance).
- Events: a `fixation` row gives `fixation_start` at `onset` and `fixation_end` at
  `onset + duration`; a `blink` row, or any row with `blink` = 1 (eye2bids marks the saccade
  around an EyeLink blink so), a blink over the row's interval; other trial types (saccades)
  are skipped; a `message` becomes a note (`gazehdr scene NAME`, `gazehdr params {json}`,
  `gazehdr model {json}`, `gazehdr reset` and `gazehdr clock {json}` messages become scene,
  parameter, model, reset and clock records). Event ids are
  numbered 1, 2, ... per kind in onset order. `duration` is in its sidecar `Units`, else in
  the onset's units when `ForeignIndexColumn` is used (eye2bids), else seconds.
- Event times: the ForeignIndexColumn's column names a sample, so it is exact only to a sample
  period. A file that also has an `onset` with `Units` (gazehdr's own) gives the exact time
  from it, provided every onset lies in the sample interval its timestamp names (the sample at
  or before it, or the first sample for an earlier one); otherwise (an onset on another clock,
  such as seconds from the start) the timestamp column is used.

Export (`write_bids`): `recording-eye1` holds the gaze (`RecordedEye` cyclopean) when the log
has no per-eye data; otherwise `eye1` left, `eye2` right, `eye3` cyclopean. Timestamps are the
log's integer ns (`Units` "ns"), positions pixels top-left, pupil mm; each recording's
physioevents hold its eye's fixations and blinks (one row each: onset, timestamp, duration, mean
position, dispersion), and the cyclopean one also the events of no particular eye and the notes,
scenes, parameter and model changes, resets and clock updates as messages. The physioevents use
explicit indexing (`"ForeignIndexColumn": "timestamp"`): `timestamp` is the physio timestamp of
the sample at or before the event (the first sample's for an earlier event), so every value is
in the physio file as the specification requires; `onset` (ns) is the exact event time on the
same clock, an extra column. A log without samples is refused (ValueError): there would be no
timestamp to index by, nor a row for implicit indexing. The native header rides along in the
sidecars as `GazehdrHeader`, so native → BIDS → native gives back the same samples, fixations
(start and end times, mean position, dispersion; not the start position nor `fixation_update`,
which BIDS rows do not hold), blinks, notes, scenes, parameters, models, resets and header. gzip
output is reproducible (no name or time in the gzip header).
"""

from __future__ import annotations

import bisect
import csv
import gzip
import io
import itertools
import json
import math
import re
import statistics
from collections.abc import Iterator
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.common import decimal_ns, geometry_with, mean_of_eyes
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    ClockInfo,
    ClockUpdate,
    EyeReset,
    FormatError,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    SceneChange,
    SessionHeader,
    SessionLog,
    decode_header,
)

UNITS_NS = {"s": 10**9, "ms": 10**6, "us": 10**3, "µs": 10**3, "μs": 10**3, "ns": 1}
NA = "n/a"
_ROW = "foreign_index"  # implicit indexing: the zero-based row of the physio file
_ENTITY = re.compile(r"[a-zA-Z0-9]+-[a-zA-Z0-9]+")
_EVENT_COLUMNS = [
    "onset",
    "timestamp",
    "duration",
    "trial_type",
    "blink",
    "message",
    "x_coordinate",
    "y_coordinate",
    "dispersion",
    "eye",
]


# --- file names, sidecars ---------------------------------------------------------------------


def _split_name(name: str) -> tuple[dict[str, str], str]:
    """`sub-01_task-x_recording-eye1_physio.tsv.gz` → ({sub, task, recording}, "physio")."""
    stem = name.split(".", 1)[0]
    parts = stem.split("_")
    entities = dict(p.split("-", 1) for p in parts[:-1] if "-" in p)
    return entities, parts[-1]


def _load_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise FormatError(path, e.lineno, None, f"not valid JSON: {e.msg}") from None
    if not isinstance(data, dict):
        raise FormatError(path, 1, None, "a sidecar is a JSON object")
    return data


def _sidecar(data_file: Path, suffix: str, entities: dict[str, str]) -> dict[str, Any]:
    """The sidecar of `data_file`, merged down from the dataset root (inheritance principle)."""
    dirs = []
    d = data_file.parent
    for _ in range(5):
        dirs.append(d)
        if (d / "dataset_description.json").exists() or d.parent == d:
            break
        d = d.parent
    merged: dict[str, Any] = {}
    for directory in reversed(dirs):
        found = []
        for candidate in directory.glob(f"*_{suffix}.json"):
            ents, sfx = _split_name(candidate.name)
            if sfx == suffix and all(entities.get(k) == v for k, v in ents.items()):
                found.append((len(ents), candidate))
        for _, candidate in sorted(found):
            merged.update(_load_json(candidate))
    return merged


def _units(sidecar: dict[str, Any], column: str) -> str | None:
    spec = sidecar.get(column)
    return spec.get("Units") if isinstance(spec, dict) else None


def _open_tsv(path: Path) -> io.TextIOBase:
    if path.name.endswith(".gz"):
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", newline="")
    return path.open(encoding="utf-8", newline="")


def _rows(path: Path, columns: list[str]) -> Iterator[tuple[int, dict[str, str]]]:
    """(line, {column: text}) for each row of a header-less TSV(.gz) file."""
    try:
        with _open_tsv(path) as f:
            reader = csv.reader(f, delimiter="\t")
            for row in reader:
                if not row or not any(v.strip() for v in row):
                    continue
                if len(row) != len(columns):
                    raise FormatError(
                        path,
                        reader.line_num,
                        None,
                        f"{len(row)} fields; the sidecar's Columns names {len(columns)} "
                        f"({', '.join(columns)})",
                    )
                yield reader.line_num, dict(zip(columns, (v.strip() for v in row), strict=True))
    except (OSError, EOFError, UnicodeDecodeError) as e:
        if isinstance(e, FileNotFoundError):
            raise
        raise FormatError(path, None, None, f"cannot read as gzip TSV: {e}") from None


def _float(path: Path, line: int, row: dict[str, str], column: str) -> float | None:
    text = row[column]
    if text == NA or text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise FormatError(path, line, column, f"expected a number or n/a, got {text!r}") from None
    return value if math.isfinite(value) else None


def _metres(value: Any, path: Path, name: str) -> float | None:
    if value is None or value == NA:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
        raise FormatError(path, None, name, f"expected a positive number, got {value!r}")
    return value / 100 if value > 10 else float(value)


# --- import -----------------------------------------------------------------------------------


class _Recording:
    """One `_physio.tsv.gz` with its merged sidecar."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.entities, _ = _split_name(path.name)
        self.times: list[int] = []  # the rows' times, once read
        self.sidecar = _sidecar(path, "physio", self.entities)
        side = self.sidecar
        columns = side.get("Columns")
        if not isinstance(columns, list) or not all(isinstance(c, str) for c in columns):
            raise FormatError(
                self._json, None, "Columns", "required: the list of the TSV's column names"
            )
        for needed in ("x_coordinate", "y_coordinate"):
            if needed not in columns:
                raise FormatError(
                    self._json, None, "Columns", f"no '{needed}' column: not eye-tracking data"
                )
        self.columns = columns
        physio_type = side.get("PhysioType", "eyetrack")
        if physio_type != "eyetrack":
            raise FormatError(
                self._json, None, "PhysioType", f"{physio_type!r}; expected 'eyetrack'"
            )
        eye = side.get("RecordedEye", "cyclopean")
        if not isinstance(eye, str) or eye.lower() not in ("left", "right", "cyclopean"):
            raise FormatError(
                self._json, None, "RecordedEye", f"expected left, right or cyclopean, got {eye!r}"
            )
        self.eye = eye.lower()
        system = side.get("SampleCoordinateSystem", "gaze-on-screen")
        if system != "gaze-on-screen":
            raise FormatError(
                self._json, None, "SampleCoordinateSystem", f"{system!r}; expected gaze-on-screen"
            )
        units = side.get("SampleCoordinateUnits") or _units(side, "x_coordinate")
        if str(units).lower() not in ("pixel", "pixels", "px"):
            raise FormatError(
                self._json,
                None,
                "SampleCoordinateUnits",
                f"{units!r}; gazehdr imports screen pixels ('pixel')",
            )
        self.fs = side.get("SamplingFrequency")
        if self.fs is not None and self.fs != NA:
            if not isinstance(self.fs, (int, float)) or not self.fs > 0:
                raise FormatError(
                    self._json,
                    None,
                    "SamplingFrequency",
                    f"expected a positive number, got {self.fs!r}",
                )
        else:
            self.fs = None

    @property
    def _json(self) -> Path:
        return self.path.with_name(self.path.name.split(".", 1)[0] + ".json")

    def read(self, flip_height: int | None) -> list[tuple[int, EyeSample]]:
        """(t_ns, position) per row; a lost position is NaN. Keeps the row times in `times`."""
        rows = list(_rows(self.path, self.columns))
        times = self._times(rows)
        has_pupil = "pupil_size" in self.columns and str(
            _units(self.sidecar, "pupil_size")
        ).lower() in ("mm", "millimeter", "millimetre")
        self.times = times
        out = []
        for t, (line, row) in zip(times, rows, strict=True):
            x = _float(self.path, line, row, "x_coordinate")
            y = _float(self.path, line, row, "y_coordinate")
            pupil = _float(self.path, line, row, "pupil_size") if has_pupil else None
            if x is None or y is None:
                out.append((t, EyeSample(math.nan, math.nan, pupil)))
                continue
            if flip_height is not None:
                y = flip_height - y
            out.append((t, EyeSample(x, y, pupil)))
        return out

    def _times(self, rows: list[tuple[int, dict[str, str]]]) -> list[int]:
        if "timestamp" not in self.columns:
            if self.fs is None:
                raise FormatError(
                    self._json,
                    None,
                    "SamplingFrequency",
                    "needed to time the rows of a file without a timestamp column",
                )
            start = self.sidecar.get("StartTime", 0)
            if not isinstance(start, (int, float)):
                raise FormatError(self._json, None, "StartTime", f"expected seconds, got {start!r}")
            return [round((start + i / self.fs) * 1e9) for i in range(len(rows))]
        raw: list[Decimal] = []
        for line, row in rows:
            text = row["timestamp"]
            try:
                value = Decimal(text)
            except InvalidOperation:
                value = Decimal("nan")
            if not value.is_finite():
                raise FormatError(self.path, line, "timestamp", f"expected a number, got {text!r}")
            raw.append(value)
        self.timestamp_unit_ns = self._timestamp_unit(raw)
        times = [int((v * self.timestamp_unit_ns).to_integral_value()) for v in raw]
        for (line, _), a, b in zip(rows[1:], times, times[1:], strict=False):
            if b < a:
                raise FormatError(self.path, line, "timestamp", "goes back in time")
        return times

    def _timestamp_unit(self, raw: list[Decimal]) -> int:
        """ns per unit of the timestamp column: its sidecar Units, else inferred."""
        units = _units(self.sidecar, "timestamp")
        if units is not None:
            if units not in UNITS_NS:
                raise FormatError(
                    self._json,
                    None,
                    "timestamp.Units",
                    f"{units!r}; supported: {', '.join(UNITS_NS)}",
                )
            return UNITS_NS[units]
        steps = [float(b - a) for a, b in itertools.pairwise(raw) if b > a]
        if self.fs and steps:
            period_ns = 1e9 / self.fs
            for scale in (10**9, 10**6, 10**3, 1):
                if abs(statistics.median(steps) * scale - period_ns) <= 0.25 * period_ns:
                    return scale
        raise FormatError(
            self._json,
            None,
            "timestamp.Units",
            "missing, and the sample spacing fits none of s, ms, us, ns at SamplingFrequency",
        )


def _physio_files(path: Path) -> list[Path]:
    """All recordings of the set `path` belongs to (same entities but `recording`)."""
    if path.is_dir():
        files = sorted(path.glob("*_physio.tsv.gz")) or sorted(path.glob("*_physio.tsv"))
        groups = {
            tuple(sorted((k, v) for k, v in _split_name(f.name)[0].items() if k != "recording"))
            for f in files
        }
        if len(groups) != 1:
            raise FormatError(
                path,
                None,
                None,
                f"{len(files)} physio files in {len(groups)} sets; name one of them",
            )
        return files
    name = path.name
    if name.endswith("_physio.json"):
        gz = path.with_name(name[: -len(".json")] + ".tsv.gz")
        path = gz if gz.exists() else path.with_name(name[: -len(".json")] + ".tsv")
    if not path.exists():
        raise FileNotFoundError(2, "No such file", str(path))
    entities, suffix = _split_name(path.name)
    if suffix != "physio":
        raise FormatError(path, None, None, "not a BIDS *_physio.tsv.gz file")
    key = {k: v for k, v in entities.items() if k != "recording"}
    extension = ".tsv.gz" if path.name.endswith(".tsv.gz") else ".tsv"
    files = []
    for f in sorted(path.parent.glob(f"*_physio{extension}")):
        ents, _ = _split_name(f.name)
        if {k: v for k, v in ents.items() if k != "recording"} == key:
            files.append(f)
    return files


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


def _read_events(log: SessionLog, recordings: list[_Recording], flip: int | None) -> None:
    intervals: list[tuple[int, str, int | None, float, float, float | None, str | None]] = []
    seen_messages: set[tuple[int, str]] = set()
    for r in recordings:
        stem = r.path.name.split(".", 1)[0]
        ext = r.path.name[len(stem) :]
        path = r.path.with_name(stem[: -len("physio")] + "physioevents" + ext)
        if not path.exists():
            continue
        side = _sidecar(path, "physioevents", r.entities)
        sidecar_path = path.with_name(path.name.split(".", 1)[0] + ".json")
        columns = side.get("Columns")
        index = side.get("ForeignIndexColumn") or side.get("OnsetSource")
        if index:  # the spec names the events' column after it; eye2bids calls it onset
            when = index if isinstance(columns, list) and index in columns else "onset"
        else:  # implicit indexing: foreign_index, the zero-based physio row
            when = _ROW if isinstance(columns, list) and _ROW in columns else "onset"
        if not isinstance(columns, list) or when not in columns:
            raise FormatError(
                sidecar_path,
                None,
                "Columns",
                "required, with an 'onset' or 'foreign_index' column (or the ForeignIndexColumn)",
            )
        if index is not None and index != "timestamp":
            raise FormatError(
                sidecar_path, None, "ForeignIndexColumn", f"{index!r}; supported: timestamp"
            )
        if index is not None and "timestamp" not in r.columns:
            raise FormatError(
                sidecar_path, None, "ForeignIndexColumn", "the physio file has no timestamp"
            )
        time_unit = r.timestamp_unit_ns if index else None
        duration_unit = _unit_ns(side, "duration", sidecar_path) or time_unit or 10**9
        first_row = 0 if when == _ROW else 1
        timed = []
        for line, row in _rows(path, columns):
            t = _event_time(path, line, row, when, time_unit, r, first_row)
            timed.append((line, row, t))
        onset_units = UNITS_NS.get(_units(side, "onset"))
        if r.times and when == index and "onset" in columns and onset_units:
            # explicit indexing snaps to a sample; an onset with Units on the same clock (what
            # gazehdr writes) is exact. Taken only when every onset lies in the sample interval
            # its index names, so an onset on another clock (s from the start) is not mistaken.
            exact = [
                _event_time(path, line, row, "onset", onset_units, r, 1) for line, row, _ in timed
            ]
            if all(_sample_at(r.times, o) == t for o, (_, _, t) in zip(exact, timed, strict=True)):
                timed = [(line, row, o) for o, (line, row, _) in zip(exact, timed, strict=True)]
        file_eye = r.eye if r.eye in ("left", "right") else None
        for line, row, t in timed:
            duration = None
            if row.get("duration", NA) not in (NA, ""):
                try:
                    duration = decimal_ns(row["duration"], duration_unit)
                except ValueError:
                    raise FormatError(
                        path, line, "duration", f"expected a number or n/a, got {row['duration']!r}"
                    ) from None
            kind = row.get("trial_type", NA)
            blink = row.get("blink", NA)
            eye = row.get("eye", NA)
            eye = eye if eye in ("left", "right") else file_eye
            message = row.get("message", NA)
            if kind == "fixation":
                x = _float(path, line, row, "x_coordinate") if "x_coordinate" in row else None
                y = _float(path, line, row, "y_coordinate") if "y_coordinate" in row else None
                if x is not None and y is not None and flip is not None:
                    y = flip - y
                disp = _float(path, line, row, "dispersion") if "dispersion" in row else None
                nan = math.nan
                intervals.append(
                    (
                        t,
                        "fixation",
                        duration,
                        nan if x is None else x,
                        nan if y is None else y,
                        disp,
                        eye,
                    )
                )
            elif kind == "blink" or blink == "1":
                intervals.append((t, "blink", duration, math.nan, math.nan, None, eye))
            if message not in (NA, "") and (t, message) not in seen_messages:
                seen_messages.add((t, message))
                _message(log, t, message, path, line)
    ids = {"fixation": 0, "blink": 0}
    for t, family, duration, x, y, disp, eye in sorted(intervals, key=lambda i: i[0]):
        ids[family] += 1
        log.events.append(GazeEvent(f"{family}_start", ids[family], t, eye=eye))
        if duration is not None:
            log.events.append(
                GazeEvent(f"{family}_end", ids[family], t + duration, x, y, duration, disp, eye)
            )
    log.events.sort(key=lambda e: e.t_ns)
    for items in (log.notes, log.scenes, log.params, log.clocks):
        items.sort(key=lambda r: r.t_ns)


def _unit_ns(side: dict[str, Any], column: str, sidecar_path: Path) -> int | None:
    """ns per unit of a column's sidecar `Units`; None without one."""
    units = _units(side, column)
    if units is not None and units not in UNITS_NS:
        raise FormatError(
            sidecar_path, None, f"{column}.Units", f"{units!r}; supported: {', '.join(UNITS_NS)}"
        )
    return UNITS_NS[units] if units is not None else None


def _event_time(
    path: Path,
    line: int,
    row: dict[str, str],
    column: str,
    unit_ns: int | None,
    r: _Recording,
    first_row: int,
) -> int:
    """An event's time from `column`: a time in `unit_ns`, or without a unit a physio row."""
    text = row[column]
    try:
        if unit_ns is not None:
            return decimal_ns(text, unit_ns)
        return _row_time(decimal_ns(text, 1) + 1 - first_row, r.times, r.fs)
    except ValueError:
        raise FormatError(path, line, column, f"expected a number, got {text!r}") from None


def _sample_at(times: list[int], t: int) -> int:
    """The time of the sample at or before `t` (the first sample's for an earlier `t`)."""
    return times[max(bisect.bisect_right(times, t) - 1, 0)]


def _row_time(row: int, sample_times: list[int], fs: float | None) -> int:
    """A one-based row number of the physio file (beyond it: at SamplingFrequency) → its time."""
    if 1 <= row <= len(sample_times):
        return sample_times[row - 1]
    if not sample_times or fs is None:
        raise ValueError("row outside the recording")
    anchor = 1 if row < 1 else len(sample_times)
    return sample_times[anchor - 1] + round((row - anchor) * 1e9 / fs)


def _message(log: SessionLog, t: int, text: str, path: Path, line: int) -> None:
    if text.startswith("gazehdr scene "):
        log.scenes.append(SceneChange(t, text[len("gazehdr scene ") :]))
        return
    if text == "gazehdr reset":
        log.resets.append(EyeReset(t))
        return
    for prefix in ("gazehdr params ", "gazehdr model ", "gazehdr clock "):
        if text.startswith(prefix):
            try:
                value = json.loads(text[len(prefix) :])
            except json.JSONDecodeError as e:
                raise FormatError(path, line, "message", f"{prefix.strip()}: {e.msg}") from None
            if not isinstance(value, dict):
                raise FormatError(path, line, "message", f"{prefix.strip()}: not an object")
            if prefix == "gazehdr params ":
                log.params.append(ParamsChange(t, value))
            elif prefix == "gazehdr model ":
                model, split = value.get("model"), value.get("split")
                if not isinstance(model, str) or not isinstance(split, (str, type(None))):
                    raise FormatError(path, line, "message", "gazehdr model: model, split names")
                log.models.append(ModelChange(t, model, split))
            else:
                log.clocks.append(
                    ClockUpdate(t, value.get("offset_ns"), value.get("offset_uncertainty_ns"))
                )
            return
    log.notes.append(Note(t, text))


# --- export -----------------------------------------------------------------------------------


def _number_text(value: float | int | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return NA
    return str(int(value)) if isinstance(value, int) else repr(float(value))


def _gzip_tsv(path: Path, rows: list[list[str]]) -> None:
    text = io.StringIO()
    csv.writer(text, delimiter="\t", lineterminator="\n").writerows(rows)
    with (
        open(path, "wb") as raw,
        gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as f,
    ):
        f.write(text.getvalue().encode("utf-8"))


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


def _event_rows(
    log: SessionLog, eye: str, own_eyes: set[str], stamps: list[int]
) -> list[list[str]]:
    """This recording's physioevents rows, sorted by onset; `stamps`: the physio timestamps."""
    mine = [e for e in log.events if (e.eye if e.eye in own_eyes else "cyclopean") == eye]
    rows: list[tuple[int, int, list[str]]] = []
    starts: dict[tuple[str, int, str | None], GazeEvent] = {}
    for e in sorted(mine, key=lambda e: e.t_ns):
        family, _, phase = e.kind.partition("_")
        key = (family, e.id, e.eye)
        if phase == "start":
            starts[key] = e
            continue
        if phase != "end":
            continue  # fixation_update: an online detector's intermediate state
        start = starts.pop(key, None)
        duration = (
            e.duration_ns if e.duration_ns is not None else (e.t_ns - start.t_ns if start else None)
        )
        onset = start.t_ns if start else e.t_ns - (duration or 0)
        rows.append((onset, len(rows), _event_row(duration, family, e)))
    for start in starts.values():
        family = start.kind.partition("_")[0]
        rows.append((start.t_ns, len(rows), _event_row(None, family, start)))
    if eye == "cyclopean":
        messages: list[tuple[int, str]] = [(n.t_ns, n.text) for n in log.notes]
        messages += [(s.t_ns, f"gazehdr scene {s.name}") for s in log.scenes]
        messages += [
            (
                p.t_ns,
                "gazehdr params " + json.dumps(p.values, sort_keys=True, separators=(",", ":")),
            )
            for p in log.params
        ]
        messages += [
            (m.t_ns, "gazehdr model " + json.dumps({"model": m.model, "split": m.split}))
            for m in log.models
        ]
        messages += [(r.t_ns, "gazehdr reset") for r in log.resets]
        messages += [
            (
                c.t_ns,
                "gazehdr clock "
                + json.dumps(
                    {"offset_ns": c.offset_ns, "offset_uncertainty_ns": c.offset_uncertainty_ns},
                    separators=(",", ":"),
                ),
            )
            for c in log.clocks
        ]
        for t, text in messages:
            rows.append((t, len(rows), [NA, NA, NA, text, NA, NA, NA, NA]))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [[str(t), str(_sample_at(stamps, t)), *rest] for t, _, rest in rows]


def _event_row(duration: int | None, family: str, e: GazeEvent) -> list[str]:
    """The columns after onset and timestamp."""
    fixation = family == "fixation"
    return [
        _number_text(duration),
        family,
        "0" if fixation else "1",
        NA,
        _number_text(e.x) if fixation else NA,
        _number_text(e.y) if fixation else NA,
        _number_text(e.dispersion_deg) if fixation else NA,
        e.eye or NA,
    ]


def write_bids(
    log: SessionLog,
    out_dir: str | Path,
    *,
    prefix: str = "sub-01_task-gazehdr",
    overwrite: bool = False,
) -> list[Path]:
    """Write `log` as BIDS eye-tracking physio files in `out_dir`; returns the files written."""
    if not prefix or not all(_ENTITY.fullmatch(p) for p in prefix.split("_")):
        raise ValueError(f"prefix {prefix!r}: expected BIDS entities such as sub-01_task-name")
    if "recording" in _split_name(prefix + "_x")[0]:
        raise ValueError("prefix must not hold the recording entity: it is added per eye")
    if not log.samples:
        raise ValueError(
            "the log has no samples: a BIDS physio file needs some, and the physioevents "
            "are indexed by their timestamps"
        )
    out = Path(out_dir)
    per_eye = any(s.left is not None or s.right is not None for s in log.samples)
    labels = (
        [("eye1", "left"), ("eye2", "right"), ("eye3", "cyclopean")]
        if per_eye
        else [("eye1", "cyclopean")]
    )
    own_eyes = {"left", "right"} if per_eye else set()
    targets = [
        out / f"{prefix}_recording-{label}_{kind}{ext}"
        for label, _ in labels
        for kind in ("physio", "physioevents")
        for ext in (".tsv.gz", ".json")
    ]
    existing = [t for t in targets if t.exists()]
    if existing and not overwrite:
        raise FileExistsError(17, "exists (pass --overwrite to replace)", str(existing[0]))
    out.mkdir(parents=True, exist_ok=True)

    times = [s.t_ns for s in log.samples]
    stamps = sorted(times)
    steps = [b - a for a, b in itertools.pairwise(times) if b > a]
    fs: float | str = round(1e9 / statistics.median(steps), 6) if steps else NA
    screen = log.header.screen
    hyp = math.hypot(screen.screen_width_px, screen.screen_height_px)
    stimulus = {
        "ScreenResolution": [screen.screen_width_px, screen.screen_height_px],
        "ScreenSize": [
            screen.screen_diagonal_m * screen.screen_width_px / hyp,
            screen.screen_diagonal_m * screen.screen_height_px / hyp,
        ],
        "ScreenDistance": screen.viewing_distance_m,
    }
    tracker = log.header.tracker
    for label, eye in labels:

        def position(s: GazeSample, eye: str = eye) -> tuple[float, float, float | None]:
            if eye == "cyclopean":
                return (s.x, s.y, None) if s.valid else (math.nan, math.nan, None)
            e = s.left if eye == "left" else s.right
            return (e.x, e.y, e.pupil_mm) if e is not None else (math.nan, math.nan, None)

        values = [position(s) for s in log.samples]
        pupil = any(p is not None and math.isfinite(p) for _, _, p in values)
        columns = ["timestamp", "x_coordinate", "y_coordinate"] + (["pupil_size"] if pupil else [])
        rows = []
        for s, (x, y, p) in zip(log.samples, values, strict=True):
            row = [str(s.t_ns), _number_text(x), _number_text(y)]
            rows.append([*row, _number_text(p)] if pupil else row)
        base = out / f"{prefix}_recording-{label}_physio"
        _gzip_tsv(base.with_name(base.name + ".tsv.gz"), rows)
        sidecar: dict[str, Any] = {
            "PhysioType": "eyetrack",
            "Columns": columns,
            "SamplingFrequency": fs,
            "StartTime": 0,
            "RecordedEye": eye,
            "SampleCoordinateSystem": "gaze-on-screen",
            "SampleCoordinateUnits": "pixel",
            "EnvironmentCoordinates": "top-left",
            "timestamp": {
                "Description": "Time of the sample on the recording's clock "
                f"({log.header.clock.source}).",
                "Units": "ns",
            },
            "x_coordinate": {
                "Description": "Gaze position, screen x, origin top-left.",
                "Units": "pixel",
            },
            "y_coordinate": {
                "Description": "Gaze position, screen y, origin top-left.",
                "Units": "pixel",
            },
            "StimulusPresentation": stimulus,
            "GazehdrHeader": log.header.to_json(),
        }
        if pupil:
            sidecar["pupil_size"] = {"Description": "Pupil diameter.", "Units": "mm"}
        for key, name in (("manufacturer", "Manufacturer"), ("model", "ManufacturersModelName")):
            if isinstance(tracker.get(key), str):
                sidecar[name] = tracker[key]
        _write_json(base.with_name(base.name + ".json"), sidecar)

        events_base = out / f"{prefix}_recording-{label}_physioevents"
        _gzip_tsv(
            events_base.with_name(events_base.name + ".tsv.gz"),
            _event_rows(log, eye, own_eyes, stamps),
        )
        _write_json(
            events_base.with_name(events_base.name + ".json"),
            {
                "Columns": _EVENT_COLUMNS,
                "Description": "Fixations, blinks and messages recorded with gazehdr.",
                "ForeignIndexColumn": "timestamp",
                "onset": {
                    "Description": "Exact time of the event (a fixation's or blink's start), "
                    "on the clock of the physio timestamp.",
                    "Units": "ns",
                },
                "timestamp": {
                    "Description": "The physio timestamp of the sample at or before the onset "
                    "(the first sample's for an earlier event): the ForeignIndexColumn.",
                    "Units": "ns",
                },
                "duration": {"Description": "Duration of the fixation or blink.", "Units": "ns"},
                "trial_type": {
                    "Description": "Event type.",
                    "Levels": {"fixation": "A fixation.", "blink": "A blink."},
                },
                "blink": {
                    "Description": "Eye state.",
                    "Levels": {"0": "Open.", "1": "Closed."},
                },
                "message": {"Description": "Notes; scene and parameter changes ('gazehdr ...')."},
                "x_coordinate": {"Description": "Mean fixation position x.", "Units": "pixel"},
                "y_coordinate": {"Description": "Mean fixation position y.", "Units": "pixel"},
                "dispersion": {
                    "Description": "Fixation dispersion, (max x - min x) + (max y - min y).",
                    "Units": "deg",
                },
                "eye": {"Description": "The eye an event came from, when another recording's."},
            },
        )
    return targets
