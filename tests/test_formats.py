"""Importers (EyeLink ASC, Pupil Player, Tobii TSV) on handwritten fixtures; the import and
export command lines. BIDS: test_bids.py.

The fixtures in tests/data/formats are written the way the tools write them (header lines,
missing-data markers, trailing tabs, CRLF where the tool writes it); each test checks exact
times in ns, positions in pixels and coordinate flips.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from gazehdr.drivers.formats import detect_format, export_main, import_main, import_recording
from gazehdr.drivers.formats.eyelink import read_eyelink_asc
from gazehdr.drivers.formats.pupil import read_pupil_gaze_csv
from gazehdr.drivers.formats.tobii import read_tobii_tsv
from gazehdr.drivers.samples import EyeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    FormatError,
    Note,
    SessionLog,
    read_session_log,
)

DATA = Path(__file__).parent / "data" / "formats"
NAN = math.nan


def xyv(log: SessionLog) -> list[tuple]:
    """(t_ns, x, y, valid) per sample, NaN positions as None for easy comparison."""
    return [
        (s.t_ns, None if math.isnan(s.x) else s.x, None if math.isnan(s.y) else s.y, s.valid)
        for s in log.samples
    ]


def approx_rows(rows: list[tuple]) -> list:
    return [
        tuple(pytest.approx(v, abs=1e-9) if isinstance(v, float) else v for v in r) for r in rows
    ]


def events(log: SessionLog) -> list[tuple]:
    return [
        (e.kind, e.id, e.t_ns, None if math.isnan(e.x) else e.x, None if math.isnan(e.y) else e.y,
         e.duration_ns, e.eye)
        for e in log.events
    ]  # fmt: skip


def corrupt(tmp_path: Path, name: str, line: int, text: str) -> Path:
    """A copy of fixture `name` with line `line` (1-based) replaced by `text`."""
    raw = (DATA / name).read_bytes().decode("utf-8")
    newline = "\r\n" if "\r\n" in raw else "\n"
    lines = raw.split(newline)
    lines[line - 1] = text
    path = tmp_path / name
    path.write_bytes(newline.join(lines).encode("utf-8"))
    return path


def assert_names(err: FormatError, path: Path, line: int | None, field: str | None) -> None:
    assert (err.path, err.line, err.field) == (str(path), line, field)
    where = f"{path}:{line}: " if line is not None else f"{path}: "
    assert str(err).startswith(where)
    if field:
        assert f"field '{field}'" in str(err)


# --- EyeLink ASC ------------------------------------------------------------------------------


def test_eyelink_monocular() -> None:
    log = read_eyelink_asc(DATA / "eyelink_mono.asc")
    ms = 1_000_000
    assert approx_rows(xyv(log)) == approx_rows([
        (2154556 * ms, 640.2, 512.4, True),
        (2154558 * ms, 640.6, 512.0, True),
        (2154560 * ms, 641.0, 511.8, True),
        (2154562 * ms, 700.5, 480.0, True),
        (2154564 * ms, 820.3, 400.2, True),
        (2154566 * ms, 830.1, 395.5, True),
        (2154568 * ms, 830.9, 396.1, True),
        (2154570 * ms, None, None, False),  # '.' during the blink
        (2154572 * ms, None, None, False),
        (2154574 * ms, 831.0, 396.0, True),  # CR flag 'C..' does not invalidate
        (2154576 * ms, 831.4, 396.4, True),
        (2154578 * ms, None, None, False),  # END of block 1
        (2154700 * ms, 100.0, 100.0, True),
        (2154702 * ms, 101.0, 101.5, True),
        (2154703 * ms, None, None, False),  # END of block 2
    ])  # fmt: skip
    # The block's one eye (LEFT) carries the pupil, in the tracker's units (PUPIL AREA);
    # a lost eye (pupil 0) has none. The END's closing invalid sample has no eye.
    assert log.header.tracker["pupil"] == "area"
    first, blink = log.samples[0], log.samples[7]
    assert first.right is None and first.left == EyeSample(640.2, 512.4, None, 1011.0)
    assert blink.left is not None and blink.left.pupil_au is None
    assert all(s.right is None for s in log.samples)
    assert events(log) == [
        ("fixation_start", 1, 2154556 * ms, None, None, None, "left"),
        ("fixation_end", 1, 2154560 * ms, 640.6, 512.1, 6 * ms, "left"),
        # a saccade: where it began on its start, where it landed on its end
        ("saccade_start", 1, 2154562 * ms, 700.5, 480.0, None, "left"),
        ("saccade_end", 1, 2154564 * ms, 820.3, 400.2, 4 * ms, "left"),
        ("fixation_start", 2, 2154566 * ms, None, None, None, "left"),
        ("fixation_end", 2, 2154568 * ms, 830.5, 395.8, 4 * ms, "left"),
        ("saccade_start", 2, 2154570 * ms, 830.9, 396.1, None, "left"),  # file order
        ("blink_start", 1, 2154570 * ms, None, None, None, "left"),
        ("blink_end", 1, 2154572 * ms, None, None, 4 * ms, "left"),
        ("saccade_end", 2, 2154574 * ms, 831.0, 396.0, 6 * ms, "left"),
        ("fixation_start", 3, 2154576 * ms, None, None, None, "left"),
        ("fixation_end", 3, 2154576 * ms, 831.4, 396.4, 2 * ms, "left"),
    ]
    assert [n.text for n in log.notes] == [
        "DISPLAY_COORDS 0 0 1279 1023",
        "RECCFG CR 500 2 1 L",
        "ELCLCFG BTABLER",
        "GAZE_COORDS 0.00 0.00 1279.00 1023.00",
        "THRESHOLDS L 102 242",
        "TRIALID 1",
        "!V TRIAL_VAR condition bright",
    ]
    assert log.notes[5].t_ns == 2154559 * ms
    screen = log.header.screen
    assert (screen.screen_width_px, screen.screen_height_px) == (1280, 1024)
    assert log.header.tracker["serial"] == "CLU-DAB50"
    assert log.header.tracker["rate_hz"] == 500.0
    assert log.header.tracker["model"].startswith("EYELINK II CL v6.12")


def test_eyelink_binocular_2000hz_fractional_times() -> None:
    log = read_eyelink_asc(DATA / "eyelink_bino.asc")
    assert approx_rows(xyv(log)) == approx_rows([
        (5_000_001_000_000, 956.0, 542.0, True),  # mean of both eyes
        (5_000_001_500_000, 956.5, 542.5, True),  # '.5' ms kept exactly
        (5_000_002_000_000, 963.0, 545.0, True),  # left lost: the right eye alone
        (5_000_002_500_000, None, None, False),  # both lost
        (5_000_003_000_000, 957.25, 543.25, True),
        (5_000_004_000_000, None, None, False),
    ])  # fmt: skip
    s = log.samples[2]
    assert math.isnan(s.left.x) and (s.right.x, s.right.y) == (963.0, 545.0)
    assert (log.samples[0].left, log.samples[0].right) == (  # PUPIL DIAMETER, its units
        EyeSample(950.0, 540.0, None, 4.1),
        EyeSample(962.0, 544.0, None, 4.2),
    )
    end = log.samples[-1]  # END: both eyes lost, neither with a pupil
    assert math.isnan(end.left.x) and math.isnan(end.right.x)
    assert end.left.pupil_au is None and end.right.pupil_au is None
    # edf2asc -nse: no SFIX lines; the starts come from the EFIX lines' <stime>; ids are
    # numbered per kind and eye, in the order the events start
    assert events(log) == [
        ("fixation_start", 1, 5_000_001_000_000, None, None, None, "left"),
        ("fixation_start", 1, 5_000_001_000_000, None, None, None, "right"),
        ("fixation_end", 1, 5_000_001_500_000, 950.3, 540.3, 1_000_000, "left"),
        ("fixation_end", 1, 5_000_003_000_000, 962.9, 544.9, 2_500_000, "right"),
    ]
    assert log.header.screen.screen_width_px == 1920
    assert log.header.tracker["eyes"] == ["left", "right"]


def test_eyelink_2000hz_without_ftime_and_message_offsets() -> None:
    """Manual §4.9.2: the second row of a 2000 Hz time stamp is 0.5 ms later; a message that
    begins with an integer happened that many ms before its time stamp (SR Research FAQ)."""
    log = read_eyelink_asc(DATA / "eyelink_2000hz.asc")
    assert xyv(log) == [
        (7_000_010_000_000, 500.0, 400.0, True),
        (7_000_010_500_000, 500.5, 400.5, True),
        (7_000_011_000_000, 501.0, 401.0, True),
        (7_000_011_500_000, 501.5, 401.5, True),
        (7_000_012_000_000, None, None, False),
        (7_000_012_500_000, 502.5, 402.5, True),
        (7_000_013_000_000, None, None, False),  # END
    ]
    assert log.notes == [
        Note(7_000_000_000_000, "DISPLAY_COORDS 0 0 1023 767"),
        Note(7_000_002_000_000, "stimulus onset"),  # 10 ms before its stamp: sorted first
        Note(7_000_015_000_000, "!V IMGLOAD CENTER scene.png 512 384"),  # -4: 4 ms after
    ]


def test_eyelink_gaze_coords_offset_and_prescaler(tmp_path: Path) -> None:
    text = (
        "MSG\t100 GAZE_COORDS 10.00 20.00 1289.00 1043.00\n"
        "START\t100 \tLEFT\tSAMPLES\tEVENTS\n"
        "PRESCALER\t10\n"
        "SAMPLES\tGAZE\tLEFT\tRATE\t1000.00\tTRACKING\tCR\tFILTER\t2\n"
        "101\t 6500\t 5200\t 900.0\t...\n"
    )
    path = tmp_path / "p.asc"
    path.write_text(text)
    log = read_eyelink_asc(path)
    assert (log.samples[0].x, log.samples[0].y) == (640.0, 500.0)
    assert log.header.screen.screen_width_px == 1280


@pytest.mark.parametrize(
    ("line", "text", "field", "reason"),
    [
        (25, "2154558\t  640.6\t  abc\t 1012.0\t...", "yp", "expected a number or '.'"),
        (25, "2154558\t  640.6", "yp", "this line has 2 fields"),
        (25, "21545x8\t  640.6\t  512.0\t 1012.0\t...", None, None),  # not a sample: skipped
        (25, "2154550\t  640.6\t  512.0\t 1012.0\t...", "time", "goes back"),
        (22, "SAMPLES\tHREF\tLEFT\tRATE\t 500.00", "data type", "edf2asc -sg"),
        (22, "SAMPLES\tGAZE\tRATE\t 500.00", "eyes", "neither LEFT nor RIGHT"),
        (28, "EFIX L   2154556\t2154560", "dur", "this line has 4 fields"),
        (28, "EFIX X   2154556\t2154560\t6\t  640.6\t  512.1\t   1012", "eye", "L or R"),
        (41, "EBLINK L 2154570\tsoon\t4", "etime", "expected a time"),
        (15, "MSG\t2154555 GAZE_COORDS 0.00 0.00 wide 1023.00", "GAZE_COORDS", "four numbers"),
    ],
)
def test_eyelink_malformed_lines_name_line_and_field(
    tmp_path: Path, line: int, text: str, field: str | None, reason: str | None
) -> None:
    """`strict=True` refuses the file at the line; by default the line becomes a note that says
    the same, and the rest of the file is read (the second block's samples, at least)."""
    path = corrupt(tmp_path, "eyelink_mono.asc", line, text)
    if reason is None:  # a line starting with a digit but not a number is a sample: error
        with pytest.raises(FormatError) as info:
            read_eyelink_asc(path, strict=True)
        assert_names(info.value, path, line, "time")
    else:
        with pytest.raises(FormatError, match=reason) as info:
            read_eyelink_asc(path, strict=True)
        assert_names(info.value, path, line, field)
    err = info.value
    log = read_eyelink_asc(path)
    unread = [n.text for n in log.notes if " not read: " in n.text]
    assert unread == [f"line {line} not read: field '{err.field}': {err.reason}: {text}"]
    assert log.header.tracker["unread_lines"] >= 1
    assert log.samples[-1].t_ns == 2154703 * 1_000_000  # the second block's END


def test_eyelink_sample_before_samples_line_and_no_screen(tmp_path: Path) -> None:
    path = tmp_path / "a.asc"
    path.write_text("START\t1 \tLEFT\tSAMPLES\n2\t  1.0\t  2.0\t 3.0\t...\n")
    with pytest.raises(FormatError, match="before any SAMPLES line") as info:
        read_eyelink_asc(path)
    assert_names(info.value, path, 2, "time")
    path.write_text("SAMPLES\tGAZE\tLEFT\tRATE\t1000.00\n2\t  1.0\t  2.0\t 3.0\t...\n")
    with pytest.raises(FormatError, match="--screen") as info:
        read_eyelink_asc(path)
    assert_names(info.value, path, None, "DISPLAY_COORDS")
    log = read_eyelink_asc(path, geometry=ScreenGeometry(0.5, 800, 600, 0.7))
    assert log.header.screen == ScreenGeometry(0.5, 800, 600, 0.7)


def _asc(tmp_path: Path, body: str, name: str = "x.asc") -> Path:
    path = tmp_path / name
    path.write_text(body.replace("|", "\t"), encoding="utf-8")
    return path


def test_eyelink_velocity_resolution_and_blocks_that_differ(tmp_path: Path) -> None:
    """Manual §4.9.2, §4.9.4: `-vel` and `-res` add columns after the pupil (not read; VPRESCALER
    scales them), the CR flags come last; each START clears the data specification, so one
    block may be monocular at 500 Hz and the next binocular at 1000 Hz, and the header says so."""
    path = _asc(
        tmp_path,
        "MSG|100 DISPLAY_COORDS 0 0 799 599\n"
        "START|100 |LEFT|SAMPLES|EVENTS\nPRESCALER|1\nVPRESCALER|10\nPUPIL|DIAMETER\n"
        "SAMPLES|GAZE|LEFT|VEL|RES|RATE| 500.00|TRACKING|CR|FILTER|2\n"
        "100|  10.0|  20.0|   4.1|  -512|   33|  22.1|  22.3|...\n"
        "102|  11.0|  21.0|   4.1|     .|    .|  22.1|  22.3|I..\n"
        "END|103 |SAMPLES|EVENTS|RES|  22.10|  22.30\n"
        "START|200 |LEFT|RIGHT|SAMPLES|EVENTS\n"
        "SAMPLES|GAZE|LEFT|RIGHT|VEL|RATE|1000.00|TRACKING|CR|FILTER|2\n"
        "200|  30.0|  40.0|   4.0|  50.0|  60.0|   4.0|  1.0|  2.0|  3.0|  4.0|.....\n"
        "END|201 |SAMPLES|EVENTS|RES|  22.10|  22.30\n",
    )
    log = read_eyelink_asc(path, strict=True)
    ms = 1_000_000
    assert xyv(log) == [
        (100 * ms, 10.0, 20.0, True),
        (102 * ms, 11.0, 21.0, True),  # interpolated ('I..'), no velocity: still placed
        (103 * ms, None, None, False),
        (200 * ms, 40.0, 50.0, True),  # the mean of (30, 40) and (50, 60)
        (201 * ms, None, None, False),
    ]
    assert (log.samples[3].left, log.samples[3].right) == (
        EyeSample(30, 40, None, 4.0),
        EyeSample(50, 60, None, 4.0),
    )
    tracker = log.header.tracker
    assert (tracker["eyes"], tracker["rate_hz"], tracker["rates_hz"]) == (
        ["left", "right"], 500.0, [500.0, 1000.0],
    )  # fmt: skip
    assert (tracker["blocks"], tracker["pupil"]) == (2, "diameter")


def test_eyelink_sample_only_files(tmp_path: Path) -> None:
    """`edf2asc -s` (manual §4.9.1): sample lines only, no data specification, GAZE (EDF2ASC's
    default); the screen must be given. The CR flags say one eye (3 characters) or both (5),
    whatever `-vel`, `-res`, `-input` add; no line names the eye of monocular samples, so
    `eye` (`--eye`) must. Without flags (`-nflags`) 6 to 8 values are one eye with extra
    columns or both: refused, naming the line, unless `eye` says. Guards: reading monocular
    samples as the left eye without being told; counting values instead of reading the flags."""
    screen = ScreenGeometry(0.5, 1024, 768)
    mono = _asc(tmp_path, "10|  1.0|  2.0|  3.0|...\n12|  .|  .|  0.0|...\n", "m.asc")
    with pytest.raises(FormatError, match="--eye left or --eye right") as info:
        read_eyelink_asc(mono, geometry=screen)
    assert_names(info.value, mono, 1, "eye")
    right = read_eyelink_asc(mono, geometry=screen, eye="right")
    assert xyv(right) == [(10_000_000, 1.0, 2.0, True), (12_000_000, None, None, False)]
    assert right.header.tracker["eyes"] == ["right"]
    bino = _asc(tmp_path, "10|  1.0|  2.0|  3.0|  5.0|  6.0|  3.0|.....\n", "b.asc")
    log = read_eyelink_asc(bino, geometry=screen)
    assert (log.samples[0].x, log.samples[0].y, log.header.tracker["eyes"]) == (
        3.0, 4.0, ["left", "right"],
    )  # fmt: skip
    with pytest.raises(FormatError, match="pass --eye both"):
        read_eyelink_asc(bino, geometry=screen, eye="left")
    # -s -vel of one eye (5 values, 3-character flags), of both (10 values, 5 characters)
    vel = _asc(tmp_path, "10|  1.0|  2.0|  3.0|  0.5|  0.6|...\n", "v.asc")
    assert xyv(read_eyelink_asc(vel, geometry=screen, eye="left")) == [(10_000_000, 1.0, 2.0, True)]
    row = "10|  1.0|  2.0|  3.0|  5.0|  6.0|  3.0|  0.1|  0.2|  0.3|  0.4|....."
    vel2 = _asc(tmp_path, row + "\n", "v2.asc")
    assert xyv(read_eyelink_asc(vel2, geometry=screen)) == [(10_000_000, 3.0, 4.0, True)]
    # -s -nflags -input of both eyes: 7 values, as one eye with -vel -res
    odd = _asc(tmp_path, "10|  1.0|  2.0|  3.0|  5.0|  6.0|  3.0|  127\n", "o.asc")
    with pytest.raises(FormatError, match="without -nflags") as info:
        read_eyelink_asc(odd, geometry=screen)
    assert_names(info.value, odd, 1, "time")
    assert xyv(read_eyelink_asc(odd, geometry=screen, eye="both")) == [(10_000_000, 3.0, 4.0, True)]


def test_eyelink_lines_not_understood_become_notes(tmp_path: Path) -> None:
    """An unknown keyword, a line that continues no message, a BUTTON without its state, a
    PRESCALER of 0, a screen no display has: each a note at the last time read (lines before
    any time at the first), and the file is read; `strict=True` refuses at the first. BUTTON
    and INPUT lines are read for their time (manual §4.9.3); a `=` may follow DISPLAY_COORDS."""
    path = _asc(
        tmp_path,
        "FOO|bar\n"
        "MSG|50 DISPLAY_COORDS = 0 0 1919 1079\n"
        "MSG|60 GAZE_COORDS 0 0 99999 99999\n"
        "START|100 |LEFT|SAMPLES|EVENTS\nPRESCALER|0\n"
        "SAMPLES|GAZE|LEFT|RATE|1000.00|TRACKING|CR|FILTER|2\n"
        "100|  10.0|  20.0|   4.1|...\n"
        "BUTTON|101|1\nINPUT|102|255\n  -0.5  0.25\nMBLINK|103\n"
        "104|  11.0|  21.0|   4.1|...\n"
        "END|105 |SAMPLES|EVENTS|RES|  22.10|  22.30\n",
    )
    log = read_eyelink_asc(path)
    assert xyv(log)[:2] == [(100_000_000, 10.0, 20.0, True), (104_000_000, 11.0, 21.0, True)]
    ms = 1_000_000
    unread = [(n.t_ns, n.text) for n in log.notes if " not read: " in n.text]
    assert unread == [
        (50 * ms, "line 1 not read: unknown keyword 'FOO': FOO\tbar"),
        (60 * ms, "line 3 not read: field 'GAZE_COORDS': larger than any screen: "
                  "'GAZE_COORDS 0 0 99999 99999': MSG\t60 GAZE_COORDS 0 0 99999 99999"),
        (100 * ms, "line 5 not read: field 'prescaler': PRESCALER needs a positive number: "
                   "PRESCALER\t0"),
        (100 * ms, "line 8 not read: BUTTON has 4 fields, this line 3: BUTTON\t101\t1"),
        (102 * ms, "line 10 not read: neither a sample, a keyword nor a message's line: "
                   "-0.5  0.25"),
        (102 * ms, "line 11 not read: unknown keyword 'MBLINK': MBLINK\t103"),
    ]  # fmt: skip
    assert log.header.tracker["unread_lines"] == 6
    assert log.header.screen.screen_width_px == 1920  # DISPLAY_COORDS, GAZE_COORDS unread
    with pytest.raises(FormatError, match="unknown keyword 'FOO'") as info:
        read_eyelink_asc(path, strict=True)
    assert_names(info.value, path, 1, None)


def test_eyelink_files_with_no_sample_to_place_are_refused(tmp_path: Path) -> None:
    """Refused only when no sample can be placed: every block HREF (the SAMPLES line's reason),
    or neither samples nor eye events (an events-only file, `edf2asc -e`, is read:
    tests/test_eyelink_real.py); a HREF block beside a GAZE one loses only its own samples."""
    head = "MSG|1 DISPLAY_COORDS 0 0 1023 767\nSTART|2 |LEFT|SAMPLES|EVENTS\n"
    href = (
        "SAMPLES|HREF|LEFT|RATE|1000.00\n2|  -512|  1024|  900.0|...\n3|  -510|  1020|  900.0|...\n"
    )
    path = _asc(tmp_path, head + href)
    with pytest.raises(FormatError, match="edf2asc -sg") as info:
        read_eyelink_asc(path)
    assert_names(info.value, path, 3, "data type")
    gaze = (
        "START|10 |LEFT|SAMPLES|EVENTS\nSAMPLES|GAZE|LEFT|RATE|1000.00\n10|  1.0|  2.0|  3.0|...\n"
    )
    log = read_eyelink_asc(_asc(tmp_path, head + href + gaze, "mixed.asc"))
    assert [s.t_ns for s in log.samples] == [10_000_000]
    assert log.header.tracker["unread_lines"] == 3  # the SAMPLES line and its two samples
    nothing = _asc(tmp_path, "MSG|1 DISPLAY_COORDS 0 0 1023 767\nMSG|2 hello\n", "n.asc")
    with pytest.raises(FormatError, match="no sample and no eye event") as info:
        read_eyelink_asc(nothing)
    assert_names(info.value, nothing, None, "samples")


# --- Pupil Player -----------------------------------------------------------------------------


def test_pupil_gaze_positions_flip_and_confidence() -> None:
    log = read_pupil_gaze_csv(DATA / "gaze_positions.csv", geometry=ScreenGeometry(0.6, 1280, 720))
    assert approx_rows(xyv(log)) == approx_rows([
        (329_378_961_000, 640.0, 360.0, True),
        (329_383_123_000, 320.0, 180.0, True),  # norm y 0.75 → 25 % from the top
        (329_387_289_000, None, None, False),  # confidence 0.42 < 0.6
        (329_391_455_000, 0.0, 720.0, True),  # (0, 0) is the bottom-left corner
        (329_395_621_000, 1280.0, 0.0, True),  # (1, 1) the top-right
        (329_399_787_000, -64.0, -14.4, True),  # off the image: kept
        (329_403_953_000, 768.0, 432.0, True),  # monocular row, empty 3d fields
        (329_408_119_000, None, None, False),  # confidence 0
    ])  # fmt: skip
    assert log.header.tracker["min_confidence"] == 0.6
    assert log.header.screen.screen_width_px == 1280
    stricter = read_pupil_gaze_csv(DATA / "gaze_positions.csv", min_confidence=0.9)
    assert [s.valid for s in stricter.samples] == [
        True,
        True,
        False,
        False,
        False,
        True,
        True,
        False,
    ]
    assert stricter.header.screen == ScreenGeometry()  # no geometry: the defaults


@pytest.mark.parametrize(
    ("line", "text", "field", "reason"),
    [
        (1, "gaze_timestamp,world_index,norm_pos_x,norm_pos_y", "confidence", "missing column"),
        (3, "329.383123,12,0.97,0.25,high,x,,,,,,,,,,,,,,,", "norm_pos_y", "expected a number"),
        (3, "329.383123,12,1.7,0.25,0.75,x,,,,,,,,,,,,,,,", "confidence", "[0, 1]"),
        (3, "t+1,12,0.97,0.25,0.75,x,,,,,,,,,,,,,,,", "gaze_timestamp", "seconds"),
        (3, "329.0,12,0.97,0.25,0.75,x,,,,,,,,,,,,,,,", "gaze_timestamp", "goes back"),
        (3, "329.383123,12,0.97,0.25", None, "4 fields; the header names 21"),
    ],
)
def test_pupil_malformed_rows_name_line_and_field(
    tmp_path: Path, line: int, text: str, field: str | None, reason: str
) -> None:
    path = corrupt(tmp_path, "gaze_positions.csv", line, text)
    with pytest.raises(FormatError, match=reason) as info:
        read_pupil_gaze_csv(path)
    assert_names(info.value, path, line, field)


def test_pupil_player_export_whole_blank_lines_fixations_and_blinks(tmp_path: Path) -> None:
    """A `gaze_positions.csv` whose first line is blank (as a spreadsheet may save it) is read;
    `fixations.csv` and `blinks.csv` beside it (Pupil Player's Fixation and Blink Detector
    exports) give fixations (start, start + duration ms, mean position flipped as gaze is,
    dispersion) and blinks (start, end), with Pupil's ids. Guards: the blank line refused; the
    exports beside it ignored."""
    folder = tmp_path / "exports" / "000"
    folder.mkdir(parents=True)
    gaze = (DATA / "gaze_positions.csv").read_text(encoding="utf-8")
    (folder / "gaze_positions.csv").write_text("\n" + gaze, encoding="utf-8")
    (folder / "fixations.csv").write_text(
        "id,start_timestamp,duration,start_frame_index,end_frame_index,norm_pos_x,norm_pos_y,"
        "dispersion,confidence,method,gaze_point_3d_x,gaze_point_3d_y,gaze_point_3d_z,"
        "base_data\n"
        "7,329.378961,8.328,10,11,0.5,0.25,0.82,0.97,2d gaze,,,,329.378961-0\n",
        encoding="utf-8",
    )
    (folder / "blinks.csv").write_text(
        "id,start_timestamp,duration,end_timestamp,start_frame_index,index,end_frame_index,"
        "confidence,filter_response,base_data\n"
        "\n"
        "3,329.387289,0.004166,329.391455,12,12,13,0.8,0.6,329.387289\n",
        encoding="utf-8",
    )
    screen = ScreenGeometry(0.6, 1280, 720)
    log = read_pupil_gaze_csv(folder / "gaze_positions.csv", geometry=screen)
    plain = read_pupil_gaze_csv(DATA / "gaze_positions.csv", geometry=screen)
    assert log.samples == plain.samples
    assert events(log) == [
        ("fixation_start", 7, 329_378_961_000, 640.0, 540.0, None, None),
        ("fixation_end", 7, 329_387_289_000, 640.0, 540.0, 8_328_000, None),
        ("blink_start", 3, 329_387_289_000, None, None, None, None),
        ("blink_end", 3, 329_391_455_000, None, None, 4_166_000, None),
    ]
    assert [e.dispersion_deg for e in log.events if e.kind == "fixation_end"] == [0.82]
    (folder / "blinks.csv").write_text("id,start_timestamp,end_timestamp\n3,x,1\n")
    with pytest.raises(FormatError) as info:
        read_pupil_gaze_csv(folder / "gaze_positions.csv", geometry=screen)
    assert_names(info.value, folder / "blinks.csv", 2, "start_timestamp")


def test_pupil_old_timestamp_column(tmp_path: Path) -> None:
    path = tmp_path / "gaze_positions.csv"
    path.write_text("timestamp,index,confidence,norm_pos_x,norm_pos_y\n1.5,0,0.9,0.5,0.25\n")
    log = read_pupil_gaze_csv(path)
    assert xyv(log) == [(1_500_000_000, 960.0, 810.0, True)]


# --- Tobii TSV --------------------------------------------------------------------------------


def test_tobii_pygaze() -> None:
    log = read_tobii_tsv(DATA / "tobii_pygaze.tsv")
    ms = 1_000_000
    assert approx_rows(xyv(log)) == approx_rows([
        (0, 960.4, 532.2, True),
        (16_700_000, 961.0, 533.0, True),
        (33_300_000, 972.0, 536.0, True),  # left code 4 (-1.0): the right eye (code 1)
        (50_000_000, None, None, False),  # both 4
        (66_700_000, None, None, False),  # both 2: Tobii says drop codes >= 2
        (83_300_000, 958.0, 530.0, True),
        (100 * ms, 510.0, 305.0, True),  # block 2 restarts at 0: placed 16.7 ms on
        (116_700_000, 511.0, 306.0, True),
    ])  # fmt: skip
    assert math.isnan(log.samples[2].left.x) and log.samples[2].right == EyeSample(972.0, 536.0)
    assert [n.t_ns for n in log.notes] == [20_100_000, 70_500_000, 100 * ms, 105_200_000]
    assert [n.text for n in log.notes[:2]] == ["trial 1 start", "key space"]
    assert log.notes[3].text == "trial 2 start"
    assert "block 2 restarts its clock at 0" in log.notes[2].text
    screen = log.header.screen
    assert (screen.screen_width_px, screen.screen_height_px) == (1920, 1080)
    assert screen.screen_diagonal_m == pytest.approx(math.hypot(0.53, 0.30))
    assert screen.viewing_distance_m == pytest.approx(0.57)
    assert log.header.tracker["writer"] == "PyGaze libtobii"


def test_tobii_psychopy_controller_height_units() -> None:
    log = read_tobii_tsv(DATA / "tobii_ptc.tsv", units="height")
    assert approx_rows(xyv(log)) == approx_rows([
        (0, 960.0, 529.2, True),
        (8_300_000, 957.84, 531.36, True),
        (16_700_000, 970.8, 538.92, True),
        (25_000_000, None, None, False),
        (33_300_000, 1186.8, 658.8, True),
    ])  # fmt: skip
    first = log.samples[0]
    assert (first.left.x, first.left.y, first.left.pupil_mm) == pytest.approx((949.2, 518.4, 3.12))
    assert (first.right.x, first.right.y, first.right.pupil_mm) == pytest.approx(
        (970.8, 540.0, 3.08)
    )
    assert log.samples[2].left.pupil_mm is None and math.isnan(log.samples[2].left.x)
    assert log.notes == [Note(12_500_000, "space")]
    assert log.header.tracker["units"] == "height"


@pytest.mark.parametrize(
    ("units", "x", "y"), [("pix", -10.0, 20.0), ("norm", -0.5, 0.5), ("height", 0.25, -0.25)]
)
def test_tobii_psychopy_units_and_embedded_events(
    tmp_path: Path, units: str, x: float, y: float
) -> None:
    header = (
        "TimeStamp\tGazePointXLeft\tGazePointYLeft\tPupilLeft\tValidityLeft\tGazePointXRight"
        "\tGazePointYRight\tPupilRight\tValidityRight\tGazePointX\tGazePointY\tEvent"
    )
    row = f"{x:.4f}\t{y:.4f}\t3.0000\t1\tnan\tnan\tnan\t0\t{x:.4f}\t{y:.4f}"
    path = tmp_path / "e.tsv"
    path.write_text(
        "Recording date:\t2024/03/06\nRecording time:\t10:01:02\n"
        "Recording resolution:\t800 x 600\nEvent recording mode:\tEmbedded\n\n"
        f"Session Start\n{header}\n0.0\t{row}\t\n5.0\t{row}\tflash on\n10.0\t{row}\t\n"
        "Session End\n\n"
    )
    log = read_tobii_tsv(path, units=units)
    want = {"pix": (390.0, 280.0), "norm": (200.0, 150.0), "height": (550.0, 450.0)}[units]
    assert [(s.t_ns, s.x, s.y) for s in log.samples] == [
        (0, *want),
        (10_000_000, *want),  # the event row's interpolated gaze is not a sample
    ]
    assert log.notes == [Note(5_000_000, "flash on")]


@pytest.mark.parametrize(
    ("name", "line", "text", "field", "reason"),
    [
        ("tobii_pygaze.tsv", 24, "16.7\t951.0\t531.0\t7\t971.0\t535.0\t0\t0.5\t0.4\t",
         "ValidityLeft", "validity code 0-4"),
        ("tobii_pygaze.tsv", 24, "16.7\t951.0\tmiddle\t0\t971.0\t535.0\t0\t0.5\t0.4\t",
         "GazePointYLeft", "expected a number"),
        ("tobii_pygaze.tsv", 24, "16,7\t951.0\t531.0\t0\t971.0\t535.0\t0\t0.5\t0.4\t", "TimeStamp",
         "expected a time in ms"),
        ("tobii_pygaze.tsv", 24, "16.7\t951.0\t531.0\t0", None, "4 fields; the header names 10"),
        ("tobii_pygaze.tsv", 26, "10.0\t-1.0\t-1.0\t4\t-1.0\t-1.0\t4\t-1.0\t-1.0\t", "TimeStamp",
         "goes back"),
        ("tobii_pygaze.tsv", 22, "TimeStamp\tLeftX\tLeftY", "TimeStamp", "unrecognised columns"),
        ("tobii_ptc.tsv", 10, "16.7\tnan\tnan\tnan\t0\t0.0100\t0.0010\t3.1000\t2\t0.0100\t0.0010",
         "ValidityRight", "validity code 0-1"),
    ],
)  # fmt: skip
def test_tobii_malformed_rows_name_line_and_field(
    tmp_path: Path, name: str, line: int, text: str, field: str | None, reason: str
) -> None:
    path = corrupt(tmp_path, name, line, text)
    with pytest.raises(FormatError, match=reason) as info:
        read_tobii_tsv(path, units="height")
    assert_names(info.value, path, line, field)


@pytest.mark.parametrize(
    ("name", "line", "text", "field", "reason"),
    [
        # the fuzzer's: a screen 0 pixels high (ScreenGeometry's ValueError)
        ("tobii_pygaze.tsv", 3, "Recording resolution\t1920 x 0", "Recording resolution",
         "1 to 65536 pixels each, got '1920 x 0'"),
        ("tobii_pygaze.tsv", 3, "Recording resolution\t0 x 1080", "Recording resolution",
         "got '0 x 1080'"),
        # 5000 digits: int() refuses them itself (a ValueError)
        ("tobii_pygaze.tsv", 3, "Recording resolution\t1920 x " + "9" * 5000,
         "Recording resolution", "1 to 65536 pixels each"),
        # 400 digits in a position's units: width / 2 overflowed a float (OverflowError)
        ("tobii_ptc.tsv", 3, "Recording resolution:\t1920 x " + "9" * 400,
         "Recording resolution", "1 to 65536 pixels each"),
        ("tobii_pygaze.tsv", 7, "display size in cm: 0x0", "display size in cm",
         "positive numbers of cm, got '0x0'"),
        ("tobii_pygaze.tsv", 7, "display size in cm: 5.3.0x30.0", "display size in cm",
         "got '5.3.0x30.0'"),
        ("tobii_pygaze.tsv", 7, "display size in cm: " + "9" * 400 + "x30.0",
         "display size in cm", "positive numbers of cm"),
        ("tobii_pygaze.tsv", 17, "distance between participant and display: 0 cm",
         "distance between participant and display", "a positive number of cm, got '0'"),
    ],
)  # fmt: skip
def test_tobii_screen_lines_that_size_no_screen_name_line_and_field(
    tmp_path: Path, name: str, line: int, text: str, field: str, reason: str
) -> None:
    """A resolution, display size or distance that gives no screen (zero, too many digits,
    not a number) is the file's FormatError at its line. Guards the check in tobii's
    `_meta_values`: without it these were a ValueError from ScreenGeometry or int() and an
    OverflowError from converting a psychopy_tobii_controller position."""
    path = corrupt(tmp_path, name, line, text)
    with pytest.raises(FormatError, match=reason) as info:
        read_tobii_tsv(path, units="pix")
    assert_names(info.value, path, line, field)


def test_tobii_psychopy_needs_units() -> None:
    path = DATA / "tobii_ptc.tsv"
    with pytest.raises(FormatError, match="--units pix") as info:
        read_tobii_tsv(path)
    assert_names(info.value, path, 8, "GazePointXLeft")


# --- dispatch and the command lines -----------------------------------------------------------


def test_detect_format(tmp_path: Path) -> None:
    assert detect_format(DATA / "eyelink_mono.asc") == "eyelink"
    assert detect_format(DATA / "gaze_positions.csv") == "pupil"
    assert detect_format(DATA / "tobii_pygaze.tsv") == "tobii"
    assert detect_format(DATA / "tobii_ptc.tsv") == "tobii"
    assert detect_format(Path("x/sub-01_task-a_recording-eye1_physio.tsv.gz")) == "bids"
    assert detect_format(DATA / "bids") == "bids"
    other = tmp_path / "other.tsv"
    other.write_text("a\tb\n")
    with pytest.raises(ValueError, match="--format"):
        detect_format(other)
    with pytest.raises(ValueError, match="unknown format"):
        import_recording(DATA / "eyelink_mono.asc", "edf")


def test_import_command_line_says_what_was_not_read_and_strict_refuses(
    tmp_path: Path, capsys
) -> None:
    path = corrupt(tmp_path, "eyelink_mono.asc", 25, "2154558\t  640.6\t  abc\t 1012.0\t...")
    out = tmp_path / "s01.jsonl"
    assert import_main([str(path), "--out", str(out)]) == 0
    assert "8 notes (1 line not read: see the notes 'line N not read')" in capsys.readouterr().out
    note = read_session_log(out).notes[5]  # at the time of the line, 2154558 ms
    assert note.t_ns == 2154558 * 1_000_000
    assert note.text.startswith("line 25 not read: field 'yp': expected a number or '.'")
    with pytest.raises(FormatError, match="field 'yp'"):
        import_main([str(path), "--out", str(tmp_path / "strict.jsonl"), "--strict"])
    assert not (tmp_path / "strict.jsonl").exists()


def test_import_command_line_missing_and_eye(tmp_path: Path, capsys) -> None:
    """`gazehdr import --missing VALUE` (edf2asc -miss) reads VALUE as missing, `--eye` says
    what a sample-only file holds; both are refused for other formats. Guards: the options
    not reaching the EyeLink reader."""
    asc = tmp_path / "s.asc"
    asc.write_text("10\t-1\t-1\t5.0\t...\n12\t1.0\t2.0\t3.0\t...\n", encoding="utf-8")
    out = tmp_path / "s.jsonl"
    argv = [str(asc), "--out", str(out), "--screen", "800x600"]
    assert import_main([*argv, "--eye", "right", "--missing", "-1"]) == 0
    assert "2 samples (1 invalid)" in capsys.readouterr().out
    log = read_session_log(out)
    assert log.header.tracker["eyes"] == ["right"] and not log.samples[0].valid
    with pytest.raises(SystemExit):
        import_main([str(DATA / "gaze_positions.csv"), "--out", str(out), "--eye", "left"])
    assert "--eye is for EyeLink ASC files" in capsys.readouterr().err


def test_import_and_export_command_lines(tmp_path: Path, capsys) -> None:
    out = tmp_path / "s01.jsonl"
    assert (
        import_main([str(DATA / "eyelink_mono.asc"), "--out", str(out), "--distance", "0.7"]) == 0
    )
    assert "15 samples (4 invalid), 12 events, 7 notes, screen 1280x1024" in capsys.readouterr().out
    log = read_session_log(out)
    assert log.header.screen == ScreenGeometry(0.6, 1280, 1024, 0.7)
    assert len(log.samples) == 15 and log.samples[0].t_ns == 2_154_556_000_000
    assert log.track().at(0.0) == (640.2 / 1280, 512.4 / 1024, True)
    with pytest.raises(FileExistsError, match=r"already exists.*pass --overwrite"):
        import_main([str(DATA / "eyelink_mono.asc"), "--out", str(out)])
    assert import_main([str(DATA / "tobii_ptc.tsv"), "--out", str(out), "--overwrite",
                        "--units", "pix"]) == 0  # fmt: skip
    pupil = tmp_path / "p.jsonl"
    assert import_main([str(DATA / "gaze_positions.csv"), "--out", str(pupil), "--screen",
                        "1280x720", "--min-confidence", "0.9"]) == 0  # fmt: skip
    assert sum(s.valid for s in read_session_log(pupil).samples) == 4
    with pytest.raises(SystemExit):
        import_main([str(DATA / "gaze_positions.csv"), "--out", str(pupil), "--screen", "big"])

    bids = tmp_path / "bids"
    assert export_main([str(out), "--out", str(bids), "--sub", "02", "--task", "x"]) == 0
    printed = capsys.readouterr().out
    # 3 of the dataset, 2 events, 4 per eye (the gaze is their mean: no cyclopean recording)
    assert "wrote 13 files to the dataset" in printed
    assert "  sub-02/beh/sub-02_task-x_events.tsv\n" in printed
    back = import_recording(bids / "sub-02" / "beh" / "sub-02_task-x_recording-eye2_physio.tsv.gz")
    assert len(back.samples) == len(read_session_log(out).samples)
    assert import_main([str(bids), "--sub", "02", "--out", str(tmp_path / "b.jsonl")]) == 0
    assert read_session_log(tmp_path / "b.jsonl").samples == back.samples
    # the old --prefix (files in --out itself) says what to use instead
    with pytest.raises(SystemExit):
        export_main([str(out), "--out", str(bids), "--prefix", "sub-02_ses-3_task-x"])
    assert "use --sub 02 --ses 3 --task x" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # picking a run is for BIDS datasets only
        import_main([str(DATA / "eyelink_mono.asc"), "--run", "1", "--out", str(pupil)])
    assert "--run picks a run of a BIDS dataset" in capsys.readouterr().err
