"""The fuzz targets: each turns one input (bytes) into a call of a parser we ship.

A target's `load` imports what it tests (inside atheris' instrumentation, so coverage reaches
it) and returns the function to call on each input and the parser's documented errors. Any
other exception is a crash; so is a hang past the per-input time limit, a memory blow-up past
the limit, and the death of the process (a C++ crash in the OpenEXR bindings). Every target
runs in a child process (`gazehdr.fuzz.worker`), one per target.

Engines: all targets use atheris (libFuzzer, coverage-guided). The two WebSocket protocols and
the session log are JSON, where byte mutation mostly makes text the JSON scanner refuses at
once: those targets add a structure-aware mutator (`jsonmut`) that changes the parsed tree
(types, sizes, depth, keys) before falling back to bytes. We chose that over Hypothesis
because it keeps coverage feedback, one corpus format, one crash-file format and one runner;
Hypothesis generates well-typed values but is blind to which of them reach new code.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import gzip
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

OneInput = Callable[[bytes], object]
Loaded = tuple[OneInput, tuple[type[BaseException], ...]]


@dataclass(frozen=True)
class Target:
    name: str
    what: str  # the code under test
    errors: str  # the documented errors: anything else is a crash
    load: Callable[[], Loaded]
    instrument: tuple[str, ...] = ("gazehdr",)
    mutator: str | None = None  # "json" or "jsonl": jsonmut's structure-aware mutators
    max_len: int = 4096  # libFuzzer's -max_len


_DIR: Path | None = None


def scratch() -> Path:
    """This process's folder for the files an input is written to: the runner's (it removes
    it when the child ends, a crash included), else a temporary one removed at exit."""
    global _DIR
    if _DIR is None:
        given = os.environ.get("GAZEHDR_FUZZ_SCRATCH")
        _DIR = Path(given) if given else Path(tempfile.mkdtemp(prefix="gazehdr-fuzz-"))
        if not given:
            atexit.register(shutil.rmtree, _DIR, True)
    return _DIR


class InPlace:
    """A scratch file that each input is written over, in place, for a parser that reads a path.

    Written as `Path.write_bytes` would, each input would cost a truncation to 0 bytes and a
    rewrite, which ext4 (`auto_da_alloc`) makes a flush to disk when the file is closed: about
    0.35 ms an input on the development machine, most of a line-format target's time. Written
    over the last input and cut to the new length, through one descriptor kept open, it
    costs microseconds. `write(None)` removes the file (an absent optional file)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def write(self, data: bytes | None) -> None:
        if data is None:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
                self.path.unlink()
            return
        if self._fd is None:
            self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        os.pwrite(self._fd, data, 0)
        os.ftruncate(self._fd, len(data))


def _file_reader(suffix: str, read: Callable[[Path], object]) -> OneInput:
    file = InPlace(scratch() / f"input{suffix}")

    def one(data: bytes) -> object:
        file.write(data)
        return read(file.path)

    return one


# --- EXR upload -------------------------------------------------------------------------------


def _exr() -> Loaded:
    from gazehdr.scenes.decoding import SceneError
    from gazehdr.scenes.image import ImageScene, file_format

    upload = InPlace(scratch() / "upload.tmp")

    def one(data: bytes) -> object:
        # What PUT /api/scenes/NAME runs on an upload: the format from its first bytes here,
        # then, in the decode worker (gazehdr.scenes.sandbox), ImageScene.open. This target
        # runs both in its own child, without a worker per input.
        upload.write(data)
        file_format(upload.path)
        return ImageScene.open(upload.path)

    return one, (SceneError,)


# --- HID --------------------------------------------------------------------------------------


def split_hid(data: bytes) -> tuple[bytes, list[bytes]]:
    """An input as (descriptor, reports): a 2-byte little-endian descriptor length, the
    descriptor, then reports, each after a 1-byte length."""
    n = int.from_bytes(data[:2], "little")
    descriptor, rest = data[2 : 2 + n], data[2 + n :]
    reports = []
    while rest:
        k = rest[0]
        reports.append(rest[1 : 1 + k])
        rest = rest[1 + k :]
    return descriptor, reports


