"""BIDS eye-tracking import and export: the fixtures of tests/data/formats (eye2bids-style),
the export's files, and the round trip native → BIDS → native."""

from __future__ import annotations

import csv
import gzip
import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from test_formats import DATA, NAN, approx_rows, assert_names, events, xyv

from gazehdr.drivers.formats.bids import read_bids, write_bids
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
)


def bids_copy(tmp_path: Path, edit: tuple[str, int, str] | None = None) -> Path:
    """A copy of the BIDS fixture (a dataset the validator accepts, test_bids_dataset.py).

    `edit` = (file, line, text) replaces one line of a TSV.GZ.
    """
    root = tmp_path / "bids"
    shutil.copytree(DATA / "bids", root)
    if edit:
        target, line, text = edit
        with gzip.open(root / target, "rt") as f:
            lines = f.read().splitlines()
        lines[line - 1] = text
        with gzip.open(root / target, "wt") as f:
            f.write("\n".join(lines) + "\n")
    return root


EYE1 = "sub-01/beh/sub-01_task-freeview_recording-eye1_physio"
EYE2 = "sub-01/beh/sub-01_task-freeview_recording-eye2_physio"


def test_bids_binocular_eyelink_style_dataset(tmp_path: Path) -> None:
    root = bids_copy(tmp_path)
    log = read_bids(root / f"{EYE2}.tsv.gz")  # any file of the set names the set
    ms = 1_000_000
    assert approx_rows(xyv(log)) == approx_rows([
        (7186799 * ms, 423.195, 268.695, True),  # mean of the two recordings
        (7186801 * ms, 423.1, 270.0, True),
        (7186803 * ms, 431.0, 272.0, True),  # left n/a: the right eye
        (7186805 * ms, 415.79, 264.6, True),  # right n/a: the left eye
        (7186807 * ms, 424.145, 269.1, True),
    ])  # fmt: skip
    s = log.samples[2]
    # pupil_size in a.u. (eye2bids: EyeLink's area): kept in the tracker's units, not as mm
    assert math.isnan(s.left.x) and s.right == EyeSample(431.0, 272.0, None, 4520.0)
    assert events(log) == [
        ("fixation_start", 1, 7186799 * ms, None, None, None, "left"),
        ("fixation_start", 2, 7186799 * ms, None, None, None, "right"),
        ("fixation_end", 1, 7186803 * ms, None, None, 4 * ms, "left"),
        ("saccade_start", 1, 7186803 * ms, None, None, None, "left"),  # a saccade row with
        ("blink_start", 1, 7186803 * ms, None, None, None, "left"),  # blink = 1: both
        ("blink_end", 1, 7186805 * ms, None, None, 2 * ms, "left"),  # at one time: L, then R;
        ("saccade_end", 1, 7186805 * ms, None, None, 2 * ms, "left"),  # ends, the blink first
        ("fixation_start", 3, 7186805 * ms, None, None, None, "left"),
        ("fixation_end", 2, 7186805 * ms, None, None, 6 * ms, "right"),
        ("fixation_end", 3, 7186809 * ms, None, None, 4 * ms, "left"),
    ]
    # the two eyes' files repeat the device messages: kept once, quotes removed; the
    # _events.tsv row at the first sample's time (onset 0, StartTime 0), its values named
    assert log.notes == [
        Note(7184392 * ms, "RECCFG CR 500 2 1 LR"),
        Note(7186771 * ms, "First task trigger"),
        Note(7186799 * ms, "events: duration=0.01 trial_number=1"),
    ]
    screen = log.header.screen  # from task-freeview_events.json, inherited from the root
    assert (screen.screen_width_px, screen.screen_height_px) == (1280, 1024)
    assert screen.screen_diagonal_m == pytest.approx(math.hypot(0.376, 0.301))
    assert screen.viewing_distance_m == pytest.approx(0.6)  # "60": centimetres
    assert log.header.tracker["DeviceSerialNumber"] == "CLG-BAF38"  # root sidecar, inherited
    assert log.header.tracker["eyes"] == ["left", "right"]
    assert read_bids(root / "sub-01" / "beh").samples == log.samples  # the directory works too


