"""The fuzzing campaign in CI: every target for a bounded count from its corpus (the seeds and
the reproducers of every crash found, which libFuzzer replays first), and each crash found
(docs/fuzzing.md) as a regression test through the real parser.

A target that crashes fails its test with the runner's report; the runner itself is checked
against a child that dies (a deadly signal, as a C++ crash in OpenEXR would be) and a child
that raises, so that a silent runner cannot pass these tests.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from gazehdr.drivers import wire
from gazehdr.drivers.formats.bids import read_bids
from gazehdr.drivers.formats.pupil import read_pupil_gaze_csv
from gazehdr.drivers.hid.descriptor import INPUT, Descriptor, DescriptorError, ReportError
from gazehdr.drivers.hid.tracker import TrackerReports
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sessionlog import FormatError, read_session_log
from gazehdr.fuzz.runner import REPO_CORPUS, _what, run_target
from gazehdr.fuzz.targets import BIDS_SEPARATOR, TARGETS, split_bids, split_hid
from gazehdr.protocol import ProtocolError, parse_control
from gazehdr.scenes.decoding import SceneError
from gazehdr.scenes.exr import write_exr
from gazehdr.scenes.library import SceneLibrary

#: Inputs per target in CI: 1 to 5 s each on a 2-core machine (the corpus included).
CI_RUNS = {
    "exr": 6000, "hid": 12000, "sessionlog": 1200, "eyelink": 1500, "tobii": 2000,
    "pupil": 2500, "bids": 1200, "xdf": 2000, "control": 20000, "wire": 20000,
}  # fmt: skip


def repro(target: str, name: str) -> bytes:
    return (REPO_CORPUS / target / f"repro-{name}").read_bytes()


def run_once(target: str, data: bytes) -> Exception | None:
    """What the target's fuzz run does with `data`: its documented error (returned), or None;
    any other exception propagates, and fails the test, as it crashes the run."""
    one, documented = TARGETS[target].load()
    try:
        one(data)
    except documented as e:
        return e
    return None


# --- the bounded run ---------------------------------------------------------------------------


#: The EXR seeds make_seeds.py writes: the 8 compressions, luminance-only, layered, tiled.
EXR_SEEDS = {
    *(f"seed-rgb-{c}.exr" for c in ("no", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa")),
    "seed-y.exr", "seed-layers.exr", "seed-tiled.exr", "seed-rgbe.hdr", "seed-a.pfm",
}  # fmt: skip


def test_every_target_has_a_ci_budget_and_a_committed_corpus() -> None:
    """Every target's corpus folder holds seeds, the EXR one the seeds make_seeds.py writes,
    and git would commit every file of it. Guards the corpus lines of .gitignore: with
    `!tests/fuzz_corpus/**` removed, `*.exr` drops the EXR seeds (checked) and this fails."""
    assert set(CI_RUNS) == set(TARGETS)
    for name in TARGETS:
        folder = REPO_CORPUS / name
        assert folder.is_dir() and any(folder.glob("seed-*")), name
        assert all(p.stat().st_size > 0 for p in folder.iterdir()), name
    assert EXR_SEEDS <= {p.name for p in (REPO_CORPUS / "exr").iterdir()}
    files = sorted(str(p) for p in REPO_CORPUS.rglob("*") if p.is_file())
    total = sum(Path(f).stat().st_size for f in files)
    assert total < 200_000  # the corpus stays small
    root = REPO_CORPUS.parents[1]
    if not (root / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout: nothing to check against .gitignore")
    ignored = subprocess.run(
        ["git", "check-ignore", "--no-index", "--stdin"],
        input="\n".join(os.path.relpath(f, root) for f in files),
        capture_output=True, text=True, cwd=root, check=False,
    )  # fmt: skip
    assert ignored.returncode in (0, 1), ignored.stderr  # 1: none is ignored
    assert ignored.stdout == "", f"git ignores corpus files:\n{ignored.stdout}"


@pytest.mark.parametrize("name", list(CI_RUNS))
def test_target_runs_clean_from_its_corpus(name: str, tmp_path: Path) -> None:
    result = run_target(name, tmp_path, runs=CI_RUNS[name], seconds=None, quiet=True, seed=1)
    assert not result.crashes, result.crashes
    assert result.runs >= CI_RUNS[name]


# --- the runner catches what it must ----------------------------------------------------------


def test_runner_reports_an_exception_a_deadly_signal_and_a_hang(tmp_path: Path) -> None:
    """A child that raises, one that dies of SIGSEGV and one that hangs, as libFuzzer (under
    the runner's options) reports them, and the input kept."""
    code = (
        "import atheris, sys, ctypes, time\n"
        "def one(data):\n"
        "    if data.startswith(b'RAISE'): raise KeyError('planted')\n"
        "    if data.startswith(b'SEGV'): ctypes.string_at(0)\n"
        "    if data.startswith(b'HANG'): time.sleep(30)\n"
        "atheris.Setup(sys.argv, one); atheris.Fuzz()\n"
    )
    cases = [(b"RAISE", "KeyError", "crash-"), (b"SEGV", "deadly signal", "crash-"),
             (b"HANG", "timeout after", "timeout-")]  # fmt: skip
    for planted, expected, prefix in cases:
        seeds = tmp_path / planted.decode()
        seeds.mkdir()
        (seeds / "x").write_bytes(planted)
        args = [sys.executable, "-c", code, f"-artifact_prefix={seeds}/", "-runs=10", "-timeout=1"]
        proc = subprocess.run([*args, str(seeds)], capture_output=True, text=True, check=False)
        assert proc.returncode != 0
        _, what = _what(proc.stdout + proc.stderr)
        assert expected in what, what
        (kept,) = seeds.glob(f"{prefix}*")  # the input kept as a reproducer
        assert kept.read_bytes() == planted


# --- EXR: the bug, through the real upload route --------------------------------------


def _exr_with_channel_name(tmp_path: Path) -> bytes:
    """A valid layered EXR whose channel `diffuse.R` is renamed `\\xbdiffuse.R` (one byte
    changed, as the fuzzer did): not UTF-8."""
    path = tmp_path / "layers.exr"
    rgb = np.full((3, 4), 5.0, np.float32)
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {f"diffuse.{c}": rgb.copy() for c in "RGB"}
    OpenEXR.File(header, channels).write(str(path))
    data = path.read_bytes()
    assert data.count(b"diffuse.R\x00") == 1
    return data.replace(b"diffuse.R\x00", b"\xbdiffuse.R\x00")


def _http(method: str, url: str, body: bytes, **headers: str) -> tuple[int, dict]:
    request = urllib.request.Request(url, data=body, method=method, headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def test_exr_channel_name_not_utf8_is_a_4xx_naming_it(live_server, tmp_path: Path) -> None:
    data = _exr_with_channel_name(tmp_path)
    assert data == repro("exr", "channel-name-not-utf8")
    server = live_server()
    status, body = _http("PUT", server.url + "/api/scenes/bad", data, **server.auth)
    assert status == 422, (status, body)
    assert body["detail"] == (
        "upload 'bad': EXR channel name b'\\xbdiffuse.R' is not UTF-8 text "
        "(invalid start byte at byte 0)"
    )
    assert not list((server.config.data_dir / "scenes").glob("bad*"))  # nothing kept


def test_exr_white_luminance_of_an_unknown_type_is_ignored_with_a_note(tmp_path: Path) -> None:
    library = SceneLibrary(tmp_path)
    library.store("w", [repro("exr", "white-luminance-unknown-type")])
    info = library.describe("w")
    assert "whiteLuminance ignored: a OpaqueAttribute, not a number" in info["notes"]


def test_exr_chromaticities_of_an_unknown_type_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "a.exr"
    write_exr(path, np.ones((2, 2, 3), np.float32))
    data = path.read_bytes()
    # A chromaticities attribute whose type name is unknown to OpenEXR (kept as opaque bytes).
    attribute = b"chromaticities\x00chromaticitiez\x00" + (32).to_bytes(4, "little") + bytes(32)
    header_end = _header_end(data)
    patched = data[:header_end] + attribute + data[header_end:]
    with pytest.raises(SceneError, match="chromaticities attribute is not of type"):
        SceneLibrary(tmp_path).store("c", [_shift_offsets(patched, len(attribute))])


def _header_end(data: bytes) -> int:
    """Offset of the NUL that ends a single-part scanline EXR header."""
    pos = 8
    while data[pos] != 0:
        name_end = data.index(b"\x00", pos)
        type_end = data.index(b"\x00", name_end + 1)
        size = int.from_bytes(data[type_end + 1 : type_end + 5], "little")
        pos = type_end + 5 + size
    return pos


def _shift_offsets(data: bytes, by: int) -> bytes:
    """The scanline offset table after the header, moved by `by` bytes."""
    start = _header_end(data) + 1
    first = int.from_bytes(data[start : start + 8], "little")  # not moved yet
    count = (first - (start - by)) // 8
    table = b"".join(
        (int.from_bytes(data[start + 8 * i : start + 8 * i + 8], "little") + by).to_bytes(
            8, "little"
        )
        for i in range(count)
    )
    return data[:start] + table + data[start + 8 * count :]


# --- HID ---------------------------------------------------------------------------------------

#: Usage Page 0x12 (eye tracker), Usage 0x01, Collection (Application) ... End Collection.
_OPEN, _CLOSE = b"\x05\x12\x09\x01\xa1\x01", b"\xc0"


@pytest.mark.parametrize(
    ("descriptor", "message"),
    [
        # Collection with a 2-byte type (hid-tools asserted, an AssertionError)
        (b"\x05\x12\x09\x01\xa2\x09\x12\xc0", "Collection type 0x1209 does not fit in a byte"),
        # Report Size 0 on a value (hid-tools then returned '<.>' for it: a ValueError in int())
        (_OPEN + b"\x09\x02\x15\x00\x25\x01\x75\x00\x95\x01\x81\x02" + _CLOSE, "Report Size 0"),
        # Unit Exponent 32 in a 4-byte item (10.0 ** 32... and beyond: OverflowError)
        (_OPEN + b"\x57\x00\x00\x00\x7f\x09\x02\x75\x08\x95\x01\x81\x02" + _CLOSE, "Unit Exponent"),
        # Usage Minimum 0 .. Maximum 2^31 on an array (hid-tools built a list of 2^31 usages)
        (
            _OPEN + b"\x19\x01\x2b\xff\xff\xff\x7f\x75\x08\x95\x01\x81\x00" + _CLOSE,
            "Usage range beyond 12288",
        ),
        # Report Count 2^31 on a variable (as many field objects)
        (_OPEN + b"\x09\x02\x75\x08\x97\xff\xff\xff\x7f\x81\x02" + _CLOSE, "Report Count"),
        (_OPEN + b"\x09\x02\x77\x00\x00\x01\x00\x95\x01\x81\x02" + _CLOSE, "Report Size 65536"),
    ],
)
def test_hid_descriptors_the_fuzzer_broke_are_refused(descriptor: bytes, message: str) -> None:
    with pytest.raises(DescriptorError, match=message):
        Descriptor(descriptor)


@pytest.mark.parametrize(
    "name",
    [
        "unit-exponent-overflow",
        "usage-range-out-of-memory",
        "collection-type-not-a-byte",
        "report-size-0",
    ],
)
def test_hid_reproducers_are_descriptor_errors(name: str) -> None:
    descriptor, _ = split_hid(repro("hid", name))
    with pytest.raises(DescriptorError):
        Descriptor(descriptor)


def test_hid_value_array_wider_than_a_float_is_a_report_error() -> None:
    """The fuzzer's descriptor: 34 Position values of 32 bits in one main item, 33 of them
    joined as one 1056-bit number, too large for a float: `decode` raised OverflowError on its
    8th report (189 bytes). Guards the width check in `Descriptor.decode` (removed: the
    OverflowError, here and in the target's own run)."""
    data = repro("hid", "value-array-wider-than-a-float")
    descriptor, reports = split_hid(data)
    d = Descriptor(descriptor)  # the descriptor opens; the report does not decode
    with pytest.raises(ReportError, match=r"usage 0x00120022 is a value array of 33 × 32 bits"):
        d.decode(INPUT, reports[7])
    run_once("hid", data)


@pytest.mark.parametrize("name", ["mode-request-two-ranges", "mode-request-too-few-bits"])
def test_hid_device_mode_request_that_cannot_hold_the_mode(name: str) -> None:
    """Device Mode Request fields whose range or size cannot hold the mode (a second field of
    that usage with another range; a 1-bit field whose logical maximum says 3): hid-tools
    raised its RangeError or a bare Exception while the report was built."""
    descriptor, _ = split_hid(repro("hid", name))
    tracker = TrackerReports(Descriptor(descriptor))
    with pytest.raises(ReportError, match="cannot hold 3"):
        tracker.mode_request(None)


# --- JSON: the WebSocket protocols and the session log ----------------------------------------

DEEP = "[" * 100_000 + "]" * 100_000


@pytest.mark.parametrize(
    ("parse", "error"), [(wire.parse, wire.WireError), (parse_control, ProtocolError)]
)
def test_messages_nested_too_deeply_are_protocol_errors(parse, error) -> None:
    with pytest.raises(error, match="nested too deeply"):
        parse('{"type": "gaze", "x": ' + "[" * 5000 + "]" * 5000 + "}")
    if parse is wire.parse:  # the gaze socket's limit is 1 MiB; the viewer's 64 KiB
        with pytest.raises(error, match="nested too deeply"):
            parse(DEEP)


def test_integers_too_large_for_a_float_are_protocol_errors() -> None:
    big = "1" + "0" * 400
    with pytest.raises(ProtocolError, match="'width' must be a finite number"):
        parse_control(f'{{"type": "viewport", "width": {big}, "height": 10}}')
    with pytest.raises(ProtocolError, match="'x' must be a finite number"):
        parse_control(f'{{"type": "gaze", "x": -{big}, "y": 0, "seq": 1}}')
    with pytest.raises(wire.WireError, match=r"'screen\.screen_width_px' must be a positive"):
        wire.parse(f'{{"type": "hello", "protocol": 1, "screen": {{"screen_width_px": {big}}}}}')
    with pytest.raises(wire.WireError, match=r"samples\[0\]: 'x' must be finite"):
        wire.parse(f'{{"type": "samples", "samples": [{{"t": 1, "x": {big}, "y": 0}}]}}')
    for name in ("control", "wire"):
        with pytest.raises((ProtocolError, wire.WireError)):
            (parse_control if name == "control" else wire.parse)(repro(name, "huge-integer"))


def _log(tmp_path: Path, *lines: str) -> Path:
    seed = (REPO_CORPUS / "sessionlog" / "seed-bino.jsonl").read_text().splitlines()
    path = tmp_path / "log.jsonl"
    path.write_text("\n".join([seed[0], *lines]) + "\n")
    return path


def test_session_log_lines_nested_too_deeply_or_too_large_are_format_errors(
    tmp_path: Path,
) -> None:
    with pytest.raises(FormatError, match=r"log.jsonl:2: not a JSON record: JSON nested too"):
        read_session_log(_log(tmp_path, DEEP, '{"k": "note", "t": 1, "text": "after"}'))
    big = "1" + "0" * 400
    with pytest.raises(FormatError, match="field 'l': an integer of 401 digits is too large"):
        read_session_log(
            _log(tmp_path, f'{{"k": "s", "t": 1, "v": 1, "x": 0, "y": 0, "l": [{big}, 0]}}')
        )
    with pytest.raises(FormatError, match="field 'x': an integer of 401 digits is too large"):
        read_session_log(_log(tmp_path, f'{{"k": "s", "t": 1, "v": 1, "x": {big}, "y": 0}}'))
    path = tmp_path / "repro.jsonl"
    path.write_bytes(repro("sessionlog", "huge-integer"))
    with pytest.raises(FormatError, match="digits is too large"):
        read_session_log(path)


def test_a_log_time_beyond_64_bits_is_a_format_error(tmp_path: Path) -> None:
    """The fuzzer's log: a fixation_end at t = 10^400 (json reads any integer), read without
    complaint; its fixation track's duration, (last - first) / 1e9, raised OverflowError.
    Guards the 64-bit check of `_Fields.integer` in the session log codec (removed: the
    OverflowError again, and the bounds below no error at all)."""
    err = run_once("sessionlog", repro("sessionlog", "event-time-beyond-64-bits"))
    assert isinstance(err, FormatError)
    assert str(err).endswith(
        ":10: field 't': must fit in 64 bits (a signed integer), got an integer of 401 digits"
    )
    for t, ok in ((2**63 - 1, True), (-(2**63), True), (2**63, False), (-(2**63) - 1, False)):
        path = _log(tmp_path, f'{{"k": "fixation_start", "id": 1, "t": {t}}}')
        if ok:
            assert read_session_log(path).events[0].t_ns == t
        else:
            with pytest.raises(FormatError, match=f"field 't': must fit in 64 bits.*got {t}$"):
                read_session_log(path)


def test_a_log_that_repeats_a_sample_time_has_a_fixation_track(tmp_path: Path) -> None:
    """I-VT refused it (ValueError: timestamps must increase strictly): read_session_track of
    an XDF import whose times went back (held at the previous time) failed the same way."""
    samples = [f'{{"k": "s", "t": {t}, "v": 1, "x": {x}, "y": 500}}' for t, x in
               [(0, 100), (1_000_000, 100), (1_000_000, 101), (2_000_000, 100)]]  # fmt: skip
    log = read_session_log(_log(tmp_path, *samples))
    track = log.fixation_track()
    assert track is not None
    path = tmp_path / "repro.jsonl"
    path.write_bytes(repro("sessionlog", "repeated-sample-time"))
    assert read_session_log(path).fixation_track() is not None


# --- importers ---------------------------------------------------------------------------------


def test_pupil_csv_bytes_that_are_not_utf8_are_a_field_error(tmp_path: Path) -> None:
    seed = (REPO_CORPUS / "pupil" / "seed-gaze_positions.csv").read_bytes().splitlines()
    path = tmp_path / "gaze_positions.csv"
    path.write_bytes(b"\n".join([seed[0], seed[1].replace(b",0.99,", b",0.9\xff,"), *seed[2:]]))
    with pytest.raises(FormatError, match=r"gaze_positions\.csv:2: field 'confidence'"):
        read_pupil_gaze_csv(path)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        # the fuzzer's: "display size in cm: 533x.00.0" (float('.00.0'), a ValueError)
        ("display-size-not-a-number", ":7: field 'display size in cm': expected positive "
         "numbers of cm, got '533x.00.0'"),
        # the seed with a screen 0 pixels high (ScreenGeometry's ValueError)
        ("screen-height-0", ":3: field 'Recording resolution': expected the screen's width x "
         "height, 1 to 65536 pixels each, got '1920 x 0'"),
    ],
)  # fmt: skip
def test_tobii_screen_lines_that_size_no_screen_are_format_errors(name: str, message: str) -> None:
    """Guards the check of tobii's `_meta_values` (removed: a ValueError, a crash of the
    target, from float() and from ScreenGeometry)."""
    err = run_once("tobii", repro("tobii", name))
    assert isinstance(err, FormatError) and str(err).endswith(message), err


