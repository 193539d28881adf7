"""`gazehdr import FILE.xdf`: a real example file (xdf-modules/example-files, MIT), and round
trips: gazehdr's own LSL outlets recorded with real liblsl as LabRecorder records them, written
as the XDF specification says (tests/xdf_files.py), imported back; malformed files; a seeded
fuzz of the reader."""

from __future__ import annotations

import random
import struct
import sys
import time
from pathlib import Path

import pytest
from lsl_loopback import TOBII, Publisher, Recorder, pylsl, stream_info
from xdf_files import Stream, chunk, samples_chunk, varlen, write_xdf, xdf_bytes

from gazehdr.drivers.formats import detect_format, import_main
from gazehdr.drivers.formats.xdf import read_xdf
from gazehdr.drivers.lsl.outlet import GazeOutlets
from gazehdr.drivers.registry import open_source
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    FormatError,
    GazeEvent,
    Note,
    encode_record,
    read_session_log,
)

DATA = Path(__file__).parent / "data" / "formats" / "xdf"
GEOMETRY = ScreenGeometry(0.5, 1280, 1024, 0.7)


def _published() -> tuple[list[GazeSample], list[GazeEvent | Note]]:
    start = time.monotonic_ns()
    eye = EyeSample(99.0, 200.0, 3.25)
    samples = [
        GazeSample(start + i * 4_000_000, 100.0 + i, 200.0 - i / 4, True, eye)
        if i % 10 != 9
        else GazeSample(start + i * 4_000_000, float("nan"), float("nan"), False)
        for i in range(120)
    ]  # fmt: skip
    t = [s.t_ns for s in samples]
    others = [
        GazeEvent("fixation_start", 1, t[2], 102.0, 199.5),
        GazeEvent("fixation_end", 1, t[40], 120, 195, duration_ns=t[40] - t[2], dispersion_deg=0.4),
        GazeEvent("blink_start", 1, t[49]),
        GazeEvent("blink_end", 1, t[50], duration_ns=t[50] - t[49]),
        Note(t[60], "a note the daemon wrote"),
    ]  # fmt: skip
    return samples, others


@pytest.fixture(scope="module")
def recording() -> tuple[list[Stream], list[GazeSample], list[GazeEvent | Note]]:
    """gazehdr's outlets publishing known records beside an experiment's markers and an EEG
    stream, each recorded as LabRecorder would (header, stamped samples, clock offsets)."""
    outlets = GazeOutlets("gz-xdf", source_id="gz-xdf-test", geometry=GEOMETRY, model="test rig")
    publisher = Publisher()
    experiment = publisher.outlet(pylsl.StreamInfo("PsychoPy", "Markers", 1, 0, "string", "pp"))
    eeg = publisher.outlet(pylsl.StreamInfo("EEG", "EEG", 4, 250, "float32", "eeg-xdf"))
    names = ("gz-xdf", "gz-xdf events", "PsychoPy", "EEG")
    recorders = [Recorder(f"name='{n}'") for n in names]
    samples, others = _published()
    records = sorted([*samples, *others], key=lambda r: r.t_ns)
    outlets.push_all(records)
    experiment.push_sample(["trial 1 starts"])
    eeg.push_chunk([[float(i)] * 4 for i in range(50)])
    counts = (len(samples), len(others), 1, 50)
    deadline = time.monotonic() + 10
    while [len(r.rows) for r in recorders] != list(counts):
        assert time.monotonic() < deadline, [len(r.rows) for r in recorders]
        time.sleep(0.02)
    streams = [Stream.of(r.stop()) for r in recorders]  # their inlets gone before the outlets
    outlets.close(wait=True)
    del experiment, eeg
    publisher.withdraw_all()
    return streams, samples, others


def _untimed(record) -> dict:
    return {k: v for k, v in encode_record(record).items() if k not in ("t", "duration")}


