"""Writing a native session log as BIDS eye-tracking physio files.

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

import csv
import gzip
import io
import itertools
import json
import math
import re
import statistics
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.bids.files import NA, _sample_at, _split_name
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import GazeEvent, SessionLog

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
