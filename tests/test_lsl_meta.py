"""The pure parts of the LSL source: queries, channel layouts (real apps' descriptions, built by
real liblsl), sample mapping, the outlet's own description, the clock arithmetic; and a
bounded, seeded fuzz of the description parser."""

from __future__ import annotations

import json
import math
import random
import time
from pathlib import Path

import pytest
from lsl_loopback import EYELINK, GAZEPOINT, PUPIL_CAPTURE, TOBII, pylsl, stream_info

from gazehdr.drivers.lsl.clock import NOTE_CHANGE_S, ClockLink, StreamClock
from gazehdr.drivers.lsl.meta import (
    DEFAULT_PREDICATE,
    OUTLET_CHANNELS,
    LayoutError,
    StreamDescription,
    channel_layout,
    marker_text,
    outlet_values,
    stream_predicate,
)
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import GazeEvent, Note, decode_record

SCREEN = ScreenGeometry(screen_width_px=1000, screen_height_px=500)
NAN = math.nan


def layout_of(info: pylsl.StreamInfo):
    return channel_layout(StreamDescription.from_xml(info.as_xml()))


def test_queries() -> None:
    assert (
        stream_predicate("")
        == DEFAULT_PREDICATE
        == ("type='Gaze' or type='gaze' or type='Eyetracker'")
    )
    assert stream_predicate("Tobii") == "name='Tobii'"
    assert stream_predicate("Bob's tracker") == 'name="Bob\'s tracker"'
    assert stream_predicate("source_id=abc=1") == "source_id='abc=1'"
    assert stream_predicate(" type = Gaze ") == "type='Gaze'"
    assert stream_predicate("name='A' and hostname='lab3'") == "name='A' and hostname='lab3'"
    assert stream_predicate("colour=red") == "name='colour=red'"  # not a property: a name
    assert stream_predicate("starts-with(name, 'Tob')") == "name=\"starts-with(name, 'Tob')\""
    assert stream_predicate("starts-with(name,'T') and type = 'Gaze'").startswith("starts")
    with pytest.raises(ValueError, match="needs a value"):
        stream_predicate("hostname=")


def test_tobii_pro_app_normalised_eyes_with_pupils_in_mm() -> None:
    layout = layout_of(stream_info("Tobii", "Eyetracker", TOBII))
    assert set(layout.eyes) == {"left", "right"}
    s = layout.sample([0.25, 0.5, 3.0, 0.35, 0.5, 3.5], 7, SCREEN)
    assert s == GazeSample(
        7, 300.0, 250.0, True, EyeSample(250, 250, 3.0), EyeSample(350, 250, 3.5)
    )
    one = layout.sample([NAN, NAN, NAN, 0.35, 0.5, 3.5], 8, SCREEN)  # the app's invalid eye
    assert (one.valid, one.x, one.left) == (True, 350.0, None)
    assert not layout.sample([NAN] * 6, 9, SCREEN).valid


def test_eyelink_app_by_its_labels_missing_data_and_untracked_eyes() -> None:
    layout = layout_of(stream_info("EyeLink", "Gaze", EYELINK, fmt="double64"))
    assert set(layout.eyes) == {"left", "right"} and not layout.eyes["left"].normalized
    both = [100.0, 200.0, 300.0, 400.0, 900.0, 950.0, 30.0, 30.0, 123.0, 4.5]
    assert (layout.sample(both, 0, SCREEN).x, layout.sample(both, 0, SCREEN).y) == (200, 300)
    # leftPupilArea, rightPupilArea: in the tracker's units, not as millimetres
    assert layout.sample(both, 0, SCREEN).left == EyeSample(100.0, 200.0, None, 900.0)
    right_only = [0.0, 0.0, 300.0, 400.0, 0.0, 950.0, 30.0, 30.0, 123.0, 4.5]  # app's zeros
    assert (layout.sample(right_only, 0, SCREEN).x, layout.sample(right_only, 0, SCREEN).y) == (
        300,
        400,
    )
    missing = [-32768.0, -32768.0, 1e8, 1e8, 900.0, 950.0, 30.0, 30.0, 123.0, 4.5]
    assert not layout.sample(missing, 0, SCREEN).valid


