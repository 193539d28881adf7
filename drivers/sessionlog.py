"""The native session log: JSON Lines, append-only, readable after a crash up to the last line.

One JSON object per line, UTF-8, `\\n`-terminated. The writer writes each record with one
`write` and flushes it at once (and `os.fsync`s every `fsync_every` records if asked, and always
on close), so a crash loses at most the line being written; the reader reads everything up to
the last whole line and says that the file was cut (`SessionLog.truncated`). A line that is
malformed anywhere else is an error naming the file, the line and the field.

Line 1, the header::

    {"format": "gazehdr-session", "version": 2, "created": "2024-05-01T12:00:00.000+00:00",
     "tracker": {...free-form: name, model, serial, where it was imported from...},
     "screen": {"screen_diagonal_m": 0.6, "screen_width_px": 1920, "screen_height_px": 1080,
                "viewing_distance_m": 1.0},
     "clock": {"source": "monotonic_ns", "offset_ns": 0, "offset_uncertainty_ns": 250000}}

`screen` holds the `ScreenGeometry` fields. `clock.source` names the clock of every `t` below;
`offset_ns` (source clock + offset = server clock) and its uncertainty may be null when unknown,
and `clock` records later in the log give newer estimates.

Then records, each with its kind `k` and its time `t` (integer nanoseconds on the source clock):

- sample: `{"k":"s","t":T,"v":1,"x":X,"y":Y}` (screen pixels, origin top-left), or invalid
  (blink, lost track) `{"k":"s","t":T,"v":0}`; optional per-eye fields `"l"` and `"r"`:
  `[x, y]` or `[x, y, pupil_mm]`, or null for an eye the tracker lost. Sample times never go
  back.
- events, `k` one of `fixation_start`, `fixation_update`, `fixation_end`, `blink_start`,
  `blink_end`: `{"k":"fixation_end","id":7,"t":T,"x":X,"y":Y,"duration":NS,"dispersion":DEG}`;
  `x`, `y` (pixels), `duration` (ns), `dispersion` (degrees, Salvucci and Goldberg's
  (max x − min x) + (max y − min y)) and `eye` (`"left"`/`"right"`) are optional. The events of
  one fixation or blink share their `id` (the fields of `gazehdr.drivers.fixations.Event`).
- `{"k":"scene","t":T,"name":"lamp"}`, `{"k":"params","t":T,"values":{...}}` (the parameters
  that changed, by their `gazehdr.sim.Params` names), `{"k":"model","t":T,"model":"jacobs+
  stochastic","split":null}` (the simulation's models, `AFTERIMAGE+ACUITY`, and the right
  pane's in split view or null), `{"k":"reset","t":T}` (the eye put back to equilibrium),
  `{"k":"note","t":T,"text":"..."}` and `{"k":"clock","t":T,"offset_ns":N,
  "offset_uncertainty_ns":N}`.

A server recording a viewing session (`gazehdr serve --record`) writes times on the session's
simulation clock (`clock.source` "simulation_ns"), each change and gaze at the end of the first
step it drove, and the gaze it followed as samples plus one `fixation_start` per position.

Unknown kinds and unknown fields are errors: a reader never guesses what a newer version meant
(it bumps `version`). Version 2 added `model` and `reset`; this reader reads 1 and 2.

`SessionLog.fixation_track()` is the log as a `GazeTrack` (normalised coordinates, seconds since
the first sample) that follows its fixations, not its samples (SPEC §4): `gazehdr render SCENE
--gaze session.jsonl` (through `read_session_track`) and a live session replaying the log show
the same gaze. `SessionLog.track()` is the raw samples on the same time line.
"""

from __future__ import annotations

import bisect
import errno
import heapq
import json
import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

from gazehdr.drivers.samples import EyeSample, GazePoint, GazeSample, ScreenGeometry