def test_bids_timestamp_unit_inferred_and_bottom_left(tmp_path: Path) -> None:
    root = bids_copy(tmp_path)
    side = root / "task-freeview_physio.json"
    data = json.loads(side.read_text())
    del data["timestamp"]["Units"]  # eye2bids writes none: 2-unit steps at 500 Hz are ms
    data["EnvironmentCoordinates"] = "bottom-left"
    side.write_text(json.dumps(data))
    log = read_bids(root / f"{EYE1}.tsv.gz")
    assert log.samples[0].t_ns == 7186799 * 1_000_000
    assert log.samples[0].left.y == pytest.approx(1024 - 267.39)
    data["SamplingFrequency"] = 7
    side.write_text(json.dumps(data))
    with pytest.raises(FormatError, match="fits none of s, ms, us, ns") as info:
        read_bids(root / f"{EYE1}.tsv.gz")
    assert info.value.field == "timestamp.Units"


@pytest.mark.parametrize("first_column", ["onset", "foreign_index"])
def test_bids_implicit_indexing_by_zero_based_row(tmp_path: Path, first_column: str) -> None:
    """Implicit indexing: the zero-based physio row, negative before the first (at
    SamplingFrequency). BIDS 1.11: `"OnsetSource": "n/a"` and the `onset` column; drafts: no
    OnsetSource (nor ForeignIndexColumn) and a `foreign_index` column."""
    root = bids_copy(tmp_path)
    side = root / "task-freeview_physioevents.json"
    data = json.loads(side.read_text())
    if first_column == "onset":
        data["OnsetSource"] = "n/a"
    else:
        del data["OnsetSource"]
    data["Columns"] = [first_column, "duration", "trial_type", "blink", "message"]
    data["duration"] = {"Units": "ms"}
    side.write_text(json.dumps(data))
    for eye in (EYE1, EYE2):
        with gzip.open(root / f"{eye}events.tsv.gz", "wt") as f:
            f.write("-2\tn/a\tn/a\tn/a\tReady\n0\t4\tfixation\t0\tn/a\n3\tn/a\tn/a\tn/a\tend\n")
    log = read_bids(root / f"{EYE1}.tsv.gz")
    ms = 1_000_000
    physio_notes = [n for n in log.notes if not n.text.startswith("events: ")]
    assert physio_notes == [Note(7186795 * ms, "Ready"), Note(7186805 * ms, "end")]  # 500 Hz
    assert [(e.kind, e.t_ns, e.eye) for e in log.events if e.eye == "left"] == [
        ("fixation_start", 7186799 * ms, "left"),  # row 0: the first sample
        ("fixation_end", 7186803 * ms, "left"),
    ]


