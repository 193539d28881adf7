"""BIDS datasets as the official validator sees them: gazehdr's export (a new dataset, runs
added to one; the real EyeLink recordings of tests/data/formats/eyelink_real, there and back
exactly), the project's own fixture, and import from a dataset's root, a subject or session
folder or one file. (No excerpt of a real BIDS dataset is committed until its licence is
settled: tests/data/formats/SOURCES.md.)

The validator is `bids-validator-deno` (the `test` extra) with the schema it bundles (BIDS
1.11.1; it fetches one only when given `--schema` or `BIDS_SCHEMA`, src/setup/loadSchema.ts),
run with the proxy pointed at a closed local port: it must not need the network.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import shutil
import subprocess
import sys
import warnings
from collections import Counter
from pathlib import Path

import pytest
from test_bids import comparable, native_log
from test_formats import DATA

from gazehdr.cli import main as gazehdr_main
from gazehdr.drivers.formats import export_main
from gazehdr.drivers.formats.bids import read_bids, write_bids
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import (
    FormatError,
    Note,
    SessionHeader,
    SessionLog,
    read_session_log,
    write_session_log,
)

RUN = "sub-01/ses-1/beh/sub-01_ses-1_task-hdr"
REAL = DATA / "eyelink_real"


class ValidatorWarning(UserWarning):
    """What the validator warns of, shown in pytest's warnings summary."""


