"""Pupil Player's `gaze_positions.csv` (Pupil Core, Raw Data Exporter) → a session log.

Written from Pupil Labs' own sources: the exporter that writes the file (pupil-labs/pupil,
`pupil_src/shared_modules/raw_data_exporter.py`, `Gaze_Positions_Exporter`: a header row, then
`gaze_timestamp, world_index, confidence, norm_pos_x, norm_pos_y, base_data, gaze_point_3d_x,
..., gaze_normal1_z`, empty fields where a value is None) and the Pupil Core terminology page
(pupil-labs/pupil-docs, `src/core/terminology.md`: timestamps are seconds of "Pupil Time", a
monotonic clock with an arbitrary epoch; "2D Normalized Space" has its origin at the
**bottom** left, unit image width/height).

- Time: `gaze_timestamp` seconds → integer ns, exactly (the decimal text, not a float).
  Files from Pupil versions before `gaze_timestamp` was named call it `timestamp`.
- Position: `norm_pos_x`, `norm_pos_y` are normalised coordinates of the world camera image,
  origin bottom-left; we take that image as the screen, so x_px = norm_x · width and
  y_px = (1 − norm_y) · height (flipped to our top-left origin). Values outside [0, 1] (gaze
  off the image) are kept. The file records no screen: `geometry` gives it (default
  `ScreenGeometry()`, 1920×1080).
- Validity: a sample whose `confidence` is below `min_confidence` (0.6, the default of Pupil
  Player's `min_data_confidence`, below which its exporter leaves data out) is invalid.
- Other columns (3d gaze, eye centres, normals) are not used. Blank lines (a first line left
  blank by a spreadsheet, say) are skipped wherever they are.
- Beside it, Pupil Player's other exports of the same recording, when they are there:
  `fixations.csv` (Fixation Detector: `id`, `start_timestamp` s, `duration` ms, `norm_pos_x`,
  `norm_pos_y`, `dispersion` degrees, ...) gives `fixation_start` and `fixation_end` (at the
  start plus the duration, at its mean position, flipped as gaze is); `blinks.csv` (Blink
  Detector: `id`, `start_timestamp`, `end_timestamp` s, ...) gives `blink_start` and
  `blink_end`. Their ids are Pupil's. A row that is malformed is refused, naming the file, the
  line and the field.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.common import decimal_ns, finite_float
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    ClockInfo,
    FormatError,
    GazeEvent,
    SessionHeader,
    SessionLog,
)

MIN_CONFIDENCE = 0.6
_REQUIRED = ("confidence", "norm_pos_x", "norm_pos_y")


def gaze_sample(
    t_ns: int,
    nx: float,
    ny: float,
    confidence: float,
    screen: ScreenGeometry,
    min_confidence: float = MIN_CONFIDENCE,
) -> GazeSample:
    """A Pupil gaze datum as a sample on `screen`: its normalised position (origin bottom-left,
    unit the image's or surface's size; values outside [0, 1] kept) flipped to pixels from the
    top left; invalid below `min_confidence`, or where the position is not finite."""
    if confidence >= min_confidence and math.isfinite(nx) and math.isfinite(ny):
        return GazeSample(t_ns, nx * screen.screen_width_px, (1.0 - ny) * screen.screen_height_px)
    return GazeSample(t_ns, math.nan, math.nan, False)


def read_pupil_gaze_csv(
    path: Path,
    *,
    geometry: ScreenGeometry | None = None,
    min_confidence: float = MIN_CONFIDENCE,
) -> SessionLog:
    """Read a Pupil Player `gaze_positions.csv`; `geometry` is the screen the image stands for."""
    path = Path(path)
    if not 0 <= min_confidence <= 1:
        raise InputError(f"min_confidence must lie in [0, 1], got {min_confidence}")
    screen = geometry or ScreenGeometry()
    samples: list[GazeSample] = []
    # Bytes that are not UTF-8 become U+FFFD: a number holding one is refused by its field.
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as f:
        rows = csv.reader(f)
        header = _header(rows)
        time_column = "gaze_timestamp" if "gaze_timestamp" in header else "timestamp"
        for name in (time_column, *_REQUIRED):
            if name not in header:
                raise FormatError(
                    path,
                    1,
                    name,
                    "missing column; a Pupil Player gaze_positions.csv has gaze_timestamp, "
                    "confidence, norm_pos_x and norm_pos_y",
                )
        index = {name: header.index(name) for name in (time_column, *_REQUIRED)}
        for row in rows:
            line = rows.line_num
            if not any(field.strip() for field in row):
                continue
            if len(row) != len(header):
                raise FormatError(
                    path, line, None, f"{len(row)} fields; the header names {len(header)}"
                )

            def number(name: str, row: list[str] = row, line: int = line) -> float:
                text = row[index[name]]
                try:
                    return finite_float(text)
                except ValueError:
                    raise FormatError(
                        path, line, name, f"expected a number, got {text!r}"
                    ) from None

            text = row[index[time_column]]
            try:
                t = decimal_ns(text, 1_000_000_000)
            except ValueError:
                raise FormatError(
                    path, line, time_column, f"expected a time in seconds, got {text!r}"
                ) from None
            if samples and t < samples[-1].t_ns:
                raise FormatError(path, line, time_column, f"{text} s goes back in time")
            confidence = number("confidence")
            if not 0 <= confidence <= 1:
                raise FormatError(path, line, "confidence", f"must lie in [0, 1], got {confidence}")
            nx, ny = number("norm_pos_x"), number("norm_pos_y")
            samples.append(gaze_sample(t, nx, ny, confidence, screen, min_confidence))
    if not samples:
        raise FormatError(path, None, None, "no gaze rows")
    events = _fixations(path.with_name("fixations.csv"), screen)
    events += _blinks(path.with_name("blinks.csv"))
    header_ = SessionHeader(
        tracker={
            "format": "pupil-player-gaze-positions",
            "file": path.name,
            "coordinates": "world camera image, normalised, origin bottom-left",
            "min_confidence": min_confidence,
        },
        screen=screen,
        clock=ClockInfo(source="Pupil Time"),
    )
    log = SessionLog(header_, samples, path=path)
    log.events = sorted(events, key=lambda e: (e.t_ns, e.kind.endswith("_start")))
    return log


def _header(rows: Any) -> list[str]:
    """The first row that is not blank, as column names."""
    for row in rows:
        if any(field.strip() for field in row):
            return [name.strip() for name in row]
    return []


def _table(path: Path, needed: tuple[str, ...]) -> list[tuple[int, dict[str, str]]]:
    """(line, {column: text}) of a Pupil Player CSV export; [] when there is none."""
    if not path.is_file():
        return []
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as f:
        rows = csv.reader(f)
        header = _header(rows)
        for name in needed:
            if name not in header:
                raise FormatError(path, 1, name, f"missing column; expected {', '.join(needed)}")
        out = []
        for row in rows:
            if not any(field.strip() for field in row):
                continue
            if len(row) != len(header):
                raise FormatError(
                    path, rows.line_num, None, f"{len(row)} fields; the header names {len(header)}"
                )
            out.append((rows.line_num, dict(zip(header, row, strict=True))))
    return out


def _field(path: Path, line: int, row: dict[str, str], name: str, unit_ns: int = 0) -> Any:
    """A number (a time in ns with `unit_ns`), or `FormatError` naming file, line, field."""
    text = row[name].strip()
    try:
        return decimal_ns(text, unit_ns) if unit_ns else finite_float(text)
    except ValueError:
        raise FormatError(path, line, name, f"expected a number, got {text!r}") from None


def _ident(path: Path, line: int, row: dict[str, str]) -> int:
    text = row["id"].strip()
    if not text.isdigit() or len(text) > 18:
        raise FormatError(path, line, "id", f"expected a whole number, got {text!r}")
    return int(text)


def _fixations(path: Path, screen: ScreenGeometry) -> list[GazeEvent]:
    needed = ("id", "start_timestamp", "duration", "norm_pos_x", "norm_pos_y")
    events = []
    for line, row in _table(path, needed):
        ident = _ident(path, line, row)
        start = _field(path, line, row, "start_timestamp", 10**9)
        duration = _field(path, line, row, "duration", 10**6)  # milliseconds
        if duration < 0:
            raise FormatError(path, line, "duration", "a fixation's duration is not negative")
        nx, ny = (_field(path, line, row, name) for name in ("norm_pos_x", "norm_pos_y"))
        x, y = nx * screen.screen_width_px, (1.0 - ny) * screen.screen_height_px
        dispersion = _field(path, line, row, "dispersion") if "dispersion" in row else None
        events.append(GazeEvent("fixation_start", ident, start, x, y))
        events.append(
            GazeEvent("fixation_end", ident, start + duration, x, y, duration, dispersion)
        )
    return events


def _blinks(path: Path) -> list[GazeEvent]:
    events = []
    for line, row in _table(path, ("id", "start_timestamp", "end_timestamp")):
        ident = _ident(path, line, row)
        start = _field(path, line, row, "start_timestamp", 10**9)
        end = _field(path, line, row, "end_timestamp", 10**9)
        if end < start:
            raise FormatError(path, line, "end_timestamp", "a blink ends before it starts")
        events.append(GazeEvent("blink_start", ident, start))
        events.append(GazeEvent("blink_end", ident, end, duration_ns=end - start))
    return events
