"""The Tobii TSV written by PyGaze's `libtobii` and by `psychopy_tobii_controller` → a session log.

Written from the code that writes these files, since neither has other documentation:

- PyGaze (esdalmaijer/PyGaze, `pygaze/_eyetracker/libtobii.py`, `TobiiController.setDataFile`
  and `flushData`, commit 66e2fdc): lines `Recording date:\\t…`, `Recording time:\\t…`,
  `Recording resolution\\t1920 x 1080`, then PyGaze's report lines (`display size in cm:
  52.0x29.0`, `distance between participant and display: 57 cm`, ...). Each recording block
  (start to stop of recording) writes a header row `TimeStamp GazePointXLeft GazePointYLeft
  ValidityLeft GazePointXRight GazePointYRight ValidityRight GazePointX GazePointY Event`, one
  row per sample, then one row per event (`time`, eight empty fields, the text). Times are ms
  since the block's first sample (`%.1f`); eye positions are screen pixels, origin top-left,
  `-1.0` when Tobii's validity code is 4. `GazePointX/Y` are in normalised units (not pixels),
  so we average the eyes ourselves.
- psychopy_tobii_controller (hsogo/psychopy_tobii_controller,
  `psychopy_tobii_controller/__init__.py`, `open_datafile`, `flush_data`, `get_psychopy_pos`,
  commit 163fd0a, the tobii_research version):
  `Recording resolution:\\t1920 x 1080`, `Event recording mode:\\tEmbedded|Separated`, then per
  block `Session Start`, a header row that adds `PupilLeft`/`PupilRight` (mm, Tobii Pro SDK)
  and with embedded events an `Event` column, sample rows, and `Session End`. Positions are in
  the PsychoPy window's units (origin at the centre, y up), which the file does not record:
  pass `units` ("pix", "norm" or "height"; "cm" and "deg" need the PsychoPy monitor and are
  refused). Validity is 1 (valid) or 0, values `nan` when invalid. Separated events follow a
  `TimeStamp\\tEvent` row; an embedded event's row carries gaze interpolated at the event's
  time, which is not a sample and is not kept as one.

Validity: an eye counts when Tobii marks it valid and its position is finite: for PyGaze's
Tobii SDK 3 codes 0-4, codes 0 and 1 (Tobii's advice is to drop codes 2 and higher: Tobii
staff, "Tobii Validity Codes", mytobiicommunity.com forum); for tobii_research, 1 (the Tobii Pro
SDK's validity is valid/invalid, devtobiipro "Validity codes"). The sample's position is the
mean of the eyes that count; both are kept per eye (NaN when lost).

Times restart at 0 in every block and the gap between blocks is not recorded: each block is
placed one sample interval after the previous one (a note says so). Events become notes.
"""

from __future__ import annotations

import itertools
import math
import re
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.common import (
    MAX_SCREEN_PX,
    decimal_ns,
    geometry_with,
    is_number,
    mean_of_eyes,
)
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import ClockInfo, FormatError, Note, SessionHeader, SessionLog

_MS = 1_000_000
PYGAZE_COLUMNS = (
    "TimeStamp",
    "GazePointXLeft",
    "GazePointYLeft",
    "ValidityLeft",
    "GazePointXRight",
    "GazePointYRight",
    "ValidityRight",
    "GazePointX",
    "GazePointY",
    "Event",
)
PTC_COLUMNS = (
    "TimeStamp",
    "GazePointXLeft",
    "GazePointYLeft",
    "PupilLeft",
    "ValidityLeft",
    "GazePointXRight",
    "GazePointYRight",
    "PupilRight",
    "ValidityRight",
    "GazePointX",
    "GazePointY",
)
UNITS = ("pix", "norm", "height")
_META = {
    "resolution": re.compile(r"Recording resolution:?\t(\d+) x (\d+)"),
    "size_cm": re.compile(r"display size in cm: ([\d.]+)x([\d.]+)"),
    "distance_cm": re.compile(r"distance between participant and display: ([\d.]+) cm"),
    "date": re.compile(r"Recording date:\t(.*)"),
    "time": re.compile(r"Recording time:\t(.*)"),
    "event_mode": re.compile(r"Event recording mode:\t(\w+)"),
}


