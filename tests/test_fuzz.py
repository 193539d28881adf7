"""The fuzzing campaign in CI: every target for a bounded count from its corpus (the seeds and
the reproducers of every crash found, which libFuzzer replays first), and each crash found
(docs/fuzzing.md) as a regression test through the real parser.

A target that crashes fails its test with the runner's report; the runner itself is checked
against a child that dies (a deadly signal, as a C++ crash in OpenEXR would be) and a child
that raises, so that a silent runner cannot pass these tests.
"""

from __future__ import annotations

import json
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
from gazehdr.drivers.hid.descriptor import Descriptor, DescriptorError, ReportError
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


# --- the bounded run ---------------------------------------------------------------------------


def test_every_target_has_a_ci_budget_and_seeds() -> None:
    assert set(CI_RUNS) == set(TARGETS)
    for name in TARGETS:
        assert any((REPO_CORPUS / name).glob("seed-*")), name
    total = sum(p.stat().st_size for p in REPO_CORPUS.rglob("*") if p.is_file())
    assert total < 64_000  # the corpus stays small


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