def test_bids_explicit_indexing_third_party_files(tmp_path: Path) -> None:
    """Explicit indexing in the specification's shape (only the ForeignIndexColumn): events at
    those sample times. An extra `onset` with Units is taken, exactly, only when it lies in the
    sample interval its `timestamp` names (gazehdr's files), not when it is on another clock."""
    ms = 1_000_000
    cases = [  # Columns, onset Units, rows, the notes' times
        (["timestamp", "message"], None, ["7186801", "7186805"], [7186801 * ms, 7186805 * ms]),
        (
            ["onset", "timestamp", "message"],
            "ms",
            ["7186801.5\t7186801", "7186806.25\t7186805"],
            [7186801 * ms + ms // 2, 7186806 * ms + ms // 4],
        ),
        (
            ["onset", "timestamp", "message"],
            "s",  # seconds from the start, as BIDS _events.tsv: not the physio clock
            ["2.5\t7186801", "6.25\t7186805"],
            [7186801 * ms, 7186805 * ms],
        ),
    ]
    for case, (columns, onset_units, rows, times) in enumerate(cases):
        root = bids_copy(tmp_path / str(case))
        sidecar = {
            "Columns": columns,
            "Description": "Messages logged by the measurement device",
            "ForeignIndexColumn": "timestamp",
        }
        if onset_units:
            sidecar["onset"] = {"Units": onset_units}
        (root / "task-freeview_physioevents.json").write_text(json.dumps(sidecar))
        for eye in (EYE1, EYE2):
            with gzip.open(root / f"{eye}events.tsv.gz", "wt") as f:
                f.write(f'{rows[0]}\t"Recalibrate"\n{rows[1]}\tNew block\n')
        log = read_bids(root / f"{EYE1}.tsv.gz")
        physio_notes = [n for n in log.notes if not n.text.startswith("events: ")]
        assert physio_notes == [Note(times[0], "Recalibrate"), Note(times[1], "New block")], case


def test_bids_screen_origin_and_distance_vector(tmp_path: Path) -> None:
    """BIDS 1.11 puts the origin in the events sidecar's `StimulusPresentation.ScreenOrigin`;
    `ScreenDistance` may be the [X, Y, Z] offset of the screen's centre from the eye."""
    root = bids_copy(tmp_path)
    side = root / "task-freeview_events.json"
    data = json.loads(side.read_text())
    data["StimulusPresentation"]["ScreenOrigin"] = ["bottom", "left"]
    data["StimulusPresentation"]["ScreenDistance"] = [0.0, 0.3, 0.4]
    side.write_text(json.dumps(data))
    log = read_bids(root)
    assert log.samples[0].left.y == pytest.approx(1024 - 267.39)
    assert log.header.screen.viewing_distance_m == pytest.approx(0.5)
    data["StimulusPresentation"]["ScreenOrigin"] = ["center", "center"]
    side.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"\['center', 'center'\]; supported") as info:
        read_bids(root)
    assert (info.value.path, info.value.field) == (str(side), "StimulusPresentation.ScreenOrigin")


def test_bids_messages_unescaped_only_where_the_sidecar_says(tmp_path: Path) -> None:
    """gazehdr writes tabs, line breaks and backslashes as `\\t`, `\\n`, `\\\\` (the validator
    splits rows on every tab) and says so; another tool's backslash is a backslash."""
    root = bids_copy(tmp_path)
    for eye in (EYE1, EYE2):
        with gzip.open(root / f"{eye}events.tsv.gz", "wt") as f:
            f.write("7186771\tn/a\tn/a\tn/a\tC:\\new\\tab\n")
    assert [n.text for n in read_bids(root).notes][:1] == ["C:\\new\\tab"]
    side = root / "task-freeview_physioevents.json"
    side.write_text(json.dumps({**json.loads(side.read_text()), "GazehdrEscapedText": True}))
    assert [n.text for n in read_bids(root).notes][:1] == ["C:\new\tab"]


@pytest.mark.parametrize(
    ("target", "line", "text", "field", "reason"),
    [
        (f"{EYE1}.tsv.gz", 2, "7186801\t416.20\tabc\t4623.0", "y_coordinate", "number or n/a"),
        (f"{EYE1}.tsv.gz", 2, "7186801\t416.20\t269.00", None, "3 fields; the sidecar's Columns"),
        (f"{EYE1}.tsv.gz", 2, "soon\t416.20\t269.00\t4623.0", "timestamp", "expected a number"),
        (f"{EYE1}.tsv.gz", 3, "7186790\t416.20\t269.00\t4623.0", "timestamp", "goes back"),
        (f"{EYE1}events.tsv.gz", 3, "7186799\tlong\tfixation\t0\tn/a", "duration", "number or n/a"),
        (f"{EYE1}events.tsv.gz", 3, "first\t4\tfixation\t0\tn/a", "onset", "expected a number"),
    ],
)
def test_bids_malformed_rows_name_file_line_and_field(
    tmp_path: Path, target: str, line: int, text: str, field: str | None, reason: str
) -> None:
    root = bids_copy(tmp_path, (target, line, text))
    with pytest.raises(FormatError, match=reason) as info:
        read_bids(root / f"{EYE1}.tsv.gz")
    assert_names(info.value, root / target, line, field)