def test_gazehdrs_streams_recorded_as_xdf_import_as_they_were_published(recording, tmp_path):
    streams, samples, others = recording
    path = write_xdf(tmp_path / "session.xdf", streams)
    assert detect_format(path) == "xdf"
    out = tmp_path / "session.jsonl"
    assert import_main([str(path), "--out", str(out)]) == 0
    log = read_session_log(out)
    assert log.header.screen == GEOMETRY  # the outlet's <screen>, not the defaults
    assert log.header.tracker["stream"] == "gz-xdf" and log.header.tracker["model"] == "test rig"
    assert [_untimed(s) for s in log.samples] == [_untimed(s) for s in samples]
    # times: LSL seconds through the recorded clock offsets, relative times kept to the µs
    t0 = samples[0].t_ns
    assert [s.t_ns - log.samples[0].t_ns for s in log.samples] == pytest.approx(
        [s.t_ns - t0 for s in samples], abs=2_000
    )
    assert [_untimed(e) for e in log.events] == [
        _untimed(e) for e in others if isinstance(e, GazeEvent)
    ]
    assert [e.duration_ns for e in log.events] == [e.duration_ns for e in others[:4]]
    texts = {n.text for n in log.notes}
    assert {"a note the daemon wrote", "PsychoPy: trial 1 starts"} <= texts
    # and it replays as a daemon source
    replayed = list(open_source(f"replay:{path}@max"))
    assert [_untimed(s) for s in replayed] == [_untimed(s) for s in log.samples]


def test_several_gaze_streams_import_the_one_named(recording, tmp_path) -> None:
    streams, *_ = recording
    tobii = stream_info("Tobii", "Eyetracker", TOBII, rate=60, source_id="tobii-xdf").as_xml()
    rows = [[0.5, 0.5, 3.0, 0.5, 0.5, 3.0], [0.25, 0.75, 3.0, float("nan"), float("nan"), 0.0]]
    path = write_xdf(tmp_path / "two.xdf", [*streams, Stream(tobii, rows, [10.0, 10.1])])
    with pytest.raises(FormatError, match=r"several gaze streams: 'gz-xdf' .*; 'Tobii' .*--stream"):
        read_xdf(path)
    log = read_xdf(path, stream="Tobii")
    assert [(s.x, s.y) for s in log.samples] == [(960.0, 540.0), (480.0, 810.0)]
    assert log.header.screen == ScreenGeometry()  # Tobii's app records none
    assert not log.events and log.header.tracker["source_id"] == "tobii-xdf"
    assert read_xdf(path, stream="gz-xdf-test").header.tracker["stream"] == "gz-xdf"
    with pytest.raises(FormatError, match="no gaze stream named 'EEG'; found 'gz-xdf'"):
        read_xdf(path, stream="EEG")
    with pytest.raises(SystemExit):
        import_main([str(DATA / "minimal.xdf"), "--out", str(tmp_path / "x"), "--units", "pix",
                     "--stream", "x", "--format", "pupil"])  # fmt: skip


def test_without_pyxdf_the_import_says_what_to_install(monkeypatch, capsys, tmp_path) -> None:
    monkeypatch.setitem(sys.modules, "pyxdf", None)
    with pytest.raises(SystemExit) as e:
        import_main([str(DATA / "minimal.xdf"), "--out", str(tmp_path / "x.jsonl")])
    assert e.value.code == 2
    assert "reading XDF needs pyxdf: install gazehdr[xdf]" in capsys.readouterr().err


def test_a_real_example_file_without_gaze_is_refused_naming_its_streams() -> None:
    with pytest.raises(FormatError) as e:
        read_xdf(DATA / "minimal.xdf")
    assert str(e.value) == (
        f"{DATA / 'minimal.xdf'}: no gaze stream to import (its streams: 'SendDataC' (EEG, 3 "
        "int16 channels), 'SendDataString' (StringMarker, 1 string channel))"
    )


def _tobii_file(**kw) -> bytes:
    info = stream_info("Tobii", "Eyetracker", TOBII, rate=60).as_xml()
    rows = [[0.1 * (i % 10), 0.5, 3.0, 0.1 * (i % 10), 0.5, 3.0] for i in range(40)]
    marks = pylsl.StreamInfo("Markers", "Markers", 1, 0, "string", "m").as_xml()
    return xdf_bytes(
        [Stream(info, rows, [i / 60 for i in range(40)], [(1.0, 0.001), (2.0, 0.001)]),
         Stream(marks, [["start"], ["end"]], [0.1, 0.5])], **kw,
    )  # fmt: skip