def _bids_run(tmp_path: Path, data: bytes) -> Path:
    sidecar, rows, _ = split_bids(data)
    folder = tmp_path / "sub-01" / "beh"
    folder.mkdir(parents=True)
    stem = "sub-01_task-fuzz_recording-eye1_physio"
    (folder / f"{stem}.json").write_bytes(sidecar)
    (folder / f"{stem}.tsv.gz").write_bytes(rows)
    return folder / f"{stem}.tsv.gz"


def test_bids_sidecar_not_utf8_or_too_deep_and_corrupt_gzip_are_format_errors(
    tmp_path: Path,
) -> None:
    seed = (REPO_CORPUS / "bids" / "seed-eye1-gz").read_bytes()
    sidecar, rows, events = split_bids(seed)
    cases = [
        (sidecar.replace(b"{", b"{\xff", 1), rows, "not UTF-8 text: invalid start byte at byte 1"),
        (b"[" * 100_000, rows, "not valid JSON: nested too deeply"),
        # the deflate data cut and changed after a valid gzip header: zlib.error
        (sidecar, rows[:12] + b"\xff" * 20, "cannot read as gzip TSV: Error -3"),
    ]
    for i, (side, physio, message) in enumerate(cases):
        data = BIDS_SEPARATOR.join([side, physio, events])
        with pytest.raises(FormatError, match=message):
            read_bids(_bids_run(tmp_path / str(i), data), geometry=ScreenGeometry())