def validate(root: Path) -> dict:
    """The validator's report on `root`; fails the test on any error, lists the warnings."""
    exe = shutil.which("bids-validator-deno", path=str(Path(sys.executable).parent))
    assert exe, "bids-validator-deno is missing: pip install -e '.[test]'"
    # the bundled schema (BIDS_SCHEMA or --schema would fetch one), and no way out if it tried
    offline = {k: v for k, v in os.environ.items() if k != "BIDS_SCHEMA"}
    offline |= {"HTTP_PROXY": "http://127.0.0.1:9", "HTTPS_PROXY": "http://127.0.0.1:9"}
    done = subprocess.run(
        [exe, "--format", "json", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
        env=offline,
        cwd=root,
        check=False,
    )
    try:
        report = json.loads(done.stdout)
    except json.JSONDecodeError:
        pytest.fail(f"the validator crashed on {root} (status {done.returncode}):\n{done.stderr}")
    issues = report["issues"]["issues"]
    errors = [
        f"{i['code']} {i.get('subCode') or ''} {i.get('location', '')}: {i.get('issueMessage', '')}"
        for i in issues
        if i["severity"] == "error"
    ]
    assert not errors, "\n".join(errors)
    counted = Counter(
        (i["code"], i.get("subCode") or "") for i in issues if i["severity"] == "warning"
    )
    if counted:
        listing = ", ".join(f"{c} {s}".strip() + f" ×{n}" for (c, s), n in sorted(counted.items()))
        warnings.warn(ValidatorWarning(f"{root.name}: {listing}"), stacklevel=2)
    return report


def cyclopean_log() -> SessionLog:
    """`native_log` without per-eye data: one recording."""
    log = native_log()
    log.samples = [GazeSample(s.t_ns, s.x, s.y, s.valid) for s in log.samples]
    log.events = [e for e in log.events if e.eye is None]
    return log


def three_runs(tmp_path: Path) -> Path:
    """sub-01 ses-1 run-1 (both eyes) and run-2 (cyclopean), sub-02 ses-1 run-1: through the
    command line, as a researcher would."""
    logs = tmp_path / "logs"
    logs.mkdir()
    both = write_session_log(logs / "both.jsonl", native_log())
    one = write_session_log(logs / "one.jsonl", cyclopean_log())
    root = tmp_path / "bids"
    for log, sub, run in ((both, "01", "1"), (one, "01", "2"), (both, "02", "1")):
        flags = ["--sub", sub, "--ses", "1", "--task", "hdr", "--run", run]
        assert export_main([str(log), "--out", str(root), *flags]) == 0
    return root


# --- the validator ----------------------------------------------------------------------------


def test_an_exported_dataset_passes_the_official_validator(tmp_path: Path) -> None:
    """Subjects, a session, runs, both eyes and one, notes with tabs and line breaks, events
    before the first sample: no error (SPEC §4)."""
    root = three_runs(tmp_path)
    summary = validate(root)["summary"]
    assert sorted(summary["subjects"]) == ["01", "02"]
    assert (summary["sessions"], summary["tasks"]) == (["1"], ["hdr"])
    assert summary["dataTypes"] == ["beh"] and summary["schemaVersion"]


def test_the_fixture_dataset_passes_the_official_validator() -> None:
    validate(DATA / "bids")


# --- export into a dataset --------------------------------------------------------------------


def test_the_events_sidecar_carries_the_screen_and_events_the_changes(tmp_path: Path) -> None:
    """BIDS "Eye-tracking": gaze-on-screen recordings REQUIRE `StimulusPresentation`'s
    ScreenDistance, ScreenOrigin, ScreenResolution and ScreenSize in the events sidecar."""
    log = native_log()  # 0.55 m diagonal, 1920x1080, 0.65 m away
    write_bids(log, tmp_path, sub="01", ses="1", task="hdr")
    side = json.loads((tmp_path / f"{RUN}_events.json").read_text())
    stim = side["StimulusPresentation"]
    assert stim["ScreenResolution"] == [1920, 1080] and stim["ScreenOrigin"] == ["top", "left"]
    assert stim["ScreenDistance"] == 0.65
    assert math.hypot(*stim["ScreenSize"]) == pytest.approx(0.55)
    assert stim["ScreenSize"][0] / stim["ScreenSize"][1] == pytest.approx(1920 / 1080)
    rows = (tmp_path / f"{RUN}_events.tsv").read_text().splitlines()
    assert rows[0] == "onset\tduration\ttrial_type\tmessage"
    assert rows[1] == "-0.000001\tn/a\tscene\tchecker-night"  # before the first sample
    assert rows[4] == '0.000000001\tn/a\tnote\t"said ""now""\\tand\\nwaited"'
    assert rows[7] == "0.000000003\tn/a\treset\tn/a"


def test_adding_runs_keeps_the_others_and_refuses_to_overwrite(tmp_path: Path) -> None:
    root = tmp_path / "bids"
    write_bids(native_log(), root, sub="01", ses="1", task="hdr", run="1")
    before = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}
    write_bids(cyclopean_log(), root, sub="01", ses="1", task="hdr", run="2")
    assert {p: p.read_bytes() for p in before} == before  # run 1 and the dataset's files
    with pytest.raises(FileExistsError) as info:
        write_bids(cyclopean_log(), root, sub="01", ses="1", task="hdr", run="01")
    message = str(info.value)  # run 01 is run 1: the run index, not the text
    assert "pass --overwrite to replace it, or --run 3 to add another" in message
    assert f"{RUN}_run-1_events.json" in message.replace(os.sep, "/")
    assert {p: p.read_bytes() for p in before} == before
    # replacing run 1 with a log of one recording leaves no stale eye2/eye3 behind
    write_bids(cyclopean_log(), root, sub="01", ses="1", task="hdr", run="1", overwrite=True)
    assert sorted(p.name for p in root.glob(f"{RUN}_run-1_*")) == [
        f"sub-01_ses-1_task-hdr_run-1_{n}"
        for n in (
            "events.json",
            "events.tsv",
            "recording-eye1_physio.json",
            "recording-eye1_physio.tsv.gz",
            "recording-eye1_physioevents.json",
            "recording-eye1_physioevents.tsv.gz",
        )
    ]
    assert comparable(read_bids(root, select={"run": "1"})) == comparable(cyclopean_log())
    assert (root / "participants.tsv").read_text() == "participant_id\nsub-01\n"


def test_a_new_subject_joins_participants_tsv(tmp_path: Path) -> None:
    """An existing dataset's participants.tsv gets a row (n/a in its other columns): the
    validator errors on a subject missing from it."""
    root = tmp_path / "bids"
    write_bids(native_log(), root, sub="01", task="hdr")
    (root / "participants.tsv").write_text("participant_id\tage\nsub-01\t30")  # no final newline
    write_bids(native_log(), root, sub="02", task="hdr")
    write_bids(native_log(), root, sub="02", task="hdr", run="2")
    assert (root / "participants.tsv").read_text() == (
        "participant_id\tage\nsub-01\t30\nsub-02\tn/a\n"
    )
    (root / "participants.tsv").write_text("subject\tage\n")
    with pytest.raises(FormatError, match="no participant_id column") as info:
        write_bids(native_log(), root, sub="03", task="hdr")
    assert info.value.path == str(root / "participants.tsv")


