"""Export (`write_bids`): a native session log as one run of a BIDS eye-tracking dataset that the
official validator (`bids-validator-deno`) accepts with no error.

The run goes to `<root>/sub-<sub>/[ses-<ses>/]beh/` (BIDS 1.11.1 `rules/files/raw/task.yaml`:
physio in the `beh` datatype), named `sub-<sub>[_ses-<ses>]_task-<task>[_run-<run>]_...`:

- `_events.tsv` + `.json`: the session's scene, model and parameter changes, resets, clock
  updates and notes (`trial_type` says which, `message` holds the name, JSON or text), `onset`
  in seconds from the first gaze sample (the physio files' `StartTime` 0), `duration` n/a. The
  sidecar's `StimulusPresentation` gives `ScreenDistance`, `ScreenOrigin` ["top", "left"],
  `ScreenResolution` and `ScreenSize` (m, from the diagonal and the pixel aspect) from the log's
  screen geometry: REQUIRED for gaze-on-screen data ("Eye-tracking", `checks/eyetrack.yaml`).
- `_recording-eye<N>_physio.tsv.gz` + `.json`, one recording per eye ("it is REQUIRED that
  recordings corresponding to each eye ... are split"): `eye1` holds the gaze when the log has
  no per-eye data (`RecordedEye` the header's eye where `tracker.eyes` names one, a monocular
  EyeLink recording; else cyclopean); otherwise `eye1` left, `eye2` right (each only where some
  sample has that eye; a sample without it, EyeLink's END, has no row there), and `eye3`
  cyclopean only where those do not give back the gaze (`_recordings`: nothing is invented).
  Columns `timestamp` (the log's integer ns, `Units` "ns"), `x_coordinate`, `y_coordinate`
  (pixels, top-left), `pupil_size` (diameter, mm) when an eye has one. The sidecar carries the
  hardware, tracking-mode and calibration metadata the log has (`_metadata`) and
  `GazehdrRecording` ("eye" or "gaze"). An empty log imported from an empty run has an empty
  recording per eye its header names, at its `rate_hz`.
- `_recording-eye<N>_physioevents.tsv.gz` + `.json`: that eye's fixations, saccades and blinks
  (one row each: onset, duration, a fixation's mean position and dispersion, a saccade's landing
  and start, the log's `event_id`); the gaze's recording (or `eye1` without one) also holds the
  events of no particular eye and, as messages, what `_events.tsv` holds (`gazehdr scene NAME`,
  `gazehdr params {json}`, ..., notes as they are). `"OnsetSource": "timestamp"`: `onset` is on
  the physio timestamp's clock, in its unit (ns), so it is exact; `duration` is in seconds
  (`columns.duration`), written exactly (nine decimals at most), the end minus the start, so
  that onset + duration is the end; `tracker_duration` (s) keeps the duration the tracker
  reported where it is not that (EyeLink's counts both ends: one sample period more).

The native header rides along in the physio sidecars as `GazehdrHeader`, so native → BIDS →
native gives back the same samples, fixations (start and end times, mean position, dispersion;
not the start position nor `fixation_update`, which BIDS rows do not hold), blinks, notes,
scenes, parameters, models, resets and header. gzip output is reproducible (no name or time in
the gzip header, which is also what the validator's privacy checks want).
"""

from __future__ import annotations

import csv
import gzip
import io
import itertools
import json
import math
import statistics
from collections.abc import Iterable
from decimal import Decimal
from importlib.metadata import version
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import (
    ESCAPED_TEXT,
    INDEX,
    LABEL,
    NA,
    escape_text,
    file_stem,
)
from gazehdr.drivers.formats.bids.layout import (
    prepare_dataset,
    refuse_existing_run,
    run_files,
    write_json,
)
from gazehdr.drivers.formats.common import mean_of_eyes
from gazehdr.drivers.samples import EyeSample, GazeSample
from gazehdr.drivers.sessionlog import GazeEvent, SessionLog

_EVENT_COLUMNS = [
    "onset",
    "duration",
    "trial_type",
    "blink",
    "message",
    "x_coordinate",
    "y_coordinate",
    "dispersion",
    "eye",
    "tracker_duration",
    "event_id",
    "start_x_coordinate",
    "start_y_coordinate",
]
#: EyeLink's tracking mode (`RECCFG`: CR or P) as the specification's `EyeTrackingMethod`.
_TRACKING_METHOD = {"CR": "P-CR", "P": "pupil-only"}
_MESSAGE_KINDS = {
    "scene": "The scene shown from here on (its name).",
    "params": "Model parameters set (JSON).",
    "model": "The model, and the split-screen model, from here on (JSON).",
    "reset": "The simulated eye's state reset.",
    "clock": "A new estimate of the offset to the server clock, ns (JSON).",
    "note": "A note (free text).",
}
_ESCAPES_NOTE = " Tab, line breaks and backslash are written as \\t, \\n, \\r and \\\\."