def _hid() -> Loaded:
    from gazehdr.drivers.hid.descriptor import INPUT, Descriptor, DescriptorError, ReportError
    from gazehdr.drivers.hid.tracker import TrackerInfo, TrackerReports, gaze_sample
    from gazehdr.drivers.samples import ScreenGeometry

    geometry = ScreenGeometry()

    def one(data: bytes) -> None:
        # What HidGazeSource does with a device: descriptor, feature reports, mode, reports.
        descriptor, reports = split_hid(data)
        d = Descriptor(descriptor)
        for report in reports:
            with contextlib.suppress(ReportError):
                d.decode(INPUT, report)
        tracker = TrackerReports(d)
        features = []
        for rid, report in zip(tracker.feature_ids, reports, strict=False):
            with contextlib.suppress(ReportError):
                features.append(tracker.decode_feature(rid, report))
        info = TrackerInfo.of({"path": b"fuzz"}, features, None)
        try:
            tracker.mode_request(None)
        except ReportError:  # the Device Mode Request field cannot hold the mode
            pass
        except ValueError as e:  # documented: a mode outside the tracker's logical range
            if "outside the tracker's range" not in str(e):
                raise
        for report in reports:
            try:
                decoded = tracker.decode(report)
            except ReportError:
                continue
            if decoded is not None:
                gaze_sample(decoded, 0, geometry, info.calibrated_screen_um)

    return one, (DescriptorError, ReportError)


# --- session log and importers ----------------------------------------------------------------


def _sessionlog() -> Loaded:
    from gazehdr.drivers.sessionlog import FormatError, read_session_log

    def read(path: Path) -> object:
        # read_session_track's steps: a log without samples has no track (documented).
        log = read_session_log(path)
        return log.fixation_track() if log.samples else log

    return _file_reader(".jsonl", read), (FormatError,)


def _importer(module: str, function: str, suffix: str) -> Callable[[], Loaded]:
    def load() -> Loaded:
        import importlib

        from gazehdr.drivers.sessionlog import FormatError

        read = getattr(importlib.import_module(module), function)
        return _file_reader(suffix, read), (FormatError,)

    return load


def _tobii() -> Loaded:
    from gazehdr.drivers.formats.tobii import UNITS, read_tobii_tsv
    from gazehdr.drivers.sessionlog import FormatError

    file = InPlace(scratch() / "input.tsv")

    def one(data: bytes) -> object:
        # psychopy_tobii_controller's positions need units (`--units`): one of them by the
        # input's length, so that its rows are read, not refused (PyGaze's files ignore it).
        file.write(data)
        return read_tobii_tsv(file.path, units=UNITS[len(data) % len(UNITS)])

    return one, (FormatError,)


BIDS_SEPARATOR = b"\n\x00--\x00\n"
_BIDS_STEM = "sub-01_task-fuzz_recording-eye1_physio"
_BIDS_EVENTS_SIDECAR = {
    "Columns": ["onset", "duration", "trial_type", "blink", "message"],
    "OnsetSource": "timestamp",
}


def split_bids(data: bytes) -> tuple[bytes, bytes, bytes]:
    """An input as (sidecar JSON, physio TSV, physioevents TSV), joined by BIDS_SEPARATOR; the
    TSVs are gzipped by the target unless they are gzip already."""
    parts = [*data.split(BIDS_SEPARATOR, 2), b"", b""]
    return parts[0], parts[1], parts[2]