def test_out_must_be_a_dataset_root(tmp_path: Path) -> None:
    root = tmp_path / "bids"
    write_bids(native_log(), root, sub="01", task="hdr")
    with pytest.raises(ValueError, match="not a BIDS dataset") as info:
        write_bids(native_log(), root / "sub-01", sub="01", task="other")
    assert f"its dataset root is {root}" in str(info.value)
    (root / "dataset_description.json").write_text('{"Name": "no version"}')
    with pytest.raises(FormatError, match="required: not a BIDS dataset") as info:
        write_bids(native_log(), root, sub="01", task="other")
    assert info.value.field == "BIDSVersion"
    assert not (root / "sub-01" / "beh" / "sub-01_task-other_events.tsv").exists()


# --- import from a dataset --------------------------------------------------------------------


def test_import_picks_the_run_from_a_root_a_subject_or_a_session_folder(tmp_path: Path) -> None:
    root = three_runs(tmp_path)
    with pytest.raises(ValueError) as info:
        read_bids(root)
    assert str(info.value) == (
        f"{root}: 3 eye-tracking runs; pick one with --sub --run:\n"
        "  sub-01 ses-1 task-hdr run-1  (sub-01/ses-1/beh/, 2 recordings)\n"
        "  sub-01 ses-1 task-hdr run-2  (sub-01/ses-1/beh/, 1 recording)\n"
        "  sub-02 ses-1 task-hdr run-1  (sub-02/ses-1/beh/, 2 recordings)"
    )
    both, one = comparable(native_log()), comparable(cyclopean_log())
    assert comparable(read_bids(root, select={"sub": "01", "run": "2"})) == one
    assert comparable(read_bids(root / "sub-02")) == both
    assert comparable(read_bids(root / "sub-01" / "ses-1", select={"run": "01"})) == both
    with pytest.raises(ValueError, match="2 eye-tracking runs; pick one with --run:"):
        read_bids(root / "sub-01" / "ses-1" / "beh")
    with pytest.raises(ValueError, match=r"no eye-tracking run has run-3; it holds:\n  sub-01"):
        read_bids(root, select={"run": "3"})
    physio = root / f"{RUN}_run-2_recording-eye1_physio.tsv.gz"
    assert comparable(read_bids(physio, select={"sub": "01"})) == one
    with pytest.raises(ValueError, match="is not the one asked for"):
        read_bids(physio, select={"run": "1"})
    # a copy under derivatives/ is not raw data: still three runs
    shutil.copytree(root / "sub-02", root / "derivatives" / "x" / "sub-03")
    with pytest.raises(ValueError, match="3 eye-tracking runs"):
        read_bids(root)


def test_import_skips_other_physio_of_a_run(tmp_path: Path) -> None:
    """A run may also record a pulse: `recording-cardiac` is no eye, nor is a folder of it."""
    root = three_runs(tmp_path)
    folder = root / "sub-02" / "ses-1" / "beh"
    cardiac = folder / "sub-02_ses-1_task-hdr_run-1_recording-cardiac_physio"
    with gzip.open(f"{cardiac}.tsv.gz", "wt") as f:
        f.write("0.5\n0.7\n")
    sidecar = {"PhysioType": "generic", "Columns": ["cardiac"], "SamplingFrequency": 100}
    Path(f"{cardiac}.json").write_text(json.dumps({**sidecar, "StartTime": 0}))
    assert comparable(read_bids(root / "sub-02")) == comparable(native_log())
    eye1 = folder / "sub-02_ses-1_task-hdr_run-1_recording-eye1_physio.tsv.gz"
    assert comparable(read_bids(eye1)) == comparable(native_log())
    other = tmp_path / "pulse" / "sub-01" / "beh"
    other.mkdir(parents=True)
    shutil.move(f"{cardiac}.tsv.gz", other)
    shutil.move(f"{cardiac}.json", other)
    with pytest.raises(FormatError, match=r"1 physio file, none eye-tracking"):
        read_bids(tmp_path / "pulse")


