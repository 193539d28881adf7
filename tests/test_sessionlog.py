"""The native session log: round trip, crash safety, errors that name file/line/field, replay."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from gazehdr.drivers.fixations import make_detector
from gazehdr.drivers.registry import open_track
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
    SessionLogReader,
    SessionLogWriter,
    read_session_log,
    read_session_track,
    write_session_log,
)
from gazehdr.drivers.synthetic import SyntheticScanPath

SCREEN = ScreenGeometry(0.6, 1000, 500, 0.8)


def header() -> SessionHeader:
    return SessionHeader(
        tracker={"name": "test tracker", "serial": "T-1"},
        screen=SCREEN,
        clock=ClockInfo("monotonic_ns", 1_500, 250),
        created="2024-05-01T12:00:00.000+00:00",
    )


def same_sample(a: GazeSample, b: GazeSample) -> bool:
    """Equality that treats NaN as equal to NaN (invalid samples, lost eyes)."""

    def eq(u: object, v: object) -> bool:
        if isinstance(u, float) and isinstance(v, float) and math.isnan(u) and math.isnan(v):
            return True
        return u == v

    def eye_eq(u: EyeSample | None, v: EyeSample | None) -> bool:
        if u is None or v is None:
            return u is v
        return all(eq(getattr(u, f), getattr(v, f)) for f in ("x", "y", "pupil_mm", "pupil_au"))

    return (
        a.t_ns == b.t_ns
        and a.valid == b.valid
        and eq(a.x, b.x)
        and eq(a.y, b.y)
        and eye_eq(a.left, b.left)
        and eye_eq(a.right, b.right)
    )


def same_event(a: GazeEvent, b: GazeEvent) -> bool:
    return (
        (a.kind, a.id, a.t_ns, a.duration_ns, a.dispersion_deg, a.eye)
        == (b.kind, b.id, b.t_ns, b.duration_ns, b.dispersion_deg, b.eye)
        and (a.x == b.x or (math.isnan(a.x) and math.isnan(b.x)))
        and (a.y == b.y or (math.isnan(a.y) and math.isnan(b.y)))
    )


SAMPLES = [
    GazeSample(1_000_000_000, 500.25, 250.125),
    GazeSample(1_016_666_667, 501.0, 251.5, left=EyeSample(490.0, 250.0, 3.25),
               right=EyeSample(512.0, 253.0, 3.5)),
    GazeSample(1_033_333_333, math.nan, math.nan, False),
    GazeSample(1_050_000_000, 620.0, 100.0, left=EyeSample(math.nan, math.nan),
               right=EyeSample(620.0, 100.0)),
    GazeSample(1_066_666_667, 0.1 + 0.2, 1e-300),  # floats survive exactly
]  # fmt: skip
EVENTS = [
    GazeEvent("fixation_start", 1, 1_000_000_000, 500.0, 250.0, 0, 0.0),
    GazeEvent("fixation_update", 1, 1_016_666_667, 500.5, 250.5, 16_666_667, 0.01),
    GazeEvent("fixation_end", 1, 1_016_666_667, 500.5, 250.75, 16_666_667, 0.0125),
    GazeEvent("blink_start", 2, 1_033_333_333),
    GazeEvent("blink_end", 2, 1_050_000_000, duration_ns=16_666_667, eye="left"),
]


def write_example(path: Path) -> None:
    with SessionLogWriter(path, header()) as w:
        w.scene(999_000_000, "lamp")
        w.params(999_000_000, {"a1": 0.2, "preset": "paper", "nested": {"n": [1, 2]}})
        for s, e in zip(SAMPLES, EVENTS, strict=True):
            w.write(s)
            w.write(e)
        w.note(1_070_000_000, 'subject blinked \u2014 twice "quoted"\nsecond line')
        w.clock(1_070_000_001, 1_600, 200)


def test_round_trip_every_record_kind(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    log = read_session_log(path)
    assert log.header == header()
    assert not log.truncated and log.truncated_line is None
    assert len(log.samples) == len(SAMPLES)
    assert all(same_sample(a, b) for a, b in zip(log.samples, SAMPLES, strict=True))
    assert all(same_event(a, b) for a, b in zip(log.events, EVENTS, strict=True))
    assert log.scenes == [SceneChange(999_000_000, "lamp")]
    assert log.params == [
        ParamsChange(999_000_000, {"a1": 0.2, "preset": "paper", "nested": {"n": [1, 2]}})
    ]
    assert log.notes == [Note(1_070_000_000, 'subject blinked \u2014 twice "quoted"\nsecond line')]
    assert log.clocks == [ClockUpdate(1_070_000_001, 1_600, 200)]
    # and in memory → file → memory again gives the same file
    again = tmp_path / "again.jsonl"
    write_session_log(again, log)
    log2 = read_session_log(again)
    assert all(same_sample(a, b) for a, b in zip(log2.samples, SAMPLES, strict=True))
    assert [r.t_ns for r in log2.records()] == sorted(r.t_ns for r in log.records())


def test_model_and_reset_records_round_trip(tmp_path: Path) -> None:
    """Version 2's records: what a server recording a viewing session writes besides gaze."""
    path = tmp_path / "s.jsonl"
    changes = [
        ModelChange(0, "jacobs+stochastic"),
        ModelChange(500_000_000, "jacobs+thompson", split="ritschel+stochastic"),
        EyeReset(500_000_000),
    ]
    with SessionLogWriter(path, header()) as w:
        w.write_all(changes)
    lines = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()[1:]]
    assert lines == [
        {"k": "model", "t": 0, "model": "jacobs+stochastic", "split": None},
        {
            "k": "model",
            "t": 500_000_000,
            "model": "jacobs+thompson",
            "split": "ritschel+stochastic",
        },
        {"k": "reset", "t": 500_000_000},
    ]
    log = read_session_log(path)
    assert (log.models, log.resets) == (changes[:2], changes[2:])
    assert list(log.records()) == changes