def test_xdf_cut_short_samples_chunk_with_a_huge_count_is_never_allocated(tmp_path: Path) -> None:
    """The last chunk runs past the end of the file (read as far as it goes, as a crash of
    LabRecorder leaves it) and says it holds 134217729 samples: pyxdf allocated ~2 GB for
    them, then dropped the chunk. Found by this file's bounded run of the xdf target. Read
    in a child whose peak memory is measured (numpy and pyxdf need ~100 MB): VmHWM, this
    program's own peak; ru_maxrss would include the forked test process's, which Linux carries
    over the exec (562 MiB late in the suite)."""
    path = tmp_path / "cut.xdf"
    path.write_bytes(repro("xdf", "cut-chunk-sample-count"))
    code = (
        "import sys; from pathlib import Path\n"
        "from gazehdr.drivers.formats.xdf import read_xdf\n"
        "from gazehdr.drivers.sessionlog import FormatError\n"
        "try:\n    read_xdf(Path(sys.argv[1]))\n"
        "except FormatError as e:\n    print(e)\n"
        "hwm = [l for l in Path('/proc/self/status').read_text().splitlines() if 'VmHWM' in l]\n"
        "print(int(hwm[0].split()[1]) // 1024, 'MiB')\n"
    )
    args = [sys.executable, "-c", code, str(path)]
    proc = subprocess.run(args, capture_output=True, text=True, check=True)
    message, peak = proc.stdout.splitlines()
    assert "no gaze stream to import (its streams: 'SendDataC'" in message
    assert int(peak.split()[0]) < 400, peak
    assert "cut short: chunk" in _notes_of_cut(path)