def _header(sid: int, xml: str) -> bytes:
    return chunk(2, struct.pack("<I", sid) + xml.encode())


GOOD = _tobii_file()
INFO = stream_info("Tobii", "Eyetracker", TOBII).as_xml()


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"t,x,y\n0,1,2\n", "not an XDF file: it does not begin with 'XDF:'"),
        (b"XDF:" + b"\x03abc", "field 'chunk': byte 4: a length of 3 bytes"),
        (b"XDF:" + chunk(9, b"??"), "byte 4: chunk 1 has tag 9"),
        (b"XDF:" + samples_chunk(7, "float32", [[1.0] * 6], [0.0]), "stream 7 has no StreamHeader"),
        (
            b"XDF:" + _header(1, INFO) + chunk(3, struct.pack("<I", 1) + varlen(10**9) + b"\0" * 8),
            "1000000000 samples of stream 1 cannot fit in 8 bytes",
        ),
        (b"XDF:" + _header(1, "<info><name>x</name></info>"), "channel_count None, format ''"),
        (b"XDF:" + _header(1, INFO) + _header(1, INFO), "a second header for stream 1"),
        (b"XDF:" + _header(1, INFO), "the gaze stream holds no samples"),
        (
            b"XDF:" + _header(1, INFO) + chunk(4, struct.pack("<Id", 1, 0.0)),
            r"ClockOffset': byte \d+: 12 bytes, 20 expected",
        ),
    ],
)
def test_malformed_files_are_refused_saying_where(tmp_path, data: bytes, message: str) -> None:
    path = tmp_path / "bad.xdf"
    path.write_bytes(data)
    with pytest.raises(FormatError, match=message):
        read_xdf(path)


def test_a_file_cut_short_is_read_as_far_as_it_goes(tmp_path) -> None:
    data = _tobii_file(per_chunk=10)
    starts = [i for i in range(len(data)) if data.startswith(b"\x03\x00\x01\x00\x00\x00", i)]
    path = tmp_path / "cut.xdf"
    path.write_bytes(data[: starts[2] + 40])  # inside the gaze stream's third Samples chunk
    log = read_xdf(path)
    assert 10 <= len(log.samples) < 40 and len(log.samples) % 10 == 0
    assert any(n.text.startswith("cut short: chunk") for n in log.notes)


def test_a_broken_marker_of_gazehdrs_stream_is_refused(tmp_path) -> None:
    gaze = stream_info("g", "Gaze", TOBII, source_id="g1").as_xml()
    marks = pylsl.StreamInfo("g events", "Markers", 1, 0, "string", "g1:events")
    marks.desc().append_child_value("gaze_source_id", "g1")
    rows = [[0.5, 0.5, 3.0, 0.5, 0.5, 3.0]]
    path = write_xdf(
        tmp_path / "m.xdf", [Stream(gaze, rows, [1.0]), Stream(marks.as_xml(), [["{oops"]], [1.0])]
    )
    with pytest.raises(FormatError, match=r"m.xdf:1: a record is a JSON object"):
        read_xdf(path)


def test_fuzz_the_reader_refuses_or_reads_never_crashes(tmp_path) -> None:
    """Seeded and bounded: flipped bytes, cuts and insertions in a valid file give a session
    log or a FormatError, nothing else (and never hang or blow up memory)."""
    rng = random.Random(7)
    path = tmp_path / "fuzz.xdf"
    read = refused = 0
    deadline = time.monotonic() + 6.0
    while time.monotonic() < deadline and read + refused < 400:
        data = bytearray(GOOD)
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(data))
            op = rng.random()
            if op < 0.6:
                data[i] = rng.randrange(256)
            elif op < 0.8:
                del data[i : i + rng.randint(1, 16)]
            else:
                data[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        if rng.random() < 0.2:
            del data[rng.randrange(len(data)) :]
        path.write_bytes(bytes(data))
        try:
            read_xdf(path)
            read += 1
        except FormatError:
            refused += 1
    assert read > 20 and refused > 20, (read, refused)