def test_pupil_capture_relay_bottom_left_origin_and_confidence() -> None:
    layout = layout_of(stream_info("pupil_capture", "Gaze", PUPIL_CAPTURE, fmt="double64"))
    s = layout.sample([0.9, 0.25, 0.8, 40, 41, 3.1, 3.2], 0, SCREEN)
    assert (s.valid, s.x, s.y) == (True, 250.0, pytest.approx(100.0))  # y 0.8 up: 0.2 down
    assert not layout.sample([0.5, 0.25, 0.8, 40, 41, 3.1, 3.2], 0, SCREEN).valid  # < 0.6
    assert layout.describe()["both"] == {
        "x": "norm_pos_x", "y": "norm_pos_y", "unit": "normalized (origin bottom-left)",
    }  # fmt: skip
    invisible = stream_info(
        "pi", "Gaze", [("x", "both", "ScreenX", "pixels"), ("y", "both", "ScreenY", "pixels")],
        metatype=True,
    )  # fmt: skip
    assert layout_of(invisible).sample([12.0, 34.0], 0, SCREEN) == GazeSample(0, 12.0, 34.0)


def test_gazepoint_best_point_of_gaze_with_its_validity_and_pupils_in_mm() -> None:
    layout = layout_of(stream_info("GazepointEyeTracker", "gaze", GAZEPOINT))
    labels = [c[0] for c in GAZEPOINT]
    values = dict.fromkeys(labels, 0.0) | {
        "FPOGX": 0.1, "FPOGY": 0.1, "FPOGV": 1, "BPOGX": 0.5, "BPOGY": 0.5, "BPOGV": 1,
        "LPOGX": 0.4, "LPOGY": 0.5, "LPOGV": 1, "LPD": 20, "LPMM": 3.3, "RPOGV": 0,
    }  # fmt: skip
    s = layout.sample([values[k] for k in labels], 0, SCREEN)
    assert (s.x, s.y) == (500.0, 250.0)  # BPOG, not the fixation-filtered FPOG
    assert s.left == EyeSample(400.0, 250.0, 3.3, 20.0) and s.right is None  # RPOGV 0
    # LPD, the pupil in the camera's pixels, is kept beside LPMM as the tracker's own units
    values |= {"BPOGV": 0}
    s = layout.sample([values[k] for k in labels], 0, SCREEN)
    assert (s.valid, s.x) == (True, 400.0)  # the best POG invalid: the valid eye


@pytest.mark.parametrize(
    ("info", "message"),
    [
        (pylsl.StreamInfo("bare", "Gaze", 2, 0, "float32", ""), "no <desc><channels>"),
        (stream_info("m", "Markers", [("m", "", "", "")], fmt="string"), "carries text"),
        (stream_info("eeg", "Gaze", [("Fz", "", "EEG", "uV")]), r"found channels Fz \(EEG\)"),
        (
            stream_info("mm", "Gaze", [("x", "both", "ScreenX", "mm"), ("y", "", "ScreenY", "mm")]),
            "ignored x: unit 'mm', y: unit 'mm'",
        ),
    ],
)
def test_streams_without_usable_gaze_are_refused_naming_what_they_have(info, message) -> None:
    with pytest.raises(LayoutError, match=message) as e:
        layout_of(info)
    assert f"'{info.name()}'" in str(e.value)


def test_malformed_descriptions() -> None:
    with pytest.raises(LayoutError, match="not XML"):
        StreamDescription.from_xml("<info><name>x</name>")
    with pytest.raises(LayoutError, match="not <info>"):
        StreamDescription.from_xml("<stream/>")
    with pytest.raises(LayoutError, match="channel_count 'two' is not a whole number"):
        StreamDescription.from_xml("<info><name>x</name><channel_count>two</channel_count></info>")
    xml = stream_info("x", "Gaze", TOBII).as_xml().replace("<channel_count>6", "<channel_count>7")
    with pytest.raises(LayoutError, match="lists 6 channels"):
        channel_layout(StreamDescription.from_xml(xml))
    layout = layout_of(stream_info("Tobii", "Eyetracker", TOBII))
    with pytest.raises(LayoutError, match="a sample of 2 values, 6 expected"):
        layout.sample([1.0, 2.0], 0, SCREEN)