@dataclass
class _Block:
    samples: list[GazeSample] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)


def read_tobii_tsv(
    path: Path, *, geometry: ScreenGeometry | None = None, units: str | None = None
) -> SessionLog:
    """Read a PyGaze or psychopy_tobii_controller TSV; `units` for the latter's positions."""
    path = Path(path)
    if units is not None and units not in UNITS:
        raise InputError(f"units {units!r}: supported are {', '.join(UNITS)}")
    meta: dict[str, tuple[Any, ...]] = {}
    blocks: list[_Block] = []
    columns: tuple[str, ...] | None = None
    writer: str | None = None
    in_rows = in_events = False
    with path.open(encoding="utf-8", errors="replace", newline="") as f:
        for line, raw in enumerate(f, 1):
            text = raw.rstrip("\r\n")
            fields = text.split("\t")
            if not text.strip():
                continue
            if fields[0] == "TimeStamp":
                if tuple(fields) == ("TimeStamp", "Event"):
                    if writer != "psychopy_tobii_controller" or not blocks:
                        raise FormatError(path, line, "TimeStamp", "an event table outside a block")
                    in_rows, in_events = True, True
                    continue
                columns, writer = _header(path, line, fields)
                if writer == "PyGaze libtobii" or not blocks:
                    blocks.append(_Block())
                in_rows, in_events = True, False
                continue
            if text == "Session Start":
                blocks.append(_Block())
                in_rows = in_events = False
                continue
            if text == "Session End":
                in_rows = in_events = False
                continue
            if not (in_rows and (in_events or len(fields) >= 3 or is_number(fields[0]))):
                for key, pattern in _META.items():  # a header or PyGaze report line
                    match = pattern.fullmatch(text)
                    if match and key not in meta:
                        meta[key] = _meta_values(path, line, key, match)
                in_rows = False
                continue
            if columns is None or writer is None or not blocks:
                raise FormatError(path, line, "TimeStamp", "a data row before any header row")
            block = blocks[-1]
            if in_events:
                if len(fields) < 2:
                    raise FormatError(path, line, "Event", "an event row is TimeStamp<TAB>Event")
                t = _time(path, line, fields[0])
                block.notes.append(Note(t, "\t".join(fields[1:])))
                continue
            if writer == "PyGaze libtobii":
                _pygaze_row(path, line, fields, block)
            else:
                _ptc_row(path, line, fields, columns, block, units, meta)
    if not blocks or not any(b.samples for b in blocks):
        raise FormatError(path, None, "TimeStamp", "no sample rows under a TimeStamp header")
    if "resolution" not in meta and geometry is None:
        raise FormatError(
            path,
            None,
            "Recording resolution",
            "the file does not give the screen size; pass it (--screen WxH)",
        )
    width = height = diagonal = distance = None
    if "resolution" in meta:
        width, height = meta["resolution"]
    if "size_cm" in meta:
        diagonal = math.hypot(*meta["size_cm"]) / 100
    if "distance_cm" in meta:
        distance = meta["distance_cm"][0] / 100
    screen = geometry_with(
        geometry, width_px=width, height_px=height, diagonal_m=diagonal, distance_m=distance
    )
    log = SessionLog(
        SessionHeader(
            tracker={
                "format": "tobii-tsv",
                "writer": writer,
                "file": path.name,
                **({"recording_date": meta["date"][0]} if "date" in meta else {}),
                **({"recording_time": meta["time"][0]} if "time" in meta else {}),
                **({"units": units} if writer == "psychopy_tobii_controller" else {}),
            },
            screen=screen,
            clock=ClockInfo(source="ms since the first sample of the file's first block"),
        ),
        path=path,
    )
    _place_blocks(log, [b for b in blocks if b.samples or b.notes])
    return log