FORMAT = "gazehdr-session"
VERSION = 2
READS = (1, 2)  # versions this reader understands
EVENT_KINDS: tuple[str, ...] = (
    "fixation_start",
    "fixation_update",
    "fixation_end",
    "blink_start",
    "blink_end",
)
EYES = ("left", "right")
_SCREEN_FIELDS = tuple(f.name for f in fields(ScreenGeometry))


class FormatError(ValueError):
    """A file that does not follow its format; the message names file, line and field."""

    def __init__(
        self, path: str | Path, line: int | None, field_name: str | None, reason: str
    ) -> None:
        self.path = str(path)
        self.line = line
        self.field = field_name
        self.reason = reason
        where = self.path if line is None else f"{self.path}:{line}"
        what = f"field '{field_name}': " if field_name else ""
        super().__init__(f"{where}: {what}{reason}")


# --- records ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockInfo:
    """What the log's times are: the source clock, and its offset to the server clock."""

    source: str = "monotonic_ns"
    offset_ns: int | None = None
    offset_uncertainty_ns: int | None = None


@dataclass(frozen=True)
class SessionHeader:
    """Line 1 of a log: tracker description, screen geometry, clock."""

    tracker: dict[str, Any] = field(default_factory=dict)
    screen: ScreenGeometry = field(default_factory=ScreenGeometry)
    clock: ClockInfo = field(default_factory=ClockInfo)
    created: str = field(
        default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    )
    version: int = VERSION

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": self.version,
            "created": self.created,
            "tracker": self.tracker,
            "screen": asdict(self.screen),
            "clock": asdict(self.clock),
        }


@dataclass(frozen=True)
class GazeEvent:
    """A fixation or blink event, as `gazehdr.drivers.fixations.Event` plus the eye it came from.

    Unknown positions are NaN (blinks have none; an EyeLink fixation start has none either).
    """

    kind: str
    id: int
    t_ns: int
    x: float = math.nan
    y: float = math.nan
    duration_ns: int | None = None
    dispersion_deg: float | None = None
    eye: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ValueError(f"event kind {self.kind!r}; known: {', '.join(EVENT_KINDS)}")
        if self.eye is not None and self.eye not in EYES:
            raise ValueError(f"event eye {self.eye!r}; known: left, right")


@dataclass(frozen=True)
class SceneChange:
    t_ns: int
    name: str


@dataclass(frozen=True)
class ParamsChange:
    t_ns: int
    values: dict[str, Any]


@dataclass(frozen=True)
class ModelChange:
    """The models from `t` on, as `AFTERIMAGE+ACUITY` names (`gazehdr.sim.models` checks them)."""

    t_ns: int
    model: str
    split: str | None = None


@dataclass(frozen=True)
class EyeReset:
    t_ns: int


@dataclass(frozen=True)
class Note:
    t_ns: int
    text: str


@dataclass(frozen=True)
class ClockUpdate:
    t_ns: int
    offset_ns: int | None
    offset_uncertainty_ns: int | None = None


Record = (
    GazeSample
    | GazeEvent
    | SceneChange
    | ParamsChange
    | ModelChange
    | EyeReset
    | Note
    | ClockUpdate
)


def _finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


def _eye_json(eye: EyeSample | None) -> list[float] | None:
    if eye is None or not (_finite(eye.x) and _finite(eye.y)):
        return None
    if _finite(eye.pupil_mm):
        return [eye.x, eye.y, eye.pupil_mm]
    return [eye.x, eye.y]