def test_import_command_line_lists_the_runs(tmp_path: Path, capsys) -> None:
    root = three_runs(tmp_path)
    capsys.readouterr()
    out = tmp_path / "s.jsonl"
    assert gazehdr_main(["import", str(root), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"gazehdr: error: {root}: 3 eye-tracking runs; pick one with --sub --run")
    assert "  sub-01 ses-1 task-hdr run-2  (sub-01/ses-1/beh/, 1 recording)\n" in err
    assert gazehdr_main(["import", str(root), "--sub", "01", "--run", "2", "--out", str(out)]) == 0
    assert "sub-01" not in capsys.readouterr().err


# --- real recordings, there and back ----------------------------------------------------------


def records(log: SessionLog) -> dict:
    """Everything a log holds, NaN comparable (as text), events with every field."""

    def eye(e):
        return None if e is None else (repr(e.x), repr(e.y), e.pupil_mm)

    return {
        "header": log.header,
        "samples": [
            (s.t_ns, repr(s.x), repr(s.y), s.valid, eye(s.left), eye(s.right)) for s in log.samples
        ],
        "events": [
            (e.kind, e.id, e.t_ns, repr(e.x), repr(e.y), e.duration_ns, e.dispersion_deg, e.eye)
            for e in log.events
        ],
        **{
            kind: getattr(log, kind)
            for kind in ("scenes", "params", "models", "resets", "notes", "clocks")
        },
    }


@pytest.mark.parametrize("name", sorted(p.name[: -len(".asc.gz")] for p in REAL.glob("*.asc.gz")))
def test_real_eyelink_recordings_round_trip_exactly_through_bids(tmp_path: Path, name: str) -> None:
    """Issue 12, "Round trip stays exact": each real EDF2ASC file → `gazehdr import` →
    `gazehdr export` (a dataset the validator accepts) → `gazehdr import` gives the same
    records: fixation and blink ends where EyeLink put them with EyeLink's durations (which
    count both ends), notes repeated at one time all kept, the END marker without eyes; a
    monocular recording is exported as its eye."""
    asc = tmp_path / f"{name}.asc"
    asc.write_bytes(gzip.decompress((REAL / f"{name}.asc.gz").read_bytes()))
    first, again, root = tmp_path / "first.jsonl", tmp_path / "again.jsonl", tmp_path / "bids"
    assert gazehdr_main(["import", str(asc), "--out", str(first)]) == 0
    flags = ["--sub", "01", "--task", "real"]
    assert gazehdr_main(["export", str(first), "--out", str(root), *flags]) == 0
    assert gazehdr_main(["import", str(root), "--out", str(again)]) == 0
    original = read_session_log(first)
    assert original.events and original.notes
    assert records(read_session_log(again)) == records(original)
    eyes = {json.loads(p.read_text())["RecordedEye"] for p in root.glob("sub-01/beh/*_physio.json")}
    header_eyes = original.header.tracker["eyes"]
    assert eyes == set(header_eyes)  # the eyes give the gaze back: no cyclopean copy
    validate(root)


# --- a bids-examples dataset, whole -----------------------------------------------------------

EXAMPLES = DATA / "bids_examples" / "eyetracking_binocular"


def test_a_bids_examples_dataset_is_read_whole_and_round_trips(tmp_path: Path, capsys) -> None:
    """bids-examples' `eyetracking_binocular` (eye2bids' conversion of a real EyeLink study,
    CC BY 4.0; README beside it): its physio files hold no row, its `_events.tsv` nine. Import
    keeps every events row as a note, warns of the empty recordings (`--strict` refuses them)
    and keeps each eye's calibration and hardware metadata; the export of that log passes the
    validator with the metadata where the dataset had it, and imports back equal. Guards:
    `_events.tsv` rows dropped; empty recordings read without a word; `Manufacturer` and
    `DeviceSerialNumber` read under one name and written under another; per-eye calibration
    lost."""
    with pytest.warns(UserWarning, match="no rows"):
        log = read_bids(EXAMPLES, select={"run": "1"})
    rows = (EXAMPLES / "sub-01/beh/sub-01_task-FreeView_run-01_events.tsv").read_text()
    assert len(log.notes) == len(rows.splitlines()) - 1 == 9
    assert log.notes[0] == Note(
        1_785_302_201_000,
        "events: duration=32.0600146 run_number=1 trial_number=1 image_blank_size=2 "
        "image_blank_num=77",
    )
    metadata = log.header.tracker["bids_metadata"]
    assert metadata["left"]["AverageCalibrationError"] == 0.29
    assert metadata["right"]["MaximalCalibrationError"] == 0.65
    assert metadata["left"]["DeviceSerialNumber"] == "CLG-BAF38"
    out = tmp_path / "again.jsonl"
    strict = ["import", str(EXAMPLES), "--run", "1", "--strict", "--out", str(out)]
    assert gazehdr_main(strict) == 2 and not out.exists()
    assert "no rows: an empty recording (--strict)" in capsys.readouterr().err
    assert gazehdr_main(["import", str(EXAMPLES), "--run", "1", "--out", str(out)]) == 0
    assert capsys.readouterr().err.count("warning: ") == 2
    root = tmp_path / "bids"
    write_bids(log, root, sub="01", task="FreeView", run="1")
    validate(root)
    sides = {
        json.loads(p.read_text())["RecordedEye"]: json.loads(p.read_text())
        for p in root.glob("sub-01/beh/*_physio.json")
    }
    assert set(sides) == {"left", "right"}  # no cyclopean recording made up
    assert sides["right"]["AverageCalibrationError"] == 0.3
    assert sides["left"]["Manufacturer"] == "SR-Research"
    assert sides["left"]["DeviceSerialNumber"] == "CLG-BAF38"
    with pytest.warns(UserWarning, match="no rows"):
        back = read_bids(root)
    assert comparable(back) == comparable(log)


def test_a_monocular_foreign_run_is_exported_as_its_eye_alone(tmp_path: Path) -> None:
    """A run of one eye from another tool (the fixture's left eye alone) exports one recording,
    that eye's, with no identical cyclopean copy; a saccade row comes back as a saccade, a row
    of another trial type as a note; the export imports back equal. Guards: the cyclopean copy;
    saccade rows and unknown rows dropped."""
    root = tmp_path / "mono"
    shutil.copytree(DATA / "bids", root)
    for p in (root / "sub-01" / "beh").glob("*eye2*"):
        p.unlink()
    events = root / "sub-01/beh/sub-01_task-freeview_recording-eye1_physioevents.tsv.gz"
    rows = gzip.decompress(events.read_bytes()).decode()
    events.write_bytes(gzip.compress((rows + "7186807\t0\tdrift_check\t0\tn/a\n").encode()))
    log = read_bids(root)
    assert [e.kind for e in log.events if e.kind.startswith("saccade")] == [
        "saccade_start",
        "saccade_end",
    ]
    assert Note(7_186_807_000_000, "physioevents: duration=0 trial_type=drift_check blink=0") in (
        log.notes
    )
    out = tmp_path / "out"
    written = write_bids(log, out, sub="01", task="freeview")
    physio = sorted(p.name for p in written if p.name.endswith("_physio.json"))
    assert physio == ["sub-01_task-freeview_recording-eye1_physio.json"]
    assert json.loads((out / "sub-01/beh" / physio[0]).read_text())["RecordedEye"] == "left"
    validate(out)
    back = read_bids(out)
    assert comparable(back) == comparable(log)
    assert [(e.kind, e.id, e.t_ns, e.eye) for e in back.events] == [
        (e.kind, e.id, e.t_ns, e.eye) for e in log.events
    ]


def test_a_bad_unit_names_the_sidecar_that_gave_it_and_its_field(tmp_path: Path) -> None:
    """Coordinates in centimetres, given by the dataset-level sidecar: the error names that file
    and `x_coordinate.Units`. Guards: naming the recording's own sidecar (which does not exist)
    and `SampleCoordinateUnits` (which no file has)."""
    root = tmp_path / "bids"
    shutil.copytree(DATA / "bids", root)
    side = root / "task-freeview_physio.json"
    data = json.loads(side.read_text())
    data["x_coordinate"]["Units"] = "cm"
    side.write_text(json.dumps(data))
    with pytest.raises(FormatError, match="gazehdr imports screen pixels") as info:
        read_bids(root)
    assert (info.value.path, info.value.field) == (str(side), "x_coordinate.Units")


def test_import_streams_a_large_run_in_bounded_memory(tmp_path: Path) -> None:
    """`gazehdr import` of a BIDS run streams its samples to the log: Python's allocations stay
    under 6 MB for 40 000 rows (2.3 MB here; reading the run whole, 27.5 MB; 531 000 rows: 26 MB
    peak RSS against 430 MB, docs/formats.md). Guards: the rows read into lists first."""
    import tracemalloc

    log = SessionLog(SessionHeader(tracker={"eyes": ["left"]}))
    log.samples = [
        GazeSample(10**12 + i * 10**6, 900.0 + i % 97, 500.0 - i % 89) for i in range(40_000)
    ]
    root = tmp_path / "big"
    write_bids(log, root, sub="01", task="big")
    out = tmp_path / "big.jsonl"
    tracemalloc.start()
    try:
        assert gazehdr_main(["import", str(root), "--out", str(out)]) == 0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 6 * 2**20, peak
    assert read_session_log(out).samples == log.samples


def test_an_eyelink_export_carries_its_calibration_tracking_mode_and_saccades(
    tmp_path: Path,
) -> None:
    """cili's mono250 (an EyeLink 1000, SR Research's test recording) exported: the physio
    sidecar has the tracker's make, model and serial number, `EyeTrackingMethod` P-CR from its
    CR mode, and its validation (`CalibrationType` HV13, average and largest error, one
    calibration); its saccades are physioevents rows with where each began and landed; its pupil
    area is the pupil_size column in the tracker's units; the validator accepts it. Guards: an
    export of the required keys only; saccades dropped; a pupil in arbitrary units dropped."""
    asc = tmp_path / "mono250.asc"
    asc.write_bytes(gzip.decompress((REAL / "cili_mono250.asc.gz").read_bytes()))
    from gazehdr.drivers.formats.eyelink import read_eyelink_asc

    log = read_eyelink_asc(asc)
    root = tmp_path / "bids"
    write_bids(log, root, sub="01", task="real")
    side = json.loads(next(root.glob("sub-01/beh/*_physio.json")).read_text())
    assert (
        side.items()
        >= {
            "Manufacturer": "SR Research",
            "ManufacturersModelName": "EYELINK II CL v5.03 Jul  3 2014",
            "DeviceSerialNumber": log.header.tracker["serial"],
            "EyeTrackingMethod": "P-CR",
            "CalibrationType": "HV13",
            "CalibrationCount": 1,
            "AverageCalibrationError": 0.38,
            "MaximalCalibrationError": 0.69,
            "RecordedEye": "left",
        }.items()
    )
    events = next(root.glob("sub-01/beh/*_physioevents.tsv.gz"))
    columns = json.loads(events.with_name(events.name.replace(".tsv.gz", ".json")).read_text())
    rows = [
        dict(zip(columns["Columns"], line.split("\t"), strict=True))
        for line in gzip.decompress(events.read_bytes()).decode().splitlines()
    ]
    saccades = [r for r in rows if r["trial_type"] == "saccade"]
    ends = [e for e in log.events if e.kind == "saccade_end"]
    assert len(saccades) == len(ends) == 5  # its five ESACC lines
    assert all(r["start_x_coordinate"] != "n/a" and r["x_coordinate"] != "n/a" for r in saccades)
    # The pupil as the tracker measured it (PUPIL AREA), in its units; lost samples n/a.
    assert log.header.tracker["pupil"] == "area" and "pupil_size" in side["Columns"]
    assert side["pupil_size"]["Units"] == "a.u." and "area" in side["pupil_size"]["Description"]
    physio = next(root.glob("sub-01/beh/*_physio.tsv.gz"))
    sizes = [
        line.split("\t")[side["Columns"].index("pupil_size")]
        for line in gzip.decompress(physio.read_bytes()).decode().splitlines()
    ]
    pupils = [s.left.pupil_au for s in log.samples if s.left is not None]
    assert len(sizes) == len(pupils) and sum(p is not None for p in pupils) > 0.9 * len(pupils)
    assert sizes == ["n/a" if p is None else repr(p) for p in pupils]
    validate(root)