@pytest.mark.parametrize(
    ("change", "field", "reason"),
    [
        ({"Columns": None}, "Columns", "required"),
        ({"Columns": ["timestamp", "x", "y", "p"]}, "Columns", "no 'x_coordinate'"),
        ({"PhysioType": "generic"}, "PhysioType", "expected 'eyetrack'"),
        ({"SampleCoordinateUnits": "deg"}, "SampleCoordinateUnits", "screen pixels"),
        ({"timestamp": {"Units": "fortnight"}}, "timestamp.Units", "supported"),
        ({"RecordedEye": "both"}, "RecordedEye", "left, right or cyclopean"),
    ],
)
def test_bids_sidecar_errors_name_the_field(
    tmp_path: Path, change: dict, field: str, reason: str
) -> None:
    root = bids_copy(tmp_path)
    side = root / f"{EYE1}.json"
    side.write_text(json.dumps({**json.loads(side.read_text()), **change}))
    with pytest.raises(FormatError, match=reason) as info:
        read_bids(root / f"{EYE1}.tsv.gz")
    assert info.value.field == field
    assert info.value.path == str(side)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("ScreenResolution", [0.4, 1080]),  # rounds to no pixels
        ("ScreenResolution", [1e400, 1080]),  # JSON's overflow: inf, which no int holds
        ("ScreenResolution", [True, 1080]),
        ("ScreenResolution", [70_000, 1080]),  # wider than any display
        ("ScreenSize", [1e400, 0.3]),
        ("ScreenDistance", 1e400),
    ],
)
def test_bids_screen_values_no_display_has_are_refused_naming_the_field(
    tmp_path: Path, key: str, value: Any
) -> None:
    """The events sidecar's StimulusPresentation, out of any display's range: a FormatError
    naming the file and the key, not an OverflowError from round(inf) or a screen of 0 pixels
    from 0.4."""
    root = bids_copy(tmp_path)
    events = root / "task-freeview_events.json"
    sidecar = json.loads(events.read_text())
    sidecar["StimulusPresentation"][key] = value
    events.write_text(json.dumps(sidecar).replace("Infinity", "1e400"))
    with pytest.raises(FormatError, match="expected") as info:
        read_bids(root)
    assert (info.value.path, info.value.field) == (str(events), key)


def test_bids_errors_name_the_file_that_gave_the_key_or_should_have(tmp_path: Path) -> None:
    """An inherited key's error names the dataset-level file; a missing one, the recording's own
    sidecar (where to add it)."""
    root = bids_copy(tmp_path)
    side = root / "task-freeview_physio.json"
    side.write_text(json.dumps({**json.loads(side.read_text()), "SamplingFrequency": -5}))
    with pytest.raises(FormatError, match="expected a positive number") as info:
        read_bids(root)
    assert (info.value.path, info.value.field) == (str(side), "SamplingFrequency")
    root = bids_copy(tmp_path / "2")
    (root / "task-freeview_physioevents.json").unlink()
    with pytest.raises(FormatError, match="required, with an 'onset' column") as info:
        read_bids(root)
    assert (info.value.path, info.value.field) == (str(root / f"{EYE1}events.json"), "Columns")