def encode_record(record: Any) -> dict[str, Any]:
    """A record as its JSON object. Events may be any object with `Event`'s attributes."""
    if isinstance(record, GazeSample):
        obj: dict[str, Any] = {"k": "s", "t": int(record.t_ns)}
        if record.valid:
            obj |= {"v": 1, "x": float(record.x), "y": float(record.y)}
        else:
            obj["v"] = 0
        if record.left is not None:
            obj["l"] = _eye_json(record.left)
        if record.right is not None:
            obj["r"] = _eye_json(record.right)
        return obj
    if isinstance(record, SceneChange):
        return {"k": "scene", "t": int(record.t_ns), "name": record.name}
    if isinstance(record, ParamsChange):
        return {"k": "params", "t": int(record.t_ns), "values": record.values}
    if isinstance(record, ModelChange):
        return {"k": "model", "t": int(record.t_ns), "model": record.model, "split": record.split}
    if isinstance(record, EyeReset):
        return {"k": "reset", "t": int(record.t_ns)}
    if isinstance(record, Note):
        return {"k": "note", "t": int(record.t_ns), "text": record.text}
    if isinstance(record, ClockUpdate):
        return {
            "k": "clock",
            "t": int(record.t_ns),
            "offset_ns": record.offset_ns,
            "offset_uncertainty_ns": record.offset_uncertainty_ns,
        }
    kind = getattr(record, "kind", None)
    if kind in EVENT_KINDS:
        obj = {"k": kind, "id": int(record.id), "t": int(record.t_ns)}
        if _finite(record.x) and _finite(record.y):
            obj |= {"x": float(record.x), "y": float(record.y)}
        if getattr(record, "duration_ns", None) is not None:
            obj["duration"] = int(record.duration_ns)
        if _finite(getattr(record, "dispersion_deg", None)):
            obj["dispersion"] = float(record.dispersion_deg)
        if getattr(record, "eye", None) is not None:
            obj["eye"] = record.eye
        return obj
    raise TypeError(f"not a session log record: {record!r}")


# --- decoding, with errors that name the field ------------------------------------------------


