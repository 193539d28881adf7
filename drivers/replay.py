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

`open_replay` is the `replay:FILE[@SPEED]` stream of `gazehdr.drivers.registry`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
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
    fixation_places,
)
from gazehdr.drivers.sources import Clock, Pacer, Sleep, SourceInfo

_EVENT_MARKERS = (b'"k":"fixation_', b'"k":"blink_')
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
        if isinstance(recording, SessionLog):
            self._log = recording
            where = str(recording.path) if recording.path else "a recording"
            self.info = _info(recording.header, bool(recording.events), where)
            return
        path = Path(recording)
        if not path.is_file():
            raise FileNotFoundError(2, "no such recording", str(path))
        if fmt in ("auto", "native") and is_session_log(path):
            self._path = path
            with SessionLogReader(path) as reader:
                header = reader.header
            self.info = _info(header, _file_has_events(path), path.name)
            return
        from gazehdr.drivers.formats import import_recording

        if geometry is not None:
            import_options.setdefault("geometry", geometry)
        self._log = import_recording(path, fmt, **import_options)
        self.info = _info(self._log.header, bool(self._log.events), path.name)

    @property
    def header(self) -> SessionHeader:
        if self._log is not None:
            return self._log.header
        assert self._path is not None
        with SessionLogReader(self._path) as reader:
            return reader.header

    def fixation_places(self) -> dict[tuple[int, str | None], FixationPlace]:
        """Each recorded fixation's place, keyed by (id, eye) (see
        `gazehdr.drivers.sessionlog.fixation_places`); empty when no fixation event has a position.
        Read once: a native log is scanned for its fixation lines on the first call."""
        if self._places is None:
            if not self.info.has_events:
                self._places = {}
            elif self._log is not None:
                self._places = fixation_places(self._log.events)
            else:
                assert self._path is not None
                self._places = fixation_places(_fixation_events(self._path))
        return self._places

    def _unpaced(self) -> Iterator[Record]:
        if self._log is not None:
            yield from self._log.records()
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


def open_replay(request: StreamRequest) -> ReplaySource:
    """The `replay:FILE[@SPEED]` stream; the request's geometry (with its `screen` fields) fills
    in what an imported recording does not record."""
    if not request.arg:
        raise InputError("replay needs a file: replay:FILE[@SPEED]")
    path, speed = split_replay_spec(request.arg)
    options = dict(request.options)
    geometry = request.screen_geometry()
    if geometry is not None:
        options.setdefault("geometry", geometry)
    return ReplaySource(path, speed=speed, clock=request.clock, sleep=request.sleep, **options)