def _bids() -> Loaded:
    from gazehdr.drivers.formats.bids import read_bids
    from gazehdr.drivers.samples import ScreenGeometry
    from gazehdr.drivers.sessionlog import FormatError

    root = scratch() / "bids"
    folder = root / "sub-01" / "beh"
    folder.mkdir(parents=True, exist_ok=True)
    # The dataset's root: the sidecar search goes up to it and no further (else up into the
    # scratch folder's parents, /tmp and its other files, on every input). The physioevents
    # sidecar there, as eye2bids writes it (the input has none): without one, every input
    # with an events part is refused before its rows are read.
    (root / "dataset_description.json").write_text('{"Name": "fuzz", "BIDSVersion": "1.9.0"}')
    (root / "task-fuzz_physioevents.json").write_text(json.dumps(_BIDS_EVENTS_SIDECAR))
    sidecar_file = InPlace(folder / f"{_BIDS_STEM}.json")
    physio = InPlace(folder / f"{_BIDS_STEM}.tsv.gz")
    events_file = InPlace(folder / f"{_BIDS_STEM}events.tsv.gz")
    geometry = ScreenGeometry()

    @functools.lru_cache(maxsize=4)
    def gz(part: bytes) -> bytes:
        # A part that starts as gzip does is written as it is (the gzip layer fuzzed too);
        # most mutants change one part, so the others' compression is the last input's.
        if part.startswith(b"\x1f\x8b"):
            return part
        return gzip.compress(part, mtime=0, compresslevel=1)

    def one(data: bytes) -> object:
        sidecar, rows, events = split_bids(data)
        sidecar_file.write(sidecar)
        physio.write(gz(rows))
        events_file.write(gz(events) if events else None)
        # The screen given, as `gazehdr import --screen` does: a run without an events sidecar
        # saying it would otherwise be refused before any row is read.
        return read_bids(physio.path, geometry=geometry)

    return one, (FormatError,)


# --- WebSocket messages -----------------------------------------------------------------------


def _control() -> Loaded:
    from gazehdr.protocol import ProtocolError, parse_control

    return parse_control, (ProtocolError,)


def _wire() -> Loaded:
    from gazehdr.drivers.wire import WireError, parse, parse_reply

    def one(data: bytes) -> None:
        for reader in (parse, parse_reply):
            with contextlib.suppress(WireError):
                reader(data)

    return one, (WireError,)


_IMPORT_ERRORS = "FormatError (a ValueError naming file, line and field)"
TARGETS: dict[str, Target] = {
    t.name: t
    for t in (
        Target(
            "exr",
            "what PUT /api/scenes/NAME runs on an upload: file_format, then (in the decode "
            "worker) the EXR, .hdr or PFM reader through ImageScene.open, OpenEXR's C++ "
            "library underneath",
            "SceneError (the route's 4xx)",
            _exr,
            max_len=8192,
        ),
        Target(
            "hid",
            "the HID report descriptor parser (hid-tools under our work-arounds) and the report "
            "decoders: Descriptor, TrackerReports, decode_feature, mode_request, gaze_sample",
            "DescriptorError, ReportError",
            _hid,
            instrument=("gazehdr", "hidtools"),
            max_len=1024,
        ),
        Target(
            "sessionlog",
            "the session log reader (read_session_log) and its fixation track (as replay uses it)",
            _IMPORT_ERRORS,
            _sessionlog,
            mutator="jsonl",
        ),
        Target(
            "eyelink",
            "the EyeLink ASC importer",
            _IMPORT_ERRORS,
            _importer("gazehdr.drivers.formats.eyelink", "read_eyelink_asc", ".asc"),
        ),
        Target(
            "tobii",
            "the Tobii TSV importer",
            _IMPORT_ERRORS,
            _tobii,
        ),
        Target(
            "pupil",
            "the Pupil Player gaze_positions.csv importer",
            _IMPORT_ERRORS,
            _importer("gazehdr.drivers.formats.pupil", "read_pupil_gaze_csv", ".csv"),
        ),
        Target(
            "bids",
            "the BIDS physio importer: sidecar JSON, physio and physioevents TSV (gzipped "
            "here), one run",
            _IMPORT_ERRORS,
            _bids,
        ),
        Target(
            "xdf",
            "the XDF importer (our structure check, then pyxdf)",
            _IMPORT_ERRORS,
            _importer("gazehdr.drivers.formats.xdf", "read_xdf", ".xdf"),
            instrument=("gazehdr", "pyxdf"),
        ),
        Target(
            "control",
            "the viewer's control messages on /ws/view (protocol.parse_control)",
            "ProtocolError",
            _control,
            mutator="json",
        ),
        Target(
            "wire",
            "the gaze wire messages on /ws/gaze (wire.parse, and the daemon's parse_reply)",
            "WireError",
            _wire,
            mutator="json",
        ),
    )
}