_META_FIELDS = {
    "resolution": "Recording resolution",
    "size_cm": "display size in cm",
    "distance_cm": "distance between participant and display",
}


def _meta_values(path: Path, line: int, key: str, match: re.Match[str]) -> tuple[Any, ...]:
    """The values of a header or report line, checked where they size the screen: a
    resolution of 1 to MAX_SCREEN_PX pixels a side, sizes and a distance in cm that are
    positive numbers (FormatError naming the line otherwise)."""
    texts = match.groups()
    if key not in _META_FIELDS:
        return texts
    shown = match.string[match.start(1) : match.end(len(texts))]
    shown = repr(shown if len(shown) <= 40 else shown[:40] + "...")
    if key == "resolution":
        # at most 6 digits: int() of thousands of digits is refused by Python itself
        pixels = tuple(int(t) if len(t) <= 6 else 0 for t in texts)
        if not all(1 <= p <= MAX_SCREEN_PX for p in pixels):
            raise FormatError(
                path,
                line,
                _META_FIELDS[key],
                f"expected the screen's width x height, 1 to {MAX_SCREEN_PX} pixels each, "
                f"got {shown}",
            )
        return pixels
    try:
        cm = tuple(float(t) for t in texts)
    except ValueError:  # the pattern takes any run of digits and dots: "5.3.0", "."
        cm = (math.nan,)
    if not all(math.isfinite(v) and v > 0 for v in cm) or not math.isfinite(math.hypot(*cm)):
        what = "a positive number" if len(texts) == 1 else "positive numbers"
        raise FormatError(path, line, _META_FIELDS[key], f"expected {what} of cm, got {shown}")
    return cm


def _header(path: Path, line: int, fields: list[str]) -> tuple[tuple[str, ...], str]:
    cols = tuple(fields)
    if cols == PYGAZE_COLUMNS:
        return cols, "PyGaze libtobii"
    if cols in (PTC_COLUMNS, (*PTC_COLUMNS, "Event")):
        return cols, "psychopy_tobii_controller"
    raise FormatError(
        path,
        line,
        "TimeStamp",
        f"unrecognised columns {' '.join(cols)}; expected PyGaze's {' '.join(PYGAZE_COLUMNS)} "
        f"or psychopy_tobii_controller's {' '.join(PTC_COLUMNS)} [Event]",
    )


def _time(path: Path, line: int, text: str) -> int:
    try:
        return decimal_ns(text, _MS)
    except ValueError:
        raise FormatError(path, line, "TimeStamp", f"expected a time in ms, got {text!r}") from None


def _number(path: Path, line: int, text: str, name: str) -> float:
    try:
        return float(text)  # 'nan' is how psychopy_tobii_controller writes a lost value
    except ValueError:
        raise FormatError(path, line, name, f"expected a number, got {text!r}") from None


def _validity(path: Path, line: int, text: str, name: str, codes: range) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value not in codes:
        raise FormatError(
            path,
            line,
            name,
            f"expected a validity code {codes.start}-{codes.stop - 1}, got {text!r}",
        )
    return value


def _sample(t: int, left: EyeSample, right: EyeSample) -> GazeSample:
    gaze = mean_of_eyes(left, right)
    if gaze is None:
        return GazeSample(t, math.nan, math.nan, False, left, right)
    return GazeSample(t, gaze[0], gaze[1], True, left, right)


def _check_time(path: Path, line: int, block: _Block, t: int) -> None:
    if block.samples and t < block.samples[-1].t_ns:
        raise FormatError(path, line, "TimeStamp", "time goes back within a recording block")