class _Fields:
    """Typed access to one JSON record; every complaint names file, line and field."""

    def __init__(self, obj: dict[str, Any], path: Path, line: int) -> None:
        self.obj, self.path, self.line = obj, path, line

    def error(self, name: str | None, reason: str) -> FormatError:
        return FormatError(self.path, self.line, name, reason)

    def only(self, allowed: Iterable[str]) -> None:
        extra = sorted(set(self.obj) - set(allowed))
        if extra:
            raise self.error(extra[0], f"unknown field in a '{self.obj['k']}' record")

    def integer(
        self, name: str, *, optional: bool = False, minimum: int | None = None
    ) -> int | None:
        value = self.obj.get(name)
        if value is None:
            if optional:
                return None
            raise self.error(name, "missing (an integer is required)")
        if not isinstance(value, int) or isinstance(value, bool):
            raise self.error(name, f"must be an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(name, f"must be at least {minimum}, got {value}")
        return value

    def number(self, name: str, *, optional: bool = False) -> float | None:
        value = self.obj.get(name)
        if value is None:
            if optional:
                return None
            raise self.error(name, "missing (a number is required)")
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise self.error(name, f"must be a number, got {value!r}")
        return float(value)

    def text(self, name: str) -> str:
        value = self.obj.get(name)
        if not isinstance(value, str):
            raise self.error(name, f"must be a string, got {value!r}")
        return value

    def eye(self, name: str) -> EyeSample | None:
        if name not in self.obj:
            return None
        value = self.obj[name]
        if value is None:
            return EyeSample(math.nan, math.nan)
        if (
            not isinstance(value, list)
            or len(value) not in (2, 3)
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        ):
            raise self.error(name, f"must be [x, y], [x, y, pupil_mm] or null, got {value!r}")
        return EyeSample(float(value[0]), float(value[1]), float(value[2]) if value[2:] else None)


_SAMPLE_KEYS = ("k", "t", "v", "x", "y", "l", "r")
_EVENT_KEYS = ("k", "id", "t", "x", "y", "duration", "dispersion", "eye")


def decode_record(obj: Any, path: Path, line: int) -> Record:
    """One parsed JSON line → a record, or `FormatError` naming the field."""
    if not isinstance(obj, dict):
        raise FormatError(path, line, None, "a record is a JSON object")
    f = _Fields(obj, path, line)
    kind = obj.get("k")
    if not isinstance(kind, str):
        raise f.error("k", f"missing or not a string: {kind!r}")
    if kind == "s":
        f.only(_SAMPLE_KEYS)
        t = f.integer("t")
        valid = obj.get("v")
        if valid not in (0, 1) or isinstance(valid, bool):
            raise f.error("v", f"must be 1 (valid) or 0 (invalid), got {valid!r}")
        left, right = f.eye("l"), f.eye("r")
        if valid:
            return GazeSample(t, f.number("x"), f.number("y"), True, left, right)
        if "x" in obj or "y" in obj:
            raise f.error("x" if "x" in obj else "y", "an invalid sample (v = 0) has no position")
        return GazeSample(t, math.nan, math.nan, False, left, right)
    if kind in EVENT_KINDS:
        f.only(_EVENT_KEYS)
        if ("x" in obj) != ("y" in obj):
            raise f.error("y" if "x" in obj else "x", "an event has both x and y or neither")
        x, y = f.number("x", optional=True), f.number("y", optional=True)
        eye = obj.get("eye")
        if eye is not None and eye not in EYES:
            raise f.error("eye", f"must be 'left' or 'right', got {eye!r}")
        dispersion = f.number("dispersion", optional=True)
        if dispersion is not None and dispersion < 0:
            raise f.error("dispersion", f"must not be negative, got {dispersion}")
        return GazeEvent(
            kind,
            f.integer("id", minimum=0),
            f.integer("t"),
            math.nan if x is None else x,
            math.nan if y is None else y,
            f.integer("duration", optional=True, minimum=0),
            dispersion,
            eye,
        )
    if kind == "scene":
        f.only(("k", "t", "name"))
        return SceneChange(f.integer("t"), f.text("name"))
    if kind == "params":
        f.only(("k", "t", "values"))
        values = obj.get("values")
        if not isinstance(values, dict):
            raise f.error("values", f"must be an object, got {values!r}")
        return ParamsChange(f.integer("t"), values)
    if kind == "model":
        f.only(("k", "t", "model", "split"))
        split = None if obj.get("split") is None else f.text("split")
        return ModelChange(f.integer("t"), f.text("model"), split)
    if kind == "reset":
        f.only(("k", "t"))
        return EyeReset(f.integer("t"))
    if kind == "note":
        f.only(("k", "t", "text"))
        return Note(f.integer("t"), f.text("text"))
    if kind == "clock":
        f.only(("k", "t", "offset_ns", "offset_uncertainty_ns"))
        return ClockUpdate(
            f.integer("t"),
            f.integer("offset_ns", optional=True),
            f.integer("offset_uncertainty_ns", optional=True, minimum=0),
        )
    known = ", ".join(("s", *EVENT_KINDS, "scene", "params", "model", "reset", "note", "clock"))
    raise f.error("k", f"unknown record kind {kind!r}; known: {known}")


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


def decode_header(obj: Any, path: Path) -> SessionHeader:
    """Line 1 → the header, or `FormatError` naming the field."""
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise FormatError(path, 1, "format", f"not a gazehdr session log (expected '{FORMAT}')")
    f = _Fields({"k": "header", **obj}, path, 1)
    f.only(("k", "format", "version", "created", "tracker", "screen", "clock"))
    version = obj.get("version")
    if version not in READS or isinstance(version, bool):
        readable = " and ".join(map(str, READS))
        raise f.error("version", f"version {version!r}; this reader reads versions {readable}")
    created = f.text("created")
    tracker = obj.get("tracker")
    if not isinstance(tracker, dict):
        raise f.error("tracker", f"must be an object, got {tracker!r}")
    screen = obj.get("screen")
    if not isinstance(screen, dict) or set(screen) != set(_SCREEN_FIELDS):
        raise f.error("screen", f"must be an object with exactly {', '.join(_SCREEN_FIELDS)}")
    try:
        geometry = ScreenGeometry(**screen)
    except (TypeError, ValueError) as e:
        raise f.error("screen", str(e)) from None
    clock = obj.get("clock")
    if not isinstance(clock, dict):
        raise f.error("clock", f"must be an object, got {clock!r}")
    c = _Fields({"k": "clock", **clock}, path, 1)
    c.only(("k", "source", "offset_ns", "offset_uncertainty_ns"))
    try:
        info = ClockInfo(
            c.text("source"),
            c.integer("offset_ns", optional=True),
            c.integer("offset_uncertainty_ns", optional=True, minimum=0),
        )
    except FormatError as e:
        raise f.error(f"clock.{e.field}", e.reason) from None
    return SessionHeader(tracker, geometry, info, created, version)


# --- writing ----------------------------------------------------------------------------------


def _dumps(obj: dict[str, Any]) -> str:
    return json.dumps(obj, ensure_ascii=False, separators=(",", ":"), allow_nan=False)


class SessionLogWriter:
    """Appends records to a new log, one flushed line each; a context manager.

    Refuses to replace an existing file unless `overwrite=True`. `fsync_every=N` also forces
    the data to disk every N records (a flush alone survives a crash of this process, not of
    the machine); `close()` always fsyncs. Sample times must not go back.
    """

    def __init__(
        self,
        path: str | Path,
        header: SessionHeader,
        *,
        overwrite: bool = False,
        fsync_every: int | None = None,
    ) -> None:
        if fsync_every is not None and fsync_every < 1:
            raise ValueError(f"fsync_every must be a positive number of records, got {fsync_every}")
        self.path = Path(path)
        self.header = header
        self.fsync_every = fsync_every
        self.records_written = 0
        self._last_sample_ns: int | None = None
        try:
            self._file = open(  # noqa: SIM115 - closed by close()
                self.path, "w" if overwrite else "x", encoding="utf-8", newline="\n"
            )
        except FileExistsError:
            raise FileExistsError(
                errno.EEXIST,
                "session log already exists (choose another name, or overwrite it on purpose)",
                str(self.path),
            ) from None
        self._line(header.to_json())
        self._sync()

    def __enter__(self) -> SessionLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._file.closed

    def _line(self, obj: dict[str, Any]) -> None:
        self._file.write(_dumps(obj) + "\n")
        self._file.flush()

    def _sync(self) -> None:
        os.fsync(self._file.fileno())

    def write(self, record: Any) -> None:
        """Append one record (a `GazeSample`, an event, `SceneChange`, `ParamsChange`, ...)."""
        if self._file.closed:
            raise ValueError(f"{self.path}: session log is closed")
        obj = encode_record(record)
        if obj["k"] == "s":
            if self._last_sample_ns is not None and obj["t"] < self._last_sample_ns:
                raise ValueError(
                    f"{self.path}: sample time {obj['t']} goes back from {self._last_sample_ns}"
                )
            self._last_sample_ns = obj["t"]
        self._line(obj)
        self.records_written += 1
        if self.fsync_every and self.records_written % self.fsync_every == 0:
            self._sync()

    def write_all(self, records: Iterable[Any]) -> None:
        for record in records:
            self.write(record)

    def scene(self, t_ns: int, name: str) -> None:
        self.write(SceneChange(t_ns, name))

    def params(self, t_ns: int, values: dict[str, Any]) -> None:
        self.write(ParamsChange(t_ns, values))

    def note(self, t_ns: int, text: str) -> None:
        self.write(Note(t_ns, text))

    def clock(self, t_ns: int, offset_ns: int | None, uncertainty_ns: int | None = None) -> None:
        self.write(ClockUpdate(t_ns, offset_ns, uncertainty_ns))

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._file.flush()
            self._sync()
        finally:
            self._file.close()


# --- reading ----------------------------------------------------------------------------------


class SessionLogReader:
    """Streams a log's records in file order (what the live source emitted, in that order).

    `header` is read on opening. Iterating stops cleanly at a final line cut short by a crash
    (no newline, or the NUL bytes a file system may leave after a crash) and sets `truncated`
    and `truncated_line`; a malformed line anywhere else raises `FormatError`.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.truncated = False
        self.truncated_line: int | None = None
        self._file: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        try:
            raw = self._file.readline()
            if not raw.strip(b"\x00 \t\r\n"):
                raise FormatError(self.path, 1, None, "empty file: no session log header")
            try:
                obj = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
            except (UnicodeDecodeError, ValueError) as e:
                cut = "" if raw.endswith(b"\n") else " (cut short: nothing was recorded)"
                raise FormatError(self.path, 1, None, f"header is not JSON{cut}: {e}") from None
            self.header = decode_header(obj, self.path)
        except BaseException:
            self._file.close()
            raise

    def __enter__(self) -> SessionLogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._file.close()

    def __iter__(self) -> Iterator[Record]:
        last_sample: int | None = None
        line = 1
        for raw in self._file:
            line += 1
            if not raw.strip(b" \t\r\n"):
                continue
            try:
                obj = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
            except (UnicodeDecodeError, ValueError) as e:
                rest = self._file.read()
                cut = not raw.endswith(b"\n") or b"\x00" in raw
                if cut and not rest.strip(b"\x00 \t\r\n"):
                    self.truncated, self.truncated_line = True, line
                    return
                raise FormatError(self.path, line, None, f"not a JSON record: {e}") from None
            record = decode_record(obj, self.path, line)
            if isinstance(record, GazeSample):
                if last_sample is not None and record.t_ns < last_sample:
                    raise FormatError(
                        self.path,
                        line,
                        "t",
                        f"sample time {record.t_ns} goes back from {last_sample}",
                    )
                last_sample = record.t_ns
            yield record


@dataclass
class SessionLog:
    """A whole log in memory: the header and its records by kind, each list in time order."""

    header: SessionHeader
    samples: list[GazeSample] = field(default_factory=list)
    events: list[GazeEvent] = field(default_factory=list)
    scenes: list[SceneChange] = field(default_factory=list)
    params: list[ParamsChange] = field(default_factory=list)
    models: list[ModelChange] = field(default_factory=list)
    resets: list[EyeReset] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)
    clocks: list[ClockUpdate] = field(default_factory=list)
    truncated: bool = False
    truncated_line: int | None = None
    path: Path | None = None

    def add(self, record: Record) -> None:
        """Append a record to the list of its kind."""
        if isinstance(record, GazeSample):
            self.samples.append(record)
        elif isinstance(record, SceneChange):
            self.scenes.append(record)
        elif isinstance(record, ParamsChange):
            self.params.append(record)
        elif isinstance(record, ModelChange):
            self.models.append(record)
        elif isinstance(record, EyeReset):
            self.resets.append(record)
        elif isinstance(record, Note):
            self.notes.append(record)
        elif isinstance(record, ClockUpdate):
            self.clocks.append(record)
        elif isinstance(record, GazeEvent):
            self.events.append(record)
        else:
            raise TypeError(f"not a session log record: {record!r}")

    def records(self) -> Iterator[Record]:
        """Every record, merged in time order (samples first at equal times)."""
        lists = (
            self.samples, self.events, self.scenes, self.params, self.models, self.resets,
            self.notes, self.clocks,
        )  # fmt: skip

        def keyed(rank: int, items: list[Any]) -> Iterator[tuple[int, int, int, Any]]:
            return ((r.t_ns, rank, i, r) for i, r in enumerate(items))

        for *_, record in heapq.merge(*(keyed(rank, rs) for rank, rs in enumerate(lists))):
            yield record

    def blinks(self) -> list[tuple[int, float]]:
        """Blink intervals `[start, end)` in source ns; an unfinished blink ends at +inf."""
        starts: dict[tuple[int, str | None], int] = {}
        intervals: list[tuple[int, float]] = []
        for e in sorted(self.events, key=lambda e: e.t_ns):
            key = (e.id, e.eye)
            if e.kind == "blink_start":
                starts[key] = e.t_ns
            elif e.kind == "blink_end":
                start = starts.pop(key, None)
                if start is None and e.duration_ns is not None:
                    start = e.t_ns - e.duration_ns
                if start is not None:
                    intervals.append((start, e.t_ns))
        intervals += [(start, math.inf) for start in starts.values()]
        return sorted(intervals)

    def track(self) -> SessionTrack:
        return SessionTrack(self.samples, self.blinks(), self.header.screen)

    def fixation_track(self) -> SessionTrack:
        """The gaze as the log's fixations: each fixation's mean position from its start until
        the next one starts, so a saccade never sweeps the simulated retina (SPEC §4). A log
        whose events place no fixation (none, only blinks, or fixations without positions) is
        run through I-VT first, as a daemon replaying it does; one where I-VT finds none falls
        back to the samples. Its time line is `track()`'s: from the first sample to the last."""
        events = self.events
        points = _fixation_points(events)
        if not points:
            from gazehdr.drivers.fixations import detect  # only logs that place no fixation need it

            found = detect(self.samples, "ivt", self.header.screen)
            events = [
                GazeEvent(e.kind, e.id, e.t_ns, e.x, e.y, e.duration_ns, e.dispersion_deg)
                for e in found
            ]
            points = _fixation_points(events)
        if not points:
            return self.track()
        held = [GazeSample(int(t), x, y) for t, x, y in points]
        span = (held[0].t_ns, held[-1].t_ns)
        if self.samples:
            span = (min(span[0], self.samples[0].t_ns), max(span[1], self.samples[-1].t_ns))
        blinks = self.blinks() or _blinks_of(events)
        return SessionTrack(held, blinks, self.header.screen, span_ns=span)


def _fixation_points(events: list[GazeEvent]) -> list[FixationPlace]:
    """The placed fixations of one eye (the first that fixates), in time order."""
    eye = next((e.eye for e in events if e.kind.startswith("fixation")), None)
    places = fixation_places(e for e in events if e.eye == eye)
    return sorted(p for p in places.values() if p.start_ns is not None)


class FixationPlace(NamedTuple):
    """Where a recorded fixation was, and when it began (None: its events do not say)."""

    start_ns: int | None
    x: float
    y: float


def fixation_places(events: Iterable[GazeEvent]) -> dict[tuple[int, str | None], FixationPlace]:
    """Each fixation of `events`, keyed by (id, eye): its start (its `fixation_start`'s time,
    else its end's less its duration) and its position, that of its last event with one (later
    events know more: the end's mean wins). Recorders such as EyeLink (`SFIX`) and BIDS
    physioevents (an onset) give a fixation's start no position; this is where it was. A
    fixation none of whose events has a position is left out. `fixation_track` holds these
    places; a daemon replaying a recording sends them (`gazehdr.drivers.replay`)."""
    found: dict[tuple[int, str | None], dict[str, Any]] = {}
    for e in sorted(events, key=lambda e: e.t_ns):
        if not e.kind.startswith("fixation"):
            continue
        f = found.setdefault((e.id, e.eye), {})
        if e.kind == "fixation_start":
            f.setdefault("t", e.t_ns)
        elif e.kind == "fixation_end" and e.duration_ns is not None:
            f.setdefault("t", e.t_ns - e.duration_ns)
        if _finite(e.x) and _finite(e.y):
            f["x"], f["y"] = e.x, e.y
    return {k: FixationPlace(f.get("t"), f["x"], f["y"]) for k, f in found.items() if "x" in f}


def _blinks_of(events: list[GazeEvent]) -> list[tuple[int, float]]:
    return SessionLog(SessionHeader(), events=list(events)).blinks()


def read_session_log(path: str | Path) -> SessionLog:
    """Read a whole log; stops cleanly at a cut final line (`truncated` says so)."""
    with SessionLogReader(path) as reader:
        log = SessionLog(reader.header, path=reader.path)
        for record in reader:
            log.add(record)
        log.truncated, log.truncated_line = reader.truncated, reader.truncated_line
    for items in (
        log.events,
        log.scenes,
        log.params,
        log.models,
        log.resets,
        log.notes,
        log.clocks,
    ):
        items.sort(key=lambda r: r.t_ns)
    return log


def write_session_log(path: str | Path, log: SessionLog, *, overwrite: bool = False) -> Path:
    """Write a log held in memory (an import, say), its records in time order."""
    with SessionLogWriter(path, log.header, overwrite=overwrite) as writer:
        writer.write_all(log.records())
    return Path(path)


# --- replay as a gaze track -------------------------------------------------------------------


class SessionTrack:
    """A log's samples as a `GazeTrack`: normalised coordinates, seconds since the first sample.

    Step interpolation: each sample holds until the next; before the first sample the track shows
    the first, after the last the last. The eyes are closed at an invalid sample and inside
    blink intervals; an invalid sample keeps the last valid position (the first valid one before
    any), so the eye does not jump to a made-up place. A pure function of `t`.

    `span_ns` (first, last) sets the time line, t = 0 at first and `duration` up to last
    (default: the first and last sample's times).
    """

    def __init__(
        self,
        samples: list[GazeSample],
        blinks: list[tuple[int, float]],
        screen: ScreenGeometry,
        *,
        span_ns: tuple[int, int] | None = None,
    ) -> None:
        if not samples:
            raise ValueError("a session log with no samples has no gaze track")
        first, last = span_ns or (samples[0].t_ns, samples[-1].t_ns)
        self.t0_ns = first
        self.duration = (last - first) / 1e9
        self._times = [s.t_ns - self.t0_ns for s in samples]
        width, height = screen.screen_width_px, screen.screen_height_px
        first = next((s for s in samples if s.valid), None)
        x, y = (first.x / width, first.y / height) if first else (0.5, 0.5)
        self._points: list[GazePoint] = []
        for s in samples:
            if s.valid:
                x, y = s.x / width, s.y / height
            self._points.append(GazePoint(x, y, s.valid))
        merged: list[list[float]] = []
        for start, end in sorted(blinks):
            start_rel, end_rel = start - self.t0_ns, end - self.t0_ns
            if merged and start_rel <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], end_rel)
            else:
                merged.append([start_rel, end_rel])
        self._blink_starts = [b[0] for b in merged]
        self._blink_ends = [b[1] for b in merged]

    def _in_blink(self, t_rel_ns: float) -> bool:
        i = bisect.bisect_right(self._blink_starts, t_rel_ns) - 1
        return i >= 0 and t_rel_ns < self._blink_ends[i]

    def at(self, t: float) -> GazePoint:
        if not math.isfinite(t):
            raise ValueError(f"gaze time must be finite, got {t}")
        q = round(t * 1e9)  # log times are integer ns
        point = self._points[max(bisect.bisect_right(self._times, q) - 1, 0)]
        if point.eyes_open and self._in_blink(q):
            return GazePoint(point.x, point.y, False)
        return point


def read_session_track(path: Path) -> SessionTrack:
    """A session log as a gaze track (`LOG.jsonl` in `gazehdr.drivers.registry`): the log's
    fixations, as a live session replaying it follows them."""
    return read_session_log(path).fixation_track()


__all__ = [
    "EVENT_KINDS",
    "FORMAT",
    "READS",
    "VERSION",
    "ClockInfo",
    "ClockUpdate",
    "EyeReset",
    "FixationPlace",
    "FormatError",
    "GazeEvent",
    "ModelChange",
    "Note",
    "ParamsChange",
    "Record",
    "SceneChange",
    "SessionHeader",
    "SessionLog",
    "SessionLogReader",
    "SessionLogWriter",
    "SessionTrack",
    "decode_record",
    "encode_record",
    "fixation_places",
    "read_session_log",
    "read_session_track",
    "write_session_log",
]