def _notes_of_cut(path: Path) -> str:
    from gazehdr.drivers.formats.xdf import check_structure

    return " ".join(check_structure(path))


def test_xdf_samples_that_do_not_fill_their_chunk_are_refused_before_pyxdf(
    tmp_path: Path,
) -> None:
    """The fuzzer's file (a timeout, 14 GB resident when let run): a string sample's length
    of 0x67 bytes (neither 1, 4 nor 8) made pyxdf give up on a Samples chunk mid-way, scan
    forward to a Boundary signature copied inside that chunk, and read a count of 1.7 billion
    samples from there. Guards `_samples_layout` in the XDF walk (removed: the walk lets the
    file through; the first assertion fails before pyxdf is called)."""
    from gazehdr.drivers.formats.xdf import _samples_layout, _Stream, check_structure

    path = tmp_path / "resync.xdf"
    path.write_bytes(repro("xdf", "samples-resync-huge-count"))
    message = "byte 653: stream 46202862: sample 1: a string length of 103 bytes (1, 4 or 8)"
    with pytest.raises(FormatError, match=re.escape(message)):
        check_structure(path)
    err = run_once("xdf", path.read_bytes())
    assert isinstance(err, FormatError) and str(err).endswith(message)
    # what pyxdf reads of each sample: a flag byte (not 0: a double follows), then the values
    doubles, strings = _Stream(2, 8), _Stream(1, 0)
    one = b"\x00" + bytes(16)
    assert _samples_layout(one * 3, 3, doubles) is None
    assert _samples_layout(b"\x08" + bytes(8) + bytes(16), 1, doubles) is None
    assert _samples_layout(one * 3 + b"\x00", 3, doubles) == (
        "its 3 samples end 1 bytes before the chunk's end"
    )
    assert _samples_layout(one * 2, 3, doubles) == "sample 3 of 3 starts past the chunk's end"
    assert _samples_layout(b"\x00\x01\x02hi", 1, strings) is None
    assert _samples_layout(b"\x00\x01\x05hi", 1, strings) == (
        "sample 1 of 1 runs past the chunk's end"
    )
    assert _samples_layout(b"\x00\x04\x02\x00\x00\x00hi\x00\x02\x02hi", 2, strings) == (
        "sample 2: a string length of 2 bytes (1, 4 or 8)"
    )