def _pygaze_row(path: Path, line: int, fields: list[str], block: _Block) -> None:
    if len(fields) == len(PYGAZE_COLUMNS) and not any(fields[1:9]) and fields[9]:
        block.notes.append(Note(_time(path, line, fields[0]), fields[9]))  # an event row
        return
    if len(fields) != len(PYGAZE_COLUMNS):
        raise FormatError(
            path, line, None, f"{len(fields)} fields; the header names {len(PYGAZE_COLUMNS)}"
        )
    t = _time(path, line, fields[0])
    _check_time(path, line, block, t)
    eyes = []
    for x_i, y_i, v_i in ((1, 2, 3), (4, 5, 6)):
        x = _number(path, line, fields[x_i], PYGAZE_COLUMNS[x_i])
        y = _number(path, line, fields[y_i], PYGAZE_COLUMNS[y_i])
        code = _validity(path, line, fields[v_i], PYGAZE_COLUMNS[v_i], range(5))
        ok = code <= 1 and (x, y) != (-1.0, -1.0) and math.isfinite(x) and math.isfinite(y)
        eyes.append(EyeSample(x, y) if ok else EyeSample(math.nan, math.nan))
    block.samples.append(_sample(t, eyes[0], eyes[1]))


def _ptc_row(
    path: Path,
    line: int,
    fields: list[str],
    columns: tuple[str, ...],
    block: _Block,
    units: str | None,
    meta: dict[str, tuple[Any, ...]],
) -> None:
    if len(fields) != len(columns):
        raise FormatError(
            path, line, None, f"{len(fields)} fields; the header names {len(columns)}"
        )
    t = _time(path, line, fields[0])
    if len(columns) > len(PTC_COLUMNS) and fields[-1]:
        block.notes.append(Note(t, fields[-1]))  # gaze on this row is interpolated, not a sample
        return
    if units is None:
        raise FormatError(
            path,
            line,
            "GazePointXLeft",
            "psychopy_tobii_controller writes positions in the PsychoPy window's units, which "
            "the file does not record: pass units (--units pix|norm|height)",
        )
    if "resolution" not in meta:
        raise FormatError(
            path, line, "Recording resolution", "needed before the rows to convert positions"
        )
    width, height = meta["resolution"]
    _check_time(path, line, block, t)
    eyes = []
    for x_i, y_i, p_i, v_i in ((1, 2, 3, 4), (5, 6, 7, 8)):
        x = _number(path, line, fields[x_i], columns[x_i])
        y = _number(path, line, fields[y_i], columns[y_i])
        pupil = _number(path, line, fields[p_i], columns[p_i])
        code = _validity(path, line, fields[v_i], columns[v_i], range(2))
        if code == 1 and math.isfinite(x) and math.isfinite(y):
            px, py = _to_pixels(x, y, units, width, height)
            eyes.append(EyeSample(px, py, pupil if math.isfinite(pupil) else None))
        else:
            eyes.append(EyeSample(math.nan, math.nan))
    block.samples.append(_sample(t, eyes[0], eyes[1]))


def _to_pixels(x: float, y: float, units: str, width: int, height: int) -> tuple[float, float]:
    """PsychoPy window coordinates (origin centre, y up) → screen pixels (origin top-left)."""
    if units == "pix":
        return x + width / 2, height / 2 - y
    if units == "norm":
        return (x + 1) / 2 * width, (1 - y) / 2 * height
    return x * height + width / 2, (0.5 - y) * height  # "height"


def _place_blocks(log: SessionLog, blocks: list[_Block]) -> None:
    offset = 0
    previous: list[int] = []
    for k, block in enumerate(blocks):
        times = [s.t_ns for s in block.samples]
        if k > 0:
            steps = [b - a for a, b in itertools.pairwise(previous) if b > a]
            step = int(statistics.median(steps)) if steps else _MS
            end = log.samples[-1].t_ns if log.samples else offset
            offset = end + step - (times[0] if times else 0)
            log.notes.append(
                Note(
                    end + step,
                    f"tobii: recording block {k + 1} restarts its clock at 0 in the file; placed "
                    f"{step / 1e6:g} ms after block {k} (the real gap is not recorded)",
                )
            )
        for s in block.samples:
            log.samples.append(GazeSample(s.t_ns + offset, s.x, s.y, s.valid, s.left, s.right))
        log.notes += [Note(n.t_ns + offset, n.text) for n in block.notes]
        previous = times or previous
    log.notes.sort(key=lambda n: n.t_ns)
