"""Replay a recording as a gaze source: a native session log, or anything `formats` reads.

A native log replays in file order, which is the order the live source emitted its samples and
its detector emitted its events; an imported recording replays its samples and events merged in
time order (samples first at equal times). Speed is the recorded speed (1), a factor, or
`math.inf` (as fast as the reader takes them); pacing goes through an injectable clock and
sleep. A replay is not `live`: a reader that falls behind makes it wait, it loses nothing.

Replays are deterministic: the same file gives the same records, in the same order, however
fast it is read.

A replay also knows what a live stream cannot: where each fixation is before it ends.
`fixation_places()` gives it (`gazehdr.drivers.sessionlog.fixation_places`, the places
`SessionLog.fixation_track` holds), so that a consumer can place the fixation starts that
recorders such as EyeLink (`SFIX`) and BIDS physioevents leave without a position.

Where a recording's fixations have no position at all (BIDS physioevents rows without
`x_coordinate`) the daemon's detector runs on the samples, as `fixation_track` does; where it
finds no fixation either (samples too sparse for I-VT, as EEGEyeNet's 10 Hz data), each of the
recording's fixations gets the mean of the valid samples inside it (of its eye where the
samples have per-eye data; `places_at_samples`, which `fixation_track` follows too), so that a
replay still sends fixations and a render shows the same; one with no valid sample inside it
stays unplaced, and `unplaced` counts them.

An imported recording ends at its last valid sample: records more than `END_GAP_NS` after it
(an EyeLink END, messages long after the samples stop) are not replayed, and an invalid sample
ends the gaze, so that a replay does not hold the last gaze through the gap.

`open_replay` is the `replay:PATH[#ENTITIES][@SPEED]` stream of `gazehdr.drivers.registry`:
PATH a native log, any file `gazehdr import` reads, or a BIDS dataset, a `sub-*`/`ses-*`
folder in one or a physio file; `#sub-01_ses-1_run-2` picks the run where PATH holds several.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry, StreamRequest
from gazehdr.drivers.sessionlog import (
    FORMAT,
    FixationPlace,
    GazeEvent,
    Record,
    SessionHeader,
    SessionLog,
    SessionLogReader,
    decode_record,
    detected_fixations,
    fixation_places,
    places_at_samples,
    read_session_log,
    write_session_log,
)
from gazehdr.drivers.sources import Clock, Pacer, Sleep, SourceInfo

_EVENT_MARKERS = (b'"k":"fixation_', b'"k":"blink_')
#: How long after an imported recording's last valid sample its replay may go on.
END_GAP_NS = 1_000_000_000
_FIXATION_MARKER = b"fixation_"  # on every fixation event's line, on no sample's


def is_session_log(path: str | Path) -> bool:
    """Whether `path` starts with a native session log header."""
    try:
        with open(path, "rb") as f:
            first = f.readline(1 << 20)
        obj = json.loads(first.decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(obj, dict) and obj.get("format") == FORMAT


def _file_has_events(path: Path) -> bool:
    """A byte scan for event records (the writer's compact separators), without parsing."""
    tail = b""
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            block = tail + chunk
            if any(m in block for m in _EVENT_MARKERS):
                return True
            tail = block[-32:]
    return False


def _fixation_events(path: Path) -> Iterator[GazeEvent]:
    """A native log's fixation events, parsing only their lines (samples are most of a log).
    A line that does not parse is left to the replay, which reports it where it stands."""
    with open(path, "rb") as f:
        f.readline()  # the header
        for line, raw in enumerate(f, start=2):
            if _FIXATION_MARKER not in raw:
                continue
            try:
                record = decode_record(json.loads(raw), path, line)
            except ValueError:
                continue
            if isinstance(record, GazeEvent):
                yield record


def _info(header: SessionHeader, has_events: bool, where: str) -> SourceInfo:
    tracker = dict(header.tracker)
    name = str(tracker.get("name") or tracker.get("model") or "recording")
    rate = tracker.get("rate_hz")
    rate_hz = float(rate) if isinstance(rate, (int, float)) and rate > 0 else None
    return SourceInfo(
        name=f"{name} (replay of {where})",
        geometry=header.screen,
        rate_hz=rate_hz,
        live=False,
        has_events=has_events,
        tracker={**tracker, "replay_of": where},
    )


class ReplaySource:
    """A recording as a source: `records()` gives samples and events, iteration the samples.

    `recording` is a path (a native log, or any format `gazehdr.drivers.formats.import_recording`
    reads: `fmt` and `import_options` go to it) or a `SessionLog` already in memory.
    `include_all=True` also yields the log's scene, parameter, note and clock records.
    After a run, `truncated` says whether the log ended in a line cut short by a crash.
    """

    def __init__(
        self,
        recording: str | Path | SessionLog,
        *,
        speed: float = 1.0,
        clock: Clock | None = None,
        sleep: Sleep | None = None,
        fmt: str = "auto",
        include_all: bool = False,
        geometry: ScreenGeometry | None = None,
        **import_options: Any,
    ) -> None:
        Pacer(speed)  # validates the speed now rather than on the first record
        self.speed = speed
        self.clock, self.sleep = clock, sleep
        self.include_all = include_all
        self.truncated = False
        self._log: SessionLog | None = None
        self._path: Path | None = None
        self._places: dict[tuple[int, str | None], FixationPlace] | None = None
        self.unplaced = 0  # fixations neither their events nor their samples place
        if isinstance(recording, SessionLog):
            self._log = recording
            where = str(recording.path) if recording.path else "a recording"
            self.info = _info(recording.header, bool(recording.events), where)
            return
        path = Path(recording)
        if not path.exists():
            raise FileNotFoundError(2, "no such recording", str(path))
        if fmt in ("auto", "native") and path.is_file() and is_session_log(path):
            self._path = path
            with SessionLogReader(path) as reader:
                header = reader.header
            self.info = _info(header, _file_has_events(path), path.name)
            return
        from gazehdr.drivers.formats import import_recording

        if geometry is not None:
            import_options.setdefault("geometry", geometry)
        select = import_options.pop("select", None)
        if select:
            from gazehdr.drivers.formats import detect_format

            if (fmt if fmt != "auto" else detect_format(path)) != "bids":
                raise InputError(f"{path}: picking a run (#{select}) is for BIDS datasets")
            import_options["select"] = select
        self._log = import_recording(path, fmt, **import_options)
        self.info = _info(self._log.header, bool(self._log.events), path.name)

    @property
    def header(self) -> SessionHeader:
        if self._log is not None:
            return self._log.header
        assert self._path is not None
        with SessionLogReader(self._path) as reader:
            return reader.header

    def session_log(self) -> SessionLog:
        """The whole recording as a session log: the import, or a native log read whole (a
        replay reads it as it goes)."""
        if self._log is not None:
            return self._log
        assert self._path is not None
        return read_session_log(self._path)

    def fixation_places(self) -> dict[tuple[int, str | None], FixationPlace]:
        """Each recorded fixation's place, keyed by (id, eye) (see
        `gazehdr.drivers.sessionlog.fixation_places`); empty when no fixation event has a position.
        Read once: a native log is scanned for its fixation lines on the first call."""
        if self._places is None:
            if not self.info.has_events:
                self._places = {}
            elif self._log is not None:
                self._places = self._placed(self._log.events, lambda: self._log.samples)
            else:
                assert self._path is not None
                events = list(_fixation_events(self._path))
                self._places = self._placed(events, lambda: _samples_of(self._path))
        return self._places

    def _placed(
        self, events: list[GazeEvent], samples: Any
    ) -> dict[tuple[int, str | None], FixationPlace]:
        """`fixation_places`; where no event places a fixation and the daemon's detector finds
        none in the samples, the mean of their samples (`places_at_samples`). `samples()` is
        called only when some fixation needs it."""
        places = fixation_places(events)
        if places or not any(e.kind.startswith("fixation") for e in events):
            return places  # the events place fixations (those are sent), or there are none
        held = list(samples())
        if any(e.kind == "fixation_start" for e in detected_fixations(held, self.info.geometry)):
            return places  # the daemon's detector finds fixations in the samples: it runs
        places, self.unplaced = places_at_samples(events, held)
        return places

    def _unpaced(self) -> Iterator[Record]:
        if self._log is not None:
            yield from _until_gap(self._log)
            self.truncated = self._log.truncated
            return
        assert self._path is not None
        with SessionLogReader(self._path) as reader:
            yield from reader
            self.truncated = reader.truncated

    def records(self) -> Iterator[Record]:
        pacer = Pacer(self.speed, clock=self.clock, sleep=self.sleep)
        for record in self._unpaced():
            if not self.include_all and not isinstance(record, (GazeSample, GazeEvent)):
                continue
            pacer.wait(record.t_ns)
            yield record

    def __iter__(self) -> Iterator[GazeSample]:
        return (r for r in self.records() if isinstance(r, GazeSample))


def _samples_of(path: Path) -> Iterator[GazeSample]:
    """A native log's samples, streamed."""
    with SessionLogReader(path) as reader:
        yield from (r for r in reader if isinstance(r, GazeSample))


def _until_gap(log: SessionLog) -> Iterable[Record]:
    """The log's records up to `END_GAP_NS` after its last valid sample; when any are left out,
    an invalid sample just after the last one given ends the gaze."""
    last_valid = next((s.t_ns for s in reversed(log.samples) if s.valid), None)
    records = log.records()
    if last_valid is None:
        yield from records
        return
    cut = last_valid + END_GAP_NS
    last_sample: GazeSample | None = None
    for record in records:
        if record.t_ns > cut:
            if last_sample is not None and last_sample.valid:
                yield GazeSample(last_sample.t_ns + 1, math.nan, math.nan, False)
            return
        if isinstance(record, GazeSample):
            last_sample = record
        yield record


def replay(
    recording: str | Path | SessionLog,
    speed: float = math.inf,
    **options: Any,
) -> list[Record]:
    """Every record a replay emits, read as fast as possible unless `speed` says otherwise."""
    return list(ReplaySource(recording, speed=speed, **options).records())


def parse_speed(text: str) -> float:
    """`max` (as fast as possible), or a positive factor such as `2`, `0.5`, `x2`, `2x`."""
    t = text.strip().lower()
    if t in ("max", "inf", "fast"):
        return math.inf
    t = t.removeprefix("x").removeprefix("×").removesuffix("x")
    try:
        value = float(t)
    except ValueError:
        raise InputError(
            f"replay speed {text!r}: expected a factor such as 2 or 0.5, or max"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"replay speed {text!r}: must be positive and finite, or max")
    return value


def split_replay_spec(rest: str) -> tuple[str, float]:
    """`FILE[@SPEED]` → (FILE, speed); an `@` that is part of the file name stays in it."""
    if "@" in rest:
        name, _, speed = rest.rpartition("@")
        try:
            return name, parse_speed(speed)
        except ValueError:
            if Path(rest).exists():
                return rest, 1.0
            raise
    return rest, 1.0


_SELECTABLE = ("sub", "ses", "task", "acq", "run")


def split_run(path: str) -> tuple[str, dict[str, str]]:
    """`PATH[#sub-01_run-2]` → (PATH, {"sub": "01", "run": "2"}): which run of a BIDS dataset,
    as its files name it; a `#` that is part of an existing path stays in it."""
    if "#" not in path or Path(path).exists():
        return path, {}
    name, _, entities = path.rpartition("#")
    select = {}
    for part in entities.split("_"):
        key, sep, value = part.partition("-")
        if not sep or key not in _SELECTABLE or not value:
            raise InputError(
                f"replay run {entities!r}: expected entities such as sub-01_ses-1_run-2 "
                f"({', '.join(_SELECTABLE)})"
            )
        select[key] = value
    return name, select


def open_replay(request: StreamRequest) -> ReplaySource:
    """The `replay:PATH[#ENTITIES][@SPEED]` stream; the request's geometry (with its `screen`
    fields) fills in what an imported recording does not record."""
    if not request.arg:
        raise InputError("replay needs a file: replay:FILE[@SPEED]")
    path, speed = split_replay_spec(request.arg)
    path, select = split_run(path)
    options = dict(request.options)
    if select:
        options["select"] = select
    geometry = request.screen_geometry()
    if geometry is not None:
        options.setdefault("geometry", geometry)
    return ReplaySource(path, speed=speed, clock=request.clock, sleep=request.sleep, **options)


def library_recording(spec: str, folder: Path) -> str:
    """`serve --gaze replay:PATH[#RUN]`: the recording PATH names (a native log, anything
    `gazehdr import` reads, a BIDS dataset or a folder or file in one), kept in the server's
    recordings `folder` as a session log, and the name it is replayed by (`replay:NAME`).
    A NAME the folder has already is that recording. Its name is the source's (its stem, or
    the run's entities); a recording of that name with other contents is kept, and this one
    takes the next free `NAME-2`, `NAME-3`, ... (a source that changed between starts too)."""
    rest = spec.removeprefix("replay:")
    if not rest:
        raise InputError("replay needs a recording: replay:NAME or replay:PATH")
    path_text, select = split_run(rest)
    path = Path(path_text)
    if not select and (folder / f"{rest}.jsonl").is_file() and not path.exists():
        return rest
    if not path.exists():
        known = sorted(p.stem for p in folder.glob("*.jsonl")) if folder.is_dir() else []
        raise InputError(
            f"replay:{rest}: no such recording, neither a file or folder nor one of the "
            f"server's ({', '.join(known) or 'none'})"
        )
    log = ReplaySource(path, **({"select": select} if select else {})).session_log()
    name = (
        "_".join(f"{k}-{v}" for k, v in select.items())
        if select
        else (path.name.split(".", 1)[0] if path.is_file() else path.resolve().name)
    )
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", name).strip("._-")[:64] or "recording"
    folder.mkdir(parents=True, exist_ok=True)
    fresh = folder / f".{name}.importing"
    write_session_log(fresh, log, overwrite=True)
    for n in itertools.count(1):  # the same recording again, or the first free name
        candidate = name if n == 1 else f"{name}-{n}"
        kept = folder / f"{candidate}.jsonl"
        if not kept.exists():
            fresh.replace(kept)
            return candidate
        if kept.read_bytes() == fresh.read_bytes():
            fresh.unlink()
            return candidate
    raise AssertionError("unreachable")
