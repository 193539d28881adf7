"""Reading a recording's `_physioevents`: fixations, blinks and messages, timed on its samples.

What import assumes (BIDS 1.11.1 "Physiology events"; the drafts before it, and eye2bids):

- Event times: `"OnsetSource": "timestamp"`: `onset` is on the physio timestamp's clock, in its
  unit. `"OnsetSource": "n/a"`: `onset` is the zero-based physio row, negative before the first
  (at SamplingFrequency). Drafts: `ForeignIndexColumn` naming `timestamp`, the events' column of
  that name (or `onset`, eye2bids) holding a physio timestamp, or without it a `foreign_index`
  column (zero-based row), or lacking one `onset` as the one-based row. Where the timestamp
  column names a sample, a file that also has an `onset` with `Units` (gazehdr's exports before
  BIDS 1.11) gives the exact time from it, provided every onset lies in the sample interval its
  timestamp names (the sample at or before it, or the first sample for an earlier one);
  otherwise (an onset on another clock, such as seconds from the start) the timestamp column is
  used.
- Events: a `fixation` row gives `fixation_start` at `onset` and `fixation_end` at `onset +
  duration`; a `saccade` row `saccade_start` and `saccade_end` (landing at its `x_coordinate`,
  `y_coordinate`, starting at gazehdr's `start_x_coordinate`, `start_y_coordinate` where a row
  has them); a `blink` row, or any row with `blink` = 1 (eye2bids marks the saccade around an
  EyeLink blink so), a blink over the row's interval (and, for a saccade row, the saccade too).
  Any other row (another trial type, or none) becomes a note at its onset, `physioevents:
  column=value ...` with the row's values that are not n/a, so that no row is dropped. A
  `message` becomes a note (`gazehdr scene NAME`, `gazehdr params {json}`, `gazehdr model
  {json}`, `gazehdr reset` and `gazehdr clock {json}` messages become scene, parameter, model,
  reset and clock records; escapes undone where the sidecar says `GazehdrEscapedText`). A
  message that several eyes' files hold (eye2bids writes each in both) is read once; one
  repeated within a file, as often as it is there. Event ids are gazehdr's `event_id` where a
  row has one (its exports: ids as the log had them), else numbered 1, 2, ... per kind in onset
  order; at one time, left-eye events come before right-eye ones. A row's `eye` column says its
  eye; without one (n/a) the recording's eye, except in gazehdr's exports, where n/a is an event
  of no particular eye. An end's duration is gazehdr's `tracker_duration` where a row has one
  (the tracker's own, EyeLink's), else `duration` is in its sidecar `Units`, else in the onset's
  units when OnsetSource names the timestamp (as the specification's example and eye2bids write
  it), else seconds.
"""

from __future__ import annotations

import bisect
import json
import math
from collections import Counter
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import ESCAPED_TEXT, NA, unescape_text
from gazehdr.drivers.formats.bids.physio import (
    UNITS_NS,
    Sidecar,
    _float,
    _Recording,
    _rows,
    _sidecar,
    _units,
)
from gazehdr.drivers.formats.common import decimal_ns, sort_events
from gazehdr.drivers.sessionlog import (
    ClockUpdate,
    EyeReset,
    FormatError,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    SceneChange,
    SessionLog,
)

_ROW = "foreign_index"  # drafts' implicit indexing: the zero-based row of the physio file


def _sample_at(times: list[int], t: int) -> int:
    """The time of the sample at or before `t` (the first sample's for an earlier `t`)."""
    return times[max(bisect.bisect_right(times, t) - 1, 0)]


_KNOWN = frozenset({"fixation", "blink", "saccade"})
_ROW_TEXT_SKIPS = frozenset({"onset", "message"})


def _row_note(source: str, columns: list[str], row: dict[str, str]) -> str:
    """A row that is no event, as a note: its values that are not n/a, named."""
    values = [
        f"{c}={row[c]}"
        for c in columns
        if c not in _ROW_TEXT_SKIPS and row.get(c, NA) not in (NA, "")
    ]
    return f"{source}: {' '.join(values)}" if values else f"{source}: (a row of n/a)"