def native_log() -> SessionLog:
    """A log with everything BIDS can carry: both eyes, pupils, events, notes, settings."""
    header = SessionHeader(
        tracker={"name": "hid eye tracker", "model": "ET-1", "manufacturer": "Acme"},
        screen=ScreenGeometry(0.55, 1920, 1080, 0.65),
        clock=ClockInfo("monotonic_ns", -12_345, 800),
        created="2024-06-01T08:00:00.000+00:00",
    )
    log = SessionLog(header)
    t0 = 1_234_567_890_123
    for i in range(12):
        t = t0 + i * 4_166_667  # 240 Hz, not a whole number of µs
        if i in (5, 6):
            log.add(GazeSample(t, NAN, NAN, False, EyeSample(NAN, NAN), EyeSample(NAN, NAN)))
        elif i == 8:
            log.add(
                GazeSample(
                    t, 800.5, 400.25, True, EyeSample(NAN, NAN), EyeSample(800.5, 400.25, 3.75)
                )
            )
        else:
            left = EyeSample(790.0 + i / 3, 395.0 - i / 7, 3.5 + i / 100)
            right = EyeSample(810.0 + i / 3, 405.0 - i / 7, 3.6 + i / 100)
            log.add(GazeSample(t, 800.0 + i / 3, 400.0 - i / 7, True, left, right))  # fmt: skip
    for e in [
        GazeEvent("fixation_start", 1, t0, 790.0, 395.0, 0, 0.0),
        GazeEvent("fixation_update", 1, t0 + 8_333_334, 800.1, 400.1, 8_333_334, 0.05),
        GazeEvent("fixation_end", 1, t0 + 16_666_668, 800.2, 399.9, 16_666_668, 0.07),
        GazeEvent("blink_start", 2, t0 + 5 * 4_166_667, duration_ns=8_333_334),
        GazeEvent("blink_end", 2, t0 + 7 * 4_166_667, duration_ns=8_333_334),
        GazeEvent("fixation_start", 3, t0 + 30_000_000, eye="right"),
        GazeEvent("fixation_end", 3, t0 + 40_000_000, 801.0, 402.0, 10_000_000, 0.1, "right"),
        GazeEvent("fixation_start", 4, t0 + 45_000_000),  # still going when the log ends
    ]:
        log.add(e)
    log.add(SceneChange(t0 - 1_000, "checker-night"))
    log.add(ParamsChange(t0 - 1_000, {"a1": 0.25, "preset": "paper"}))
    log.add(ModelChange(t0 - 1_000, "jacobs+stochastic"))
    log.add(ModelChange(t0 + 3, "ritschel+none", split="mikamo+stochastic"))
    log.add(EyeReset(t0 + 3))
    log.add(Note(t0 + 1, 'said "now"\tand\nwaited'))
    log.add(ClockUpdate(t0 + 2, -12_300, 600))
    return log


def comparable(log: SessionLog) -> dict:
    def eye(e: EyeSample | None) -> tuple | None:
        return None if e is None else (repr(e.x), repr(e.y), e.pupil_mm)

    return {
        "header": log.header,
        "samples": [
            (s.t_ns, repr(s.x), repr(s.y), s.valid, eye(s.left), eye(s.right)) for s in log.samples
        ],
        "scenes": log.scenes,
        "params": log.params,
        "models": log.models,
        "resets": log.resets,
        "notes": log.notes,
        "clocks": log.clocks,
    }