def _number_text(value: float | int | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return NA
    return str(int(value)) if isinstance(value, int) else repr(float(value))


def _seconds(ns: int | None) -> str:
    """Integer ns as exact decimal seconds: 16666668 → `0.016666668`."""
    return NA if ns is None else format(Decimal(ns).scaleb(-9).normalize(), "f")


def _tsv(rows: list[list[str]]) -> bytes:
    text = io.StringIO()
    csv.writer(text, delimiter="\t", lineterminator="\n").writerows(rows)
    return text.getvalue().encode("utf-8")


def _write_gzip_tsv(path: Path, rows: list[list[str]]) -> None:
    with (
        open(path, "wb") as raw,
        gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as f,
    ):
        f.write(_tsv(rows))


def _messages(log: SessionLog) -> list[tuple[int, str, str]]:
    """(t_ns, kind, payload) of everything but gaze: notes, scenes, settings, resets, clocks."""
    found = [(n.t_ns, "note", n.text) for n in log.notes]
    found += [(s.t_ns, "scene", s.name) for s in log.scenes]
    found += [
        (p.t_ns, "params", json.dumps(p.values, sort_keys=True, separators=(",", ":")))
        for p in log.params
    ]
    found += [
        (m.t_ns, "model", json.dumps({"model": m.model, "split": m.split})) for m in log.models
    ]
    found += [(r.t_ns, "reset", "") for r in log.resets]
    found += [
        (
            c.t_ns,
            "clock",
            json.dumps(
                {"offset_ns": c.offset_ns, "offset_uncertainty_ns": c.offset_uncertainty_ns},
                separators=(",", ":"),
            ),
        )
        for c in log.clocks
    ]
    return sorted(found, key=lambda m: m[0])  # stable: at one time, in the order above


def _message_text(kind: str, payload: str) -> str:
    """The physioevents `message` the importer reads back (`physioevents._message`)."""
    if kind == "note":
        return payload
    return f"gazehdr {kind}" + (f" {payload}" if payload else "")


def _event_rows(log: SessionLog, eye: str, own_eyes: set[str], catch_all: bool) -> list[list[str]]:
    """This recording's physioevents rows, sorted by onset (ns, on the timestamp's clock): the
    events of its eye; with `catch_all`, also those of an eye with no recording of its own, of
    no eye, and the messages."""
    mine = [
        e
        for e in log.events
        if e.eye == eye or (catch_all and (e.eye is None or e.eye not in own_eyes))
    ]
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
        if start is not None:  # onset + duration is the end, exactly, as the reader rebuilds it
            onset, duration = start.t_ns, e.t_ns - start.t_ns
        else:
            onset, duration = e.t_ns - (e.duration_ns or 0), e.duration_ns
        # the tracker's own duration where it is not end - start (EyeLink counts both ends)
        reported = e.duration_ns if e.duration_ns != duration else None
        rows.append((onset, len(rows), _event_row(duration, reported, family, e, start)))
    for start in starts.values():
        family = start.kind.partition("_")[0]
        row = _event_row(None, None, family, start, start)
        rows.append((start.t_ns, len(rows), row))
    if catch_all:
        for t, kind, payload in _messages(log):
            text = escape_text(_message_text(kind, payload))
            rows.append((t, len(rows), [NA, NA, NA, text, *[NA] * (len(_EVENT_COLUMNS) - 5)]))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [[str(t), *rest] for t, _, rest in rows]


def _event_row(
    duration: int | None,
    reported: int | None,
    family: str,
    e: GazeEvent,
    start: GazeEvent | None = None,
) -> list[str]:
    """The columns after onset: a fixation's mean position and dispersion, a saccade's landing
    (and, from its start, where it began)."""
    placed = family in ("fixation", "saccade")
    saccade = family == "saccade" and start is not None
    return [
        _seconds(duration),
        family,
        "1" if family == "blink" else "0",
        NA,
        _number_text(e.x) if placed else NA,
        _number_text(e.y) if placed else NA,
        _number_text(e.dispersion_deg) if family == "fixation" else NA,
        e.eye or NA,
        _seconds(reported),
        str(int(e.id)),
        _number_text(start.x) if saccade else NA,
        _number_text(start.y) if saccade else NA,
    ]


def _entities(sub: str, ses: str | None, task: str, run: str | None) -> dict[str, str]:
    """The run's entities, each checked: labels alphanumeric, the run an index."""
    entities = {"sub": sub, "ses": ses, "task": task, "run": run}
    for key, value in entities.items():
        pattern = INDEX if key == "run" else LABEL
        if value is not None and not pattern.fullmatch(value):
            what = "digits" if key == "run" else "letters and digits only"
            raise InputError(f"--{key} {value!r}: a BIDS {key} is {what}")
    return {k: v for k, v in entities.items() if v is not None}


def write_bids(
    log: SessionLog,
    root: str | Path,
    *,
    sub: str = "01",
    task: str = "gazehdr",
    ses: str | None = None,
    run: str | None = None,
    overwrite: bool = False,
) -> list[Path]:
    """Write `log` as a run of the BIDS dataset at `root` (made if new); returns the files
    written. An existing run is refused (FileExistsError) unless `overwrite`; other runs and
    subjects are left as they are."""
    entities = _entities(sub, ses, task, run)
    steps = [b - a for a, b in itertools.pairwise(s.t_ns for s in log.samples) if b > a]
    rate = log.header.tracker.get("rate_hz")
    rate = rate if isinstance(rate, (int, float)) and not isinstance(rate, bool) else None
    if steps:
        fs = round(1e9 / statistics.median(steps), 6)
    elif not log.samples and rate is not None and math.isfinite(rate) and rate > 0:
        fs = float(rate)  # an empty run (a dataset's, imported): its recordings stay empty
    else:
        what = f"samples at one time only ({len(log.samples)})" if log.samples else "no samples"
        raise InputError(
            f"the log has {what}: a BIDS physio file needs samples at two times at least, for "
            "its SamplingFrequency (REQUIRED)"
        )
    root = Path(root)
    folder = root / f"sub-{sub}" / (f"ses-{ses}" if ses else "") / "beh"
    if not overwrite:
        refuse_existing_run(folder, entities)
    generated_by = {"Name": "gazehdr", "Version": version("gazehdr")}
    written = prepare_dataset(root, sub, generated_by)
    for old in run_files(folder, entities):  # a run exported before may have had other eyes
        old.unlink()
    folder.mkdir(parents=True, exist_ok=True)

    def target(suffix: str, ext: str, recording: str | None = None) -> Path:
        path = folder / (file_stem({**entities, "recording": recording}, suffix) + ext)
        written.append(path)
        return path

    t0 = min((s.t_ns for s in log.samples), default=0)
    events = [["onset", "duration", "trial_type", "message"]]
    events += [[_seconds(t - t0), NA, k, escape_text(p) or NA] for t, k, p in _messages(log)]
    target("events", ".tsv").write_bytes(_tsv(events))
    write_json(target("events", ".json"), _events_sidecar(log, task))

    for n, (label, source, recorded, role) in enumerate(_recordings(log)):
        if source == "cyclopean":
            eyes = [(s.t_ns, EyeSample(s.x, s.y) if s.valid else None) for s in log.samples]
        else:  # a sample without this eye's data has no row in its file
            eyes = [(s.t_ns, e) for s in log.samples if (e := _eye(s, source))]
        pupil = _pupil_unit(e for _, e in eyes)
        rows = []
        for t, e in eyes:
            row = [str(t), *(_number_text(v) for v in ((e.x, e.y) if e else (math.nan,) * 2))]
            size = None if e is None else e.pupil_mm if pupil == "mm" else e.pupil_au
            rows.append([*row, _number_text(size)] if pupil else row)
        _write_gzip_tsv(target("physio", ".tsv.gz", label), rows)
        sidecar = _physio_sidecar(log, task, fs, recorded, pupil, role)
        write_json(target("physio", ".json", label), sidecar)
        own = {src for _, src, _, _ in _recordings(log) if src in ("left", "right")}
        # the first recording (eye2 alone for a right eye) takes what belongs to no eye
        events = _event_rows(log, source, own, catch_all=role == "gaze" or n == 0)
        _write_gzip_tsv(target("physioevents", ".tsv.gz", label), events)
        write_json(target("physioevents", ".json", label), _physioevents_sidecar(task))
    return written


def _recordings(log: SessionLog) -> list[tuple[str, str, str, str]]:
    """(label, the samples' source, RecordedEye, role) of each recording to write: an eye's
    data ("eye": `eye1` left, `eye2` right, each only where some sample has it) and the gaze
    ("gaze", `eye3`, cyclopean) only where the eyes' recordings do not give it back (a sample
    with no eye's data, or a gaze that is not their mean: nothing is invented). A log without
    per-eye data has only the gaze, in `eye1`, its `RecordedEye` the header's eye where
    `tracker.eyes` names one (a monocular EyeLink recording), else cyclopean. An empty log
    (an imported empty run) has an empty recording of each eye its header names."""
    eyes = [e for e in ("left", "right") if any(_eye(s, e) for s in log.samples)]
    header_eyes = log.header.tracker.get("eyes")
    if not log.samples and isinstance(header_eyes, list):
        eyes = [e for e in ("left", "right") if e in header_eyes]
        if not eyes:
            return [("eye1", "cyclopean", "cyclopean", "gaze")]
    if not eyes:
        mono = header_eyes in (["left"], ["right"])
        return [("eye1", "cyclopean", header_eyes[0] if mono else "cyclopean", "gaze")]
    labels = [(f"eye{i + 1}", e, e, "eye") for i, e in enumerate(("left", "right")) if e in eyes]
    if any(not _eyes_give_back(s) for s in log.samples):
        labels.append(("eye3", "cyclopean", "cyclopean", "gaze"))
    return labels


def _eyes_give_back(s: GazeSample) -> bool:
    """Whether the eyes' rows give back this sample as the importer rebuilds it (the mean of
    the eyes with a position; a sample no eye's file has a row for is lost)."""
    if s.left is None and s.right is None:
        return False
    gaze = mean_of_eyes(s.left, s.right)
    if gaze is None:
        return not s.valid
    return s.valid and (gaze[0], gaze[1]) == (s.x, s.y)


def _eye(s: GazeSample, eye: str) -> EyeSample | None:
    return s.left if eye == "left" else s.right


def _events_sidecar(log: SessionLog, task: str) -> dict[str, Any]:
    screen = log.header.screen
    hyp = math.hypot(screen.screen_width_px, screen.screen_height_px)
    return {
        "TaskName": task,
        "StimulusPresentation": {
            "ScreenDistance": screen.viewing_distance_m,
            "ScreenOrigin": ["top", "left"],
            "ScreenResolution": [screen.screen_width_px, screen.screen_height_px],
            "ScreenSize": [
                screen.screen_diagonal_m * screen.screen_width_px / hyp,
                screen.screen_diagonal_m * screen.screen_height_px / hyp,
            ],
        },
        "onset": {
            "Description": "Time of the change, from the first gaze sample of the run's "
            "physio files (their StartTime 0).",
            "Units": "s",
        },
        "duration": {"Description": "n/a: a change holds until the next.", "Units": "s"},
        "trial_type": {"Description": "What changed.", "Levels": _MESSAGE_KINDS},
        "message": {"Description": "The scene name, the JSON or the note." + _ESCAPES_NOTE},
        ESCAPED_TEXT: True,
    }


def _pupil_unit(eyes: Iterable[EyeSample | None]) -> str | None:
    """The unit of a recording's `pupil_size` column: mm where any sample has a pupil in mm,
    else the tracker's arbitrary units where any has one of those, else no column."""
    unit = None
    for e in eyes:
        if e is not None and e.pupil_mm is not None and math.isfinite(e.pupil_mm):
            return "mm"
        if e is not None and e.pupil_au is not None and math.isfinite(e.pupil_au):
            unit = "a.u."
    return unit


def _physio_sidecar(
    log: SessionLog, task: str, fs: float, eye: str, pupil: str | None, role: str
) -> dict[str, Any]:
    side: dict[str, Any] = {
        "TaskName": task,
        "PhysioType": "eyetrack",
        "Columns": ["timestamp", "x_coordinate", "y_coordinate"] + (["pupil_size"] * bool(pupil)),
        "SamplingFrequency": fs,
        "StartTime": 0,
        "RecordedEye": eye,
        "SampleCoordinateSystem": "gaze-on-screen",
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
    }
    if pupil == "mm":
        side["pupil_size"] = {"Description": "Pupil diameter.", "Units": "mm"}
    elif pupil:  # EyeLink's PUPIL line says area or diameter
        measure = log.header.tracker.get("pupil")
        what = measure if measure in ("area", "diameter") else "size"
        side["pupil_size"] = {
            "Description": f"Pupil {what} as the eye tracker measures it, in its own arbitrary "
            "units.",
            "Units": pupil,
        }
    side.update(_metadata(log, eye))
    side["GazehdrRecording"] = role
    side["GazehdrHeader"] = log.header.to_json()
    return side


def _metadata(log: SessionLog, eye: str) -> dict[str, Any]:
    """The hardware and eye-tracking metadata of the recording of `eye` (BIDS 1.11
    `PhysioHardware`, `EyeTrack`): what an imported BIDS run had (`tracker.bids_metadata`),
    else what the header says (its BIDS keys, and an EyeLink import's model, serial number,
    tracking mode and validations: the last one of this eye gives `CalibrationType` and the
    errors, their count `CalibrationCount`)."""
    tracker = log.header.tracker
    out: dict[str, Any] = {}
    for keys, name in (
        (("Manufacturer", "manufacturer"), "Manufacturer"),
        (("ManufacturersModelName", "model"), "ManufacturersModelName"),
        (("DeviceSerialNumber", "serial"), "DeviceSerialNumber"),
        (("SoftwareVersions",), "SoftwareVersions"),
    ):
        value = next((tracker[k] for k in keys if isinstance(tracker.get(k), str)), None)
        if value is not None:
            out[name] = value
    if tracker.get("format") == "eyelink-asc":
        out.setdefault("Manufacturer", "SR Research")
        if tracker.get("tracking") in _TRACKING_METHOD:
            out["EyeTrackingMethod"] = _TRACKING_METHOD[tracker["tracking"]]
        validations = tracker.get("validations")
        if isinstance(validations, list):
            mine = [v for v in validations if isinstance(v, dict) and v.get("eye") == eye]
            if mine:
                last = mine[-1]
                if isinstance(last.get("type"), str):
                    out["CalibrationType"] = last["type"]
                out["CalibrationCount"] = len(mine)
                for key, name in (
                    ("error_avg_deg", "AverageCalibrationError"),
                    ("error_max_deg", "MaximalCalibrationError"),
                ):
                    if isinstance(last.get(key), (int, float)):
                        out[name] = last[key]
    metadata = tracker.get("bids_metadata")
    if isinstance(metadata, dict) and isinstance(metadata.get(eye), dict):
        out.update(metadata[eye])
    return out


def _physioevents_sidecar(task: str) -> dict[str, Any]:
    return {
        "TaskName": task,
        "Columns": _EVENT_COLUMNS,
        "Description": "Fixations, saccades, blinks and messages recorded with gazehdr.",
        "OnsetSource": "timestamp",
        "onset": {
            "Description": "Time of the event (a fixation's or blink's start), exact, on the "
            "clock of the physio timestamp (the OnsetSource).",
            "Units": "ns",
        },
        "duration": {"Description": "Duration of the fixation or blink.", "Units": "s"},
        "trial_type": {
            "Description": "Event type.",
            "Levels": {"fixation": "A fixation.", "blink": "A blink.", "saccade": "A saccade."},
        },
        "blink": {"Description": "Eye state.", "Levels": {"0": "Open.", "1": "Closed."}},
        "message": {
            "Description": "Notes; scene, model and parameter changes, resets and clock updates "
            "('gazehdr ...')." + _ESCAPES_NOTE
        },
        "x_coordinate": {
            "Description": "Mean fixation position x; where a saccade landed.",
            "Units": "pixel",
        },
        "y_coordinate": {
            "Description": "Mean fixation position y; where a saccade landed.",
            "Units": "pixel",
        },
        "start_x_coordinate": {"Description": "Where a saccade began, x.", "Units": "pixel"},
        "start_y_coordinate": {"Description": "Where a saccade began, y.", "Units": "pixel"},
        "event_id": {
            "Description": "The event's id in the gazehdr session log (a fixation's, blink's "
            "or saccade's; per eye)."
        },
        "dispersion": {
            "Description": "Fixation dispersion, (max x - min x) + (max y - min y).",
            "Units": "deg",
        },
        "eye": {
            "Description": "The eye an event came from, when another recording's.",
            "Levels": {"left": "The left eye.", "right": "The right eye."},
        },
        "tracker_duration": {
            "Description": "The duration the tracker reported, where it is not the event's "
            "end minus its start (onset + duration): EyeLink counts the first and the last "
            "sample, one sample period more; n/a where it is the same.",
            "Units": "s",
        },
        ESCAPED_TEXT: True,
    }