def test_what_gazehdr_publishes_reads_back_as_it_was() -> None:
    info = stream_info("gazehdr", "Gaze", [tuple(c.values()) for c in OUTLET_CHANNELS])
    layout = layout_of(info)
    sample = GazeSample(5, 10.5, 20.25, True, EyeSample(9.0, 20.0, 3.5), EyeSample(12.0, 20.5))
    assert layout.sample(outlet_values(sample), 5, SCREEN) == sample
    imported = GazeSample(8, 1.0, 2.0, True, EyeSample(1.0, 2.0, None, 1204.0), EyeSample(1, 2))
    assert layout.sample(outlet_values(imported), 8, SCREEN) == imported  # EyeLink's a.u. pupil
    both = GazeSample(9, 1.0, 2.0, True, EyeSample(1.0, 2.0, 3.5, 1204.0))
    assert layout.sample(outlet_values(both), 9, SCREEN) == both
    lost = GazeSample(6, NAN, NAN, False)
    assert layout.sample(outlet_values(lost), 6, SCREEN) == lost
    assert layout.sample(outlet_values(GazeSample(7, 1.0, 2.0)), 7, SCREEN) == GazeSample(7, 1, 2)
    event = GazeEvent("fixation_start", 3, 100, 1.5, 2.5, eye="left")
    assert decode_record(json.loads(marker_text(event)), Path("m"), 1) == event
    assert marker_text(Note(4, "hello")) == '{"k":"note","t":4,"text":"hello"}'


def test_clock_link_and_stream_clock_arithmetic() -> None:
    readings = iter([100, 140, 1000, 1010])  # monotonic: a wide bracket, then a tight one
    lsl = iter([0.5e-7, 9.9e-7])
    link = ClockLink.measure(lambda: next(lsl), lambda: next(readings), tries=2)
    assert link == ClockLink(1005 - 990, 5)
    assert link.to_ns(2.0) == 2_000_000_015 and link.to_lsl(2_000_000_015) == 2.0
    clock = StreamClock(ClockLink(1_000, 0), offset_s=0.25)
    assert clock.t_ns(10.0) == 10_250_001_000
    assert clock.correct(0.25 + NOTE_CHANGE_S / 2) is None  # small: not noted
    assert clock.correct(0.2) == pytest.approx(-0.05)  # noted, from the last noted value
    assert clock.t_ns(10.0) == 10_250_001_000  # moved back: held at the last time given
    assert clock.t_ns(10.1) == 10_300_001_000
    assert clock.correct(math.nan) is None and clock.offset_s == 0.2
    with pytest.raises(ValueError):
        StreamClock(link, math.inf)


def test_liblsl_local_clock_is_the_monotonic_clock_here() -> None:
    """What the source relies on, measured: on Linux liblsl's clock is CLOCK_MONOTONIC."""
    link = ClockLink.measure(pylsl.local_clock, time.monotonic_ns)
    assert abs(link.offset_ns) <= link.uncertainty_ns + 50_000


def _mutate(text: str, rng: random.Random) -> str:
    pieces = ["<", ">", "</channel>", "<channel>", "<type>ScreenX</type>", "<eye>left</eye>",
              "<unit>norm</unit>", "&amp;", "\x00", "<channels>", "é", "<label>BPOGX</label>",
    ]  # fmt: skip
    chars = list(text)
    for _ in range(rng.randint(1, 6)):
        i = rng.randrange(len(chars) + 1)
        op = rng.random()
        if op < 0.4:
            chars[i:i] = list(rng.choice(pieces))
        elif op < 0.7:
            del chars[i : i + rng.randint(1, 30)]
        else:
            chars[i:i] = [chr(rng.randrange(32, 127))]
    return "".join(chars)


def test_fuzz_descriptions_and_samples_only_ever_raise_layout_errors() -> None:
    """Seeded, bounded: mutated descriptions of every real app's stream either read as a layout
    (which maps random values without other errors) or are refused with a LayoutError."""
    rng = random.Random(12)
    bases = [
        stream_info("Tobii", "Eyetracker", TOBII).as_xml(),
        stream_info("EyeLink", "Gaze", EYELINK).as_xml(),
        stream_info("pupil", "Gaze", PUPIL_CAPTURE).as_xml(),
        stream_info("gp", "gaze", GAZEPOINT).as_xml(),
    ]
    values = [NAN, 0.0, -32768.0, 1e8, 0.5, 1.0, -1.0, math.inf, 1e300]
    read = refused = 0
    deadline = time.monotonic() + 5.0
    for _ in range(3000):
        if time.monotonic() > deadline:
            break
        text = _mutate(rng.choice(bases), rng)
        try:
            layout = channel_layout(StreamDescription.from_xml(text))
        except LayoutError:
            refused += 1
            continue
        read += 1
        n = layout.stream.channel_count
        for _ in range(3):
            sample = layout.sample([rng.choice(values) for _ in range(n)], 1, SCREEN)
            assert not sample.valid or (math.isfinite(sample.x) and math.isfinite(sample.y))
    assert read > 50 and refused > 50