def _read_events(
    log: SessionLog, recordings: list[_Recording], flip: int | None, native: bool = False
) -> None:
    """The run's physioevents into `log` (events, notes, and the records gazehdr's messages
    carry). `native`: a run gazehdr exported, whose `eye` column is the whole truth."""
    intervals: list[tuple] = []
    messages: Counter[tuple[int, str]] = Counter()  # the most of each in any one file
    for r in recordings:
        stem = r.path.name.split(".", 1)[0]
        ext = r.path.name[len(stem) :]
        path = r.path.with_name(stem[: -len("physio")] + "physioevents" + ext)
        if not path.exists():
            continue
        side = _sidecar(path, "physioevents", r.entities)
        columns = side.get("Columns")
        # which column times a row, and how (see the module docstring)
        key = "ForeignIndexColumn" if "ForeignIndexColumn" in side else "OnsetSource"
        index = side.get(key)
        first_row = 0
        if index == NA:  # BIDS 1.11: onset is the zero-based physio row
            index, when = None, "onset"
        elif index:  # the spec names the events' column after it; eye2bids calls it onset
            when = index if isinstance(columns, list) and index in columns else "onset"
        else:  # drafts' implicit indexing: foreign_index, the zero-based physio row
            when = _ROW if isinstance(columns, list) and _ROW in columns else "onset"
            first_row = 0 if when == _ROW else 1
        if not isinstance(columns, list) or when not in columns:
            raise side.error(
                "Columns",
                "required, with an 'onset' column (or the drafts' foreign_index or "
                "ForeignIndexColumn)",
            )
        if index is not None and index != "timestamp":
            raise side.error(key, f"{index!r}; supported: timestamp, n/a")
        if index is not None and "timestamp" not in r.columns:
            raise side.error(key, "the physio file has no timestamp column")
        time_unit = r.timestamp_unit_ns if index else None
        duration_unit = _unit_ns(side, "duration") or time_unit or 10**9
        escaped = side.get(ESCAPED_TEXT) is True
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
        file_eye = r.eye if r.eye in ("left", "right") and not native else None
        reported_unit = _unit_ns(side, "tracker_duration") or duration_unit
        read_here: Counter[tuple[int, str]] = Counter()
        for line, row, t in timed:
            duration = _duration(path, line, row, "duration", duration_unit)
            reported = _duration(path, line, row, "tracker_duration", reported_unit)
            kind = row.get("trial_type", NA)
            blink = row.get("blink", NA)
            eye = row.get("eye", NA)
            eye = eye if eye in ("left", "right") else file_eye
            message = row.get("message", NA)
            message = unescape_text(message) if escaped else message
            ident = _event_id(path, line, row)
            if kind == "saccade":
                x = _float(path, line, row, "x_coordinate") if "x_coordinate" in row else None
                y = _float(path, line, row, "y_coordinate") if "y_coordinate" in row else None
                sx = (
                    _float(path, line, row, "start_x_coordinate")
                    if "start_x_coordinate" in row
                    else None
                )
                sy = (
                    _float(path, line, row, "start_y_coordinate")
                    if "start_y_coordinate" in row
                    else None
                )
                if flip is not None:
                    y = None if y is None else flip - y
                    sy = None if sy is None else flip - sy
                nan = math.nan
                intervals.append(
                    (
                        t,
                        "saccade",
                        duration,
                        reported,
                        nan if x is None or y is None else x,
                        nan if x is None or y is None else y,
                        (
                            nan if sx is None or sy is None else sx,
                            nan if sx is None or sy is None else sy,
                        ),
                        eye,
                        ident,
                    )
                )
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
                        reported,
                        nan if x is None else x,
                        nan if y is None else y,
                        disp,
                        eye,
                        ident,
                    )
                )
            elif kind == "blink" or blink == "1":
                blink_id = ident if kind == "blink" else None
                nan = math.nan
                intervals.append((t, "blink", duration, reported, nan, nan, None, eye, blink_id))
            elif kind not in _KNOWN and (kind not in (NA, "") or message in (NA, "")):
                log.notes.append(Note(t, _row_note("physioevents", columns, row)))
            if message not in (NA, ""):
                # a message in several eyes' files (eye2bids) once; repeats in one file all
                read_here[t, message] += 1
                if read_here[t, message] > messages[t, message]:
                    messages[t, message] += 1
                    _message(log, t, message, path, line)
    ids = {"fixation": 0, "blink": 0, "saccade": 0}
    order = sorted(intervals, key=lambda i: (i[0], i[7] == "right"))
    for t, family, duration, reported, x, y, disp, eye, ident in order:
        ids[family] += 1
        ident = ids[family] if ident is None else ident
        start_x, start_y = disp if family == "saccade" else (math.nan, math.nan)
        disp = None if family == "saccade" else disp
        log.events.append(GazeEvent(f"{family}_start", ident, t, start_x, start_y, eye=eye))
        if duration is not None:
            kept = duration if reported is None else reported
            log.events.append(
                GazeEvent(f"{family}_end", ident, t + duration, x, y, kept, disp, eye)
            )
    log.events[:] = sort_events(log.events)  # at one time, as every importer orders them
    for items in (log.notes, log.scenes, log.params, log.clocks):
        items.sort(key=lambda r: r.t_ns)


def _event_id(path: Path, line: int, row: dict[str, str]) -> int | None:
    """gazehdr's `event_id` column (its exports), or None."""
    text = row.get("event_id", NA)
    if text in (NA, ""):
        return None
    if not text.isdigit() or len(text) > 18:
        raise FormatError(path, line, "event_id", f"expected a whole number, got {text!r}")
    return int(text)


def _duration(path: Path, line: int, row: dict[str, str], column: str, unit: int) -> int | None:
    """A duration column in ns; None where n/a or absent."""
    text = row.get(column, NA)
    if text in (NA, ""):
        return None
    try:
        return decimal_ns(text, unit)
    except ValueError:
        raise FormatError(path, line, column, f"expected a number or n/a, got {text!r}") from None


def _unit_ns(side: Sidecar, column: str) -> int | None:
    """ns per unit of a column's sidecar `Units`; None without one."""
    units = _units(side, column)
    if units is not None and units not in UNITS_NS:
        raise side.error(f"{column}.Units", f"{units!r}; supported: {', '.join(UNITS_NS)}")
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


def _row_time(row: int, sample_times: list[int], fs: float | None) -> int:
    """A one-based row number of the physio file (beyond it: at SamplingFrequency) → its time."""
    if 1 <= row <= len(sample_times):
        return sample_times[row - 1]
    if not sample_times or fs is None:
        raise InputError("row outside the recording")
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
            except RecursionError:  # Python's parser recurses once per level of nesting
                what = f"{prefix.strip()}: JSON nested too deeply"
                raise FormatError(path, line, "message", what) from None
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