def test_a_version_1_log_still_reads(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    replace_line(path, 1, json.dumps({**header().to_json(), "version": 1}))
    log = read_session_log(path)
    assert log.header.version == 1 and len(log.samples) == len(SAMPLES)


def test_file_layout_is_the_documented_one(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    assert json.loads(lines[0]) == {
        "format": "gazehdr-session",
        "version": 3,
        "created": "2024-05-01T12:00:00.000+00:00",
        "tracker": {"name": "test tracker", "serial": "T-1"},
        "screen": {
            "screen_diagonal_m": 0.6,
            "screen_width_px": 1000,
            "screen_height_px": 500,
            "viewing_distance_m": 0.8,
        },
        "clock": {"source": "monotonic_ns", "offset_ns": 1500, "offset_uncertainty_ns": 250},
    }
    records = [json.loads(line) for line in lines[1:]]
    assert records[2] == {"k": "s", "t": 1_000_000_000, "v": 1, "x": 500.25, "y": 250.125}
    assert records[4] == {
        "k": "s",
        "t": 1_016_666_667,
        "v": 1,
        "x": 501.0,
        "y": 251.5,
        "l": [490.0, 250.0, 3.25],
        "r": [512.0, 253.0, 3.5],
    }
    assert records[6] == {"k": "s", "t": 1_033_333_333, "v": 0}
    assert records[8]["l"] is None  # a lost eye
    assert records[9] == {"k": "blink_start", "id": 2, "t": 1_033_333_333}
    assert records[7]["k"] == "fixation_end" and records[7]["dispersion"] == 0.0125
    assert records[5]["k"] == "fixation_update"
    assert all(line.count("\n") == 0 for line in lines)  # one record per line


def test_writer_accepts_the_detectors_events(tmp_path: Path) -> None:
    from gazehdr.drivers import fixations

    event = fixations.Event("fixation_end", 4, 2_000, 10.0, 20.0, 1_500, 0.3)
    blink = fixations.Event("blink_start", 5, 3_000, math.nan, math.nan, 100)
    path = tmp_path / "s.jsonl"
    with SessionLogWriter(path, header()) as w:
        w.write(event)
        w.write(blink)
    log = read_session_log(path)
    assert same_event(log.events[0], GazeEvent("fixation_end", 4, 2_000, 10.0, 20.0, 1_500, 0.3))
    assert same_event(log.events[1], GazeEvent("blink_start", 5, 3_000, duration_ns=100))


def test_each_record_is_flushed_before_close(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    w = SessionLogWriter(path, header())
    w.write(SAMPLES[0])
    w.write(EVENTS[0])
    # another reader sees both while the writer is still open (no buffering in the writer)
    with SessionLogReader(path) as reader:
        assert len(list(reader)) == 2
    w.close()
    w.close()  # idempotent
    with pytest.raises(ValueError, match="closed"):
        w.write(SAMPLES[1])


def test_fsync_every_n_records_and_on_close(tmp_path: Path, monkeypatch) -> None:
    calls = []
    monkeypatch.setattr("gazehdr.drivers.sessionlog.writer.os.fsync", lambda fd: calls.append(fd))
    with SessionLogWriter(tmp_path / "s.jsonl", header(), fsync_every=2) as w:
        assert len(calls) == 1  # the header
        for s in SAMPLES:
            w.write(s)
        assert len(calls) == 1 + len(SAMPLES) // 2
    assert len(calls) == 2 + len(SAMPLES) // 2  # and on close
    with pytest.raises(ValueError, match="fsync_every"):
        SessionLogWriter(tmp_path / "t.jsonl", header(), fsync_every=0)


def test_refuses_to_overwrite_unless_asked(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="already exists"):
        SessionLogWriter(path, header())
    assert path.read_bytes() == before
    with SessionLogWriter(path, header(), overwrite=True) as w:
        w.write(SAMPLES[0])
    assert len(read_session_log(path).samples) == 1


def test_sample_times_must_not_go_back(tmp_path: Path) -> None:
    with SessionLogWriter(tmp_path / "s.jsonl", header()) as w:
        w.write(GazeSample(10, 1.0, 1.0))
        w.write(GazeEvent("fixation_end", 1, 5, 1.0, 1.0))  # events may lag behind samples
        with pytest.raises(ValueError, match="goes back"):
            w.write(GazeSample(9, 1.0, 1.0))


# --- crash safety -----------------------------------------------------------------------------


@pytest.mark.parametrize("cut", [1, 7, -2])
def test_crash_mid_line_keeps_everything_before(tmp_path: Path, cut: int) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    data = path.read_bytes()
    lines = data.splitlines(keepends=True)
    # cut the file inside line 9 (an event), as a crash mid-write would
    offset = sum(len(line) for line in lines[:8]) + (cut if cut > 0 else len(lines[8]) + cut)
    path.write_bytes(data[:offset])
    log = read_session_log(path)
    assert log.truncated and log.truncated_line == 9
    whole = [json.loads(line) for line in lines[1:8]]  # lines 2-8 read back, nothing else
    assert [r.t_ns for r in log.records()] == sorted(r["t"] for r in whole)
    assert len(log.samples) == 3 and same_sample(log.samples[2], SAMPLES[2])


def test_crash_leaving_nul_bytes_is_a_truncation(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    with path.open("ab") as f:
        f.write(b'{"k":"s","t":2000000000,"v"' + b"\x00" * 300)
    log = read_session_log(path)
    assert log.truncated and len(log.samples) == len(SAMPLES)
    path.write_bytes(path.read_bytes().split(b'{"k":"s","t":2000000000')[0] + b"\x00" * 64 + b"\n")
    assert read_session_log(path).truncated


def test_cut_at_a_line_end_is_not_a_truncation(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    path.write_bytes(path.read_bytes()[:-1])  # the last newline only
    log = read_session_log(path)
    assert not log.truncated and log.clocks == [ClockUpdate(1_070_000_001, 1_600, 200)]


def test_a_cut_header_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    path.write_bytes(b'{"format":"gazehdr-session","vers')
    with pytest.raises(FormatError, match=r"s\.jsonl:1: header is not JSON \(cut short"):
        read_session_log(path)
    path.write_bytes(b"")
    with pytest.raises(FormatError, match="empty file"):
        read_session_log(path)


# --- malformed input --------------------------------------------------------------------------


def replace_line(path: Path, number: int, text: str) -> None:
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    lines[number - 1] = text + "\n"
    path.write_text("".join(lines), encoding="utf-8")


def test_an_eyes_pupil_in_the_trackers_units_round_trips(tmp_path: Path) -> None:
    """An eye's pupil in millimetres, in the tracker's arbitrary units (EyeLink's area or
    diameter), both or neither: each written as the documented list (`pupil_mm` null where only
    the arbitrary one is known) and read back the same. Guards: a pupil in arbitrary units
    dropped, or written as millimetres."""
    path = tmp_path / "s.jsonl"
    eyes = [
        EyeSample(1.0, 2.0),
        EyeSample(1.0, 2.0, 3.5),
        EyeSample(1.0, 2.0, None, 4520.0),
        EyeSample(1.0, 2.0, 3.5, 4520.0),
    ]
    with SessionLogWriter(path, header()) as w:
        for i, eye in enumerate(eyes):
            w.write(GazeSample(1_000_000_000 + i, 1.0, 2.0, True, eye, None))
    written = [json.loads(line)["l"] for line in path.read_text().splitlines()[1:]]
    assert written == [
        [1.0, 2.0],
        [1.0, 2.0, 3.5],
        [1.0, 2.0, None, 4520.0],
        [1.0, 2.0, 3.5, 4520.0],
    ]
    assert [s.left for s in read_session_log(path).samples] == eyes


@pytest.mark.parametrize(
    ("line", "text", "field", "reason"),
    [
        (4, '{"k":"s","t":1000000000,"v":1,"x":"500","y":1}', "x", "must be a number"),
        (4, '{"k":"s","t":1.5,"v":1,"x":1,"y":1}', "t", "must be an integer"),
        (4, '{"k":"s","t":1000000000,"v":true,"x":1,"y":1}', "v", "must be 1"),
        (4, '{"k":"s","t":1000000000,"v":1,"y":1}', "x", "missing"),
        (4, '{"k":"s","t":1000000000,"v":0,"x":1,"y":1}', "x", "invalid sample"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":1,"y":1,"l":[1]}', "l", "[x, y]"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":1,"y":1,"l":[1,1,null]}', "l", "pupil_au"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":1,"y":1,"r":[null,1,2,3]}', "r", "pupil_au"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":1,"y":1,"r":[1,1,2,3,4]}', "r", "[x, y]"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":1,"y":1,"z":0}', "z", "unknown field"),
        (4, '{"k":"saccade","t":1000000000}', "k", "unknown record kind"),
        (5, '{"k":"fixation_start","id":-1,"t":1}', "id", "at least 0"),
        (5, '{"k":"fixation_end","id":1,"t":1,"x":2}', "y", "both x and y"),
        (5, '{"k":"blink_end","id":1,"t":1,"eye":"both"}', "eye", "'left' or 'right'"),
        (2, '{"k":"scene","t":1,"name":7}', "name", "must be a string"),
        (3, '{"k":"params","t":1,"values":[1]}', "values", "must be an object"),
        (3, '{"k":"model","t":1,"model":null}', "model", "must be a string"),
        (3, '{"k":"model","t":1,"model":"jacobs","split":2}', "split", "must be a string"),
        (3, '{"k":"reset","t":1,"hard":true}', "hard", "unknown field"),
        (4, '{"k":"s","t":1000000000,"v":1,"x":NaN,"y":1}', None, "not a JSON record"),
        (4, '{"k":"s","t":1000000000,"v":1,', None, "not a JSON record"),
        (4, "[1, 2]", None, "a record is a JSON object"),
        (6, '{"k":"s","t":5,"v":1,"x":1,"y":1}', "t", "goes back"),
    ],
)
def test_malformed_line_in_the_middle_names_file_line_and_field(
    tmp_path: Path, line: int, text: str, field: str | None, reason: str
) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    replace_line(path, line, text)
    with pytest.raises(FormatError) as info:
        read_session_log(path)
    err = info.value
    assert (err.path, err.line, err.field) == (str(path), line, field)
    assert str(err).startswith(f"{path}:{line}: ")
    assert reason in str(err)
    if field:
        assert f"field '{field}'" in str(err)


def test_a_whole_but_malformed_last_line_is_an_error_not_a_truncation(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    with path.open("a", encoding="utf-8") as f:
        f.write('{"k":"s","t":2000000000,"v":1,"x":1\n')
    with pytest.raises(FormatError, match=r":16: not a JSON record"):
        read_session_log(path)


@pytest.mark.parametrize(
    ("change", "field", "reason"),
    [
        ({"format": "other"}, "format", "not a gazehdr session log"),
        ({"version": 4}, "version", "this reader reads versions 1, 2, 3"),
        ({"version": True}, "version", "this reader reads versions 1, 2, 3"),
        ({"screen": {"screen_width_px": 10}}, "screen", "exactly"),
        # an int too large for a float: a clear error, not math.isfinite's OverflowError (fuzz)
        (
            {"screen": {**header().to_json()["screen"], "screen_width_px": 10**400}},
            "screen",
            "finite positive",
        ),
        ({"clock": {"source": "x", "offset_ns": "1"}}, "clock.offset_ns", "integer"),
        ({"extra": 1}, "extra", "unknown field"),
    ],
)
def test_header_errors_name_the_field(
    tmp_path: Path, change: dict, field: str, reason: str
) -> None:
    path = tmp_path / "s.jsonl"
    write_example(path)
    head = {**header().to_json(), **change}
    replace_line(path, 1, json.dumps(head))
    with pytest.raises(FormatError, match=reason) as info:
        read_session_log(path)
    assert (info.value.line, info.value.field) == (1, field)


# --- replay as a gaze track -------------------------------------------------------------------


def test_sample_track_steps_normalises_and_closes_the_eyes(tmp_path: Path) -> None:
    log = SessionLog(header())
    for s in [
        GazeSample(5_000_000_000, 100.0, 50.0),
        GazeSample(5_010_000_000, 200.0, 100.0),
        GazeSample(5_020_000_000, math.nan, math.nan, False),
        GazeSample(5_030_000_000, 300.0, 150.0),
        GazeSample(5_040_000_000, 400.0, 200.0),
        GazeSample(5_050_000_000, 500.0, 250.0),
    ]:
        log.add(s)
    log.add(GazeEvent("blink_start", 9, 5_035_000_000))
    log.add(GazeEvent("blink_end", 9, 5_045_000_000, duration_ns=10_000_000))
    path = tmp_path / "s.jsonl"
    write_session_log(path, log)
    track = read_session_log(path).track()
    assert track.at(0.0) == (0.1, 0.1, True)
    assert track.at(0.0099) == (0.1, 0.1, True)  # step: no interpolation
    assert track.at(0.010) == (0.2, 0.2, True)
    assert track.at(0.025) == (0.2, 0.2, False)  # invalid: closed, position held
    assert track.at(0.031) == (0.3, 0.3, True)
    assert track.at(0.036) == (0.3, 0.3, False)  # inside the blink
    assert track.at(0.044) == (0.4, 0.4, False)
    assert track.at(0.045) == (0.4, 0.4, True)  # blink over
    assert track.at(-1.0) == (0.1, 0.1, True)  # before the start: the first sample
    assert track.at(99.0) == (0.5, 0.5, True)  # after the end: the last
    times = [0.036, 0.0, 0.025, 99.0, 0.010, 0.036]
    assert [track.at(t) for t in times] == [track.at(t) for t in reversed(times)][::-1]
    assert track.duration == pytest.approx(0.05)
    with pytest.raises(ValueError, match="finite"):
        track.at(math.nan)
    # 50 ms hold no fixation (I-VT discards those under 60 ms): render falls back to the samples
    rendered = read_session_track(path)
    assert [rendered.at(t) for t in times] == [track.at(t) for t in times]


def test_track_of_an_unfinished_blink_and_an_invalid_start() -> None:
    log = SessionLog(header())
    log.add(GazeSample(0, math.nan, math.nan, False))
    log.add(GazeSample(10, 250.0, 125.0))
    log.add(GazeSample(20, 500.0, 250.0))
    log.add(GazeEvent("blink_start", 1, 15))
    track = log.track()
    assert track.at(0.0) == (0.25, 0.25, False)  # the first valid position, eyes closed
    assert track.at(10e-9) == (0.25, 0.25, True)
    assert track.at(20e-9) == (0.5, 0.5, False)  # the blink never ended
    with pytest.raises(ValueError, match="no samples"):
        SessionLog(header()).track()


def _recorded_scan(folder: Path, *, with_events: bool) -> tuple[SyntheticScanPath, Path]:
    """A 6 s synthetic scan path (0.05° tracker noise) at 120 Hz recorded as
    `folder/recordings/scan.jsonl`, with the live I-VT detector's events or samples only."""
    path = SyntheticScanPath(seed=3, duration=6.0, geometry=SCREEN, noise_deg=0.05)
    file = folder / "recordings" / "scan.jsonl"
    file.parent.mkdir(parents=True)
    detector = make_detector("ivt", SCREEN)
    with SessionLogWriter(file, header()) as writer:
        for sample in path.samples(120):
            writer.write(sample)
            if with_events:
                writer.write_all(detector.feed(sample))
        if with_events:
            writer.write_all(detector.flush())
    return path, file


TIMES_S = [i / 1000 for i in range(6001)]  # every millisecond of the recording


@pytest.mark.parametrize("with_events", [True, False])
def test_render_follows_the_fixations_of_a_log(tmp_path: Path, with_events: bool) -> None:
    """`gazehdr render --gaze LOG.jsonl` holds each fixation's target through the next saccade
    (raw samples would pass through points at least 1° from every target, saccades being 2°
    or more), and closes the eyes for the blinks."""
    path, file = _recorded_scan(tmp_path, with_events=with_events)
    assert path.blinks and len(path.fixations) > 10
    track = open_track(str(file))
    assert track.duration == pytest.approx(6.0)

    def deg(x: float, y: float) -> float:
        return math.hypot(*SCREEN.norm_to_deg(x, y))

    for t in TIMES_S:
        x, y, eyes_open = track.at(t)
        assert min(deg(x - f.x, y - f.y) for f in path.fixations) < 0.15
        if any(b.start + 0.01 <= t < b.end for b in path.blinks):
            assert not eyes_open
    for f in path.fixations:
        # from 60 ms in (I-VT knows a fixation once it spans 60 ms) to its end
        for t in (u for u in TIMES_S if f.start + 0.06 <= u < f.end):
            x, y, eyes_open = track.at(t)
            assert deg(x - f.x, y - f.y) < 0.15 and eyes_open


@pytest.mark.parametrize("with_events", [True, False])
def test_render_and_live_replay_of_a_log_agree(tmp_path: Path, with_events: bool) -> None:
    """The offline track (`open_track`) and a live session's `replay:NAME` track are one."""
    from gazehdr.recordings import RecordingLibrary

    _, file = _recorded_scan(tmp_path, with_events=with_events)
    rendered, live = open_track(str(file)), RecordingLibrary(tmp_path).track("scan")
    assert rendered.duration == live.duration == pytest.approx(6.0)
    assert [rendered.at(t) for t in TIMES_S] == [live.at(t) for t in TIMES_S]


def test_fixation_track_never_follows_a_saccade() -> None:
    """Without events the log is run through I-VT; the track holds each fixation's mean."""
    ms = 1_000_000
    samples = [GazeSample(i * 10 * ms, 100.0, 100.0) for i in range(30)]  # 300 ms at A
    for k in range(1, 4):  # a 30 ms saccade, ~300 deg/s
        samples.append(GazeSample((290 + 10 * k) * ms, 100 + 200.0 * k, 100 + 100.0 * k))
    samples += [GazeSample((330 + i * 10) * ms, 900.0, 500.0) for i in range(30)]  # at B
    log = SessionLog(SessionHeader(), samples=samples)
    track = log.fixation_track()
    seen = {track.at(t / 1000)[:2] for t in range(0, 620, 5)}
    assert seen == {(100 / 1920, 100 / 1080), (900 / 1920, 500 / 1080)}
    assert track.at(0.6)[:2] == (900 / 1920, 500 / 1080)


def test_fixation_track_places_end_only_fixations_at_their_start() -> None:
    """EyeLink-style events: the start has no position, the end has the mean and duration."""
    ms = 1_000_000
    samples = [GazeSample(i * 10 * ms, 0.0, 0.0) for i in range(100)]
    events = [
        GazeEvent("fixation_start", 1, 0),
        GazeEvent("fixation_end", 1, 200 * ms, 960.0, 540.0, 200 * ms),
        GazeEvent("fixation_end", 2, 900 * ms, 480.0, 270.0, 500 * ms),  # started at 400 ms
    ]
    track = SessionLog(SessionHeader(), samples=samples, events=events).fixation_track()
    assert track.at(0.1)[:2] == (0.5, 0.5)
    assert track.at(0.39)[:2] == (0.5, 0.5)
    assert track.at(0.41)[:2] == (0.25, 0.25)


@pytest.mark.parametrize(
    "events",
    [[], [GazeEvent("fixation_start", 1, 0)], [GazeEvent("blink_start", 1, 700_000_000)]],
    ids=["no events", "fixations without positions", "only blinks"],
)
def test_a_log_whose_events_place_no_fixation_is_followed_through_ivt(
    events: list[GazeEvent],
) -> None:
    """As a daemon replaying it would: the track holds I-VT's fixations, so the saccade between
    them never moves the gaze, where the raw samples would sweep it across."""
    ms = 1_000_000
    a, b = (100.0, 100.0), (900.0, 400.0)
    samples = [GazeSample(t * 10 * ms, *a) for t in range(40)]
    samples += [  # a 30 ms saccade, then B
        GazeSample((400 + 10 * k) * ms, a[0] + (b[0] - a[0]) * k / 3, a[1] + (b[1] - a[1]) * k / 3)
        for k in range(1, 3)
    ]
    samples += [GazeSample((430 + 10 * t) * ms, *b) for t in range(50)]
    log = SessionLog(header(), samples=samples, events=events)
    track = log.fixation_track()
    w, h = SCREEN.screen_width_px, SCREEN.screen_height_px
    assert track.at(0.2)[:2] == pytest.approx((a[0] / w, a[1] / h))
    assert track.at(0.415)[:2] == pytest.approx((a[0] / w, a[1] / h))  # mid-saccade: still A
    assert track.at(0.7)[:2] == pytest.approx((b[0] / w, b[1] / h))
    assert log.track().at(0.415)[:2] != pytest.approx((a[0] / w, a[1] / h))  # the raw samples