def test_native_bids_native_round_trip(tmp_path: Path) -> None:
    log = native_log()
    root = tmp_path / "out"
    written = write_bids(log, root, sub="07", ses="1", task="hdr")
    run = "sub-07/ses-1/beh/sub-07_ses-1_task-hdr"
    assert sorted(p.relative_to(root).as_posix() for p in written) == sorted([
        "dataset_description.json",
        "README.md",
        "participants.tsv",
        f"{run}_events.tsv",
        f"{run}_events.json",
        *(
            f"{run}_recording-{eye}_{kind}{ext}"
            for eye in ("eye1", "eye2")  # the gaze is the eyes' mean: no cyclopean copy
            for kind in ("physio", "physioevents")
            for ext in (".tsv.gz", ".json")
        ),
    ])  # fmt: skip
    side = json.loads((root / f"{run}_recording-eye1_physio.json").read_text())
    assert side["RecordedEye"] == "left" and side["Columns"][:3] == [
        "timestamp",
        "x_coordinate",
        "y_coordinate",
    ]
    assert side["SamplingFrequency"] == pytest.approx(240, rel=1e-6)
    assert side["Manufacturer"] == "Acme"
    with gzip.open(root / f"{run}_recording-eye1_physio.tsv.gz", "rt") as f:
        first = f.readline().rstrip("\n").split("\t")
    assert first == ["1234567890123", "790.0", "395.0", "3.5"]  # header-less, left, ns

    back = read_bids(root / f"{run}_recording-eye2_physio.tsv.gz")
    assert comparable(back) == comparable(log)
    # fixations and blinks come back as start/end pairs with their ids; updates and start
    # positions do not
    assert events(back) == [
        ("fixation_start", 1, log.events[0].t_ns, None, None, None, None),
        ("fixation_end", 1, log.events[2].t_ns, 800.2, 399.9, 16_666_668, None),
        ("blink_start", 2, log.events[3].t_ns, None, None, None, None),
        ("blink_end", 2, log.events[4].t_ns, None, None, 8_333_334, None),
        ("fixation_start", 3, log.events[5].t_ns, None, None, None, "right"),
        ("fixation_end", 3, log.events[6].t_ns, 801.0, 402.0, 10_000_000, "right"),
        ("fixation_start", 4, log.events[7].t_ns, None, None, None, None),
    ]
    assert [e.dispersion_deg for e in back.events if e.kind == "fixation_end"] == [0.07, 0.1]


def test_bids_round_trip_keeps_repeated_notes_and_samples_without_an_eye(tmp_path: Path) -> None:
    """The same note twice at one time is two notes (only a message in several eyes' files is
    one); a sample without per-eye data (EyeLink's END) comes back without it."""
    log = native_log()
    t = log.samples[3].t_ns
    log.add(Note(t, "twice"))
    log.add(Note(t, "twice"))
    log.add(GazeSample(log.samples[-1].t_ns + 1, NAN, NAN, False))
    write_bids(log, tmp_path)
    back = read_bids(tmp_path)
    assert [n for n in back.notes if n.text == "twice"] == [Note(t, "twice")] * 2
    assert comparable(back) == comparable(log)
    assert back.samples[-1].left is None and back.samples[-1].right is None


def gz_rows(path: Path) -> list[list[str]]:
    with gzip.open(path, "rt", encoding="utf-8", newline="") as f:
        return list(csv.reader(f, delimiter="\t"))


def test_bids_export_onsets_on_the_timestamp_clock_durations_in_seconds(tmp_path: Path) -> None:
    """BIDS 1.11 "Physiology events": the REQUIRED `OnsetSource` names the physio column whose
    values `onset` shares, so each onset is the event's exact time in the timestamp's clock and
    unit (ns), before the first sample or after the last as well; `duration` is in seconds
    (the schema's `columns.duration`), exact to the ns."""
    log = native_log()
    log.add(Note(log.samples[-1].t_ns + 10**9, "after the last sample"))
    written = write_bids(log, tmp_path / "ds")
    for physio in (p for p in written if p.name.endswith("_physio.tsv.gz")):
        events = physio.with_name(physio.name.replace("_physio.", "_physioevents."))
        side = json.loads(events.with_name(events.name.replace(".tsv.gz", ".json")).read_text())
        physio_side = json.loads(
            physio.with_name(physio.name.replace(".tsv.gz", ".json")).read_text()
        )
        assert side["OnsetSource"] == "timestamp" and "ForeignIndexColumn" not in side
        assert side["onset"]["Units"] == physio_side["timestamp"]["Units"] == "ns"
        assert side["duration"]["Units"] == "s"
        assert side["Columns"][0] == "onset" and "timestamp" not in side["Columns"]
    # the gaze is the mean of the eyes: no cyclopean recording; eye1 holds the events of no eye
    assert not any("eye3" in p.name for p in written)
    eye1 = next(p for p in written if p.name.endswith("eye1_physioevents.tsv.gz"))
    side = json.loads(eye1.with_name(eye1.name.replace(".tsv.gz", ".json")).read_text())
    rows = [dict(zip(side["Columns"], row, strict=True)) for row in gz_rows(eye1)]
    first, last = log.samples[0].t_ns, log.samples[-1].t_ns
    onsets = [int(r["onset"]) for r in rows]
    assert onsets == sorted(onsets) and min(onsets) < first and max(onsets) > last
    assert [(int(r["onset"]), r["duration"]) for r in rows if r["trial_type"] != "n/a"] == [
        (log.events[0].t_ns, "0.016666668"),  # the fixation: 16 666 668 ns
        (log.events[3].t_ns, "0.008333334"),  # the blink
        (log.events[7].t_ns, "n/a"),  # a fixation still going when the log ends
    ]


def test_bids_export_refuses_a_log_without_samples(tmp_path: Path) -> None:
    log = native_log()
    log.samples = []
    with pytest.raises(ValueError, match="no samples"):
        write_bids(log, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_round_trip_without_per_eye_data_and_reproducible_gzip(tmp_path: Path) -> None:
    log = native_log()
    log.samples = [GazeSample(s.t_ns, s.x, s.y, s.valid) for s in log.samples]
    log.events = [e for e in log.events if e.eye is None]
    first = write_bids(log, tmp_path / "a")
    recordings = [p for p in first if "_recording-" in p.name]
    assert [p.name for p in recordings][:2] == [
        "sub-01_task-gazehdr_recording-eye1_physio.tsv.gz",
        "sub-01_task-gazehdr_recording-eye1_physio.json",
    ]
    assert len(recordings) == 4
    back = read_bids(recordings[0])
    assert comparable(back) == comparable(log)
    second = write_bids(log, tmp_path / "b")
    assert [p.read_bytes() for p in first] == [p.read_bytes() for p in second]
    with pytest.raises(FileExistsError):
        write_bids(log, tmp_path / "a")
    write_bids(log, tmp_path / "a", overwrite=True)
    with pytest.raises(ValueError, match="--run 'x': a BIDS run is digits"):
        write_bids(log, tmp_path / "c", run="x")
    with pytest.raises(ValueError, match="--sub 'subject one': a BIDS sub is letters and digits"):
        write_bids(log, tmp_path / "c", sub="subject one")
    assert not (tmp_path / "c").exists()


def test_bids_round_trip_keeps_each_events_id_whatever_its_eye(tmp_path: Path) -> None:
    """A right-eye fixation numbered before a left-eye one that starts at the same time (as
    EDF2ASC writes them when the right eye's event comes first) keeps its id through export and
    import (`event_id`), instead of the ids swapping between the eyes. Guards: the importer
    numbering gazehdr's own rows anew."""
    log = native_log()
    t = log.samples[2].t_ns
    log.events = [
        GazeEvent("fixation_start", 1, t, eye="right"),
        GazeEvent("fixation_start", 2, t, eye="left"),
        GazeEvent("fixation_end", 2, t + 8_333_334, 790.0, 395.0, 8_333_334, eye="left"),
        GazeEvent("fixation_end", 1, t + 8_333_334, 810.0, 405.0, 8_333_334, eye="right"),
    ]
    write_bids(log, tmp_path / "ds")
    back = read_bids(tmp_path / "ds")
    assert sorted((e.kind, e.id, e.eye) for e in back.events) == sorted(
        (e.kind, e.id, e.eye) for e in log.events
    )
