"""A record ↔ its JSON object: the file format, line by line, and decoding that names the field.

A log is JSON Lines: one JSON object per line, UTF-8, `\\n`-terminated (how it is written and
read back after a crash: `writer` and `reader`).

Line 1, the header::

    {"format": "gazehdr-session", "version": 3, "created": "2024-05-01T12:00:00.000+00:00",
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
  `[x, y]`, `[x, y, pupil_mm]` or `[x, y, pupil_mm, pupil_au]` (the pupil in the tracker's own
  arbitrary units, as EyeLink's area or diameter; `pupil_mm` null where it has none), or null
  for an eye the tracker lost. Sample times never go back.
- events, `k` one of `fixation_start`, `fixation_update`, `fixation_end`, `blink_start`,
  `blink_end`, `saccade_start`, `saccade_end`: `{"k":"fixation_end","id":7,"t":T,"x":X,"y":Y,
  "duration":NS,"dispersion":DEG}`; `x`, `y` (pixels), `duration` (ns), `dispersion` (degrees,
  Salvucci and Goldberg's (max x − min x) + (max y − min y)) and `eye` (`"left"`/`"right"`) are
  optional. The events of one fixation, blink or saccade share their `id` (the fields of
  `gazehdr.drivers.fixations.Event`). Saccades come from imported recordings (a saccade's start
  holds where it began, its end where it landed); a daemon does not send them.
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
(it bumps `version`). Version 2 added `model` and `reset`, version 3 `saccade_start`,
`saccade_end` and an eye's `pupil_au`; this reader reads 1, 2 and 3.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import fields
from pathlib import Path
from typing import Any

from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog.records import (
    EVENT_KINDS,
    EYES,
    FORMAT,
    READS,
    ClockInfo,
    ClockUpdate,
    EyeReset,
    FormatError,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    Record,
    SceneChange,
    SessionHeader,
    _finite,
)

_SCREEN_FIELDS = tuple(f.name for f in fields(ScreenGeometry))


def _eye_json(eye: EyeSample | None) -> list[float | None] | None:
    if eye is None or not (_finite(eye.x) and _finite(eye.y)):
        return None
    mm = eye.pupil_mm if _finite(eye.pupil_mm) else None
    if _finite(eye.pupil_au):
        return [eye.x, eye.y, mm, eye.pupil_au]
    return [eye.x, eye.y] if mm is None else [eye.x, eye.y, mm]


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


_INT64 = 1 << 63


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
        if not -_INT64 <= value < _INT64:  # times in ns: ±292 years; json reads any integer
            shown = value if abs(value) < 10**30 else f"an integer of {len(str(value))} digits"
            raise self.error(name, f"must fit in 64 bits (a signed integer), got {shown}")
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
        return self.as_float(name, value)

    def as_float(self, name: str, value: int | float) -> float:
        """A JSON number as a float; an integer too large for one (json reads any) is refused."""
        try:
            return float(value)
        except OverflowError:
            raise self.error(name, f"an integer of {len(str(value))} digits is too large") from None

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
            or len(value) not in (2, 3, 4)
            or not all(
                (isinstance(v, (int, float)) and not isinstance(v, bool))
                or (v is None and i == 2 and len(value) == 4)  # no pupil_mm, a pupil_au
                for i, v in enumerate(value)
            )
        ):
            raise self.error(
                name,
                f"must be [x, y], [x, y, pupil_mm], [x, y, pupil_mm or null, pupil_au] or null, "
                f"got {value!r}",
            )
        x, y, *pupils = (None if v is None else self.as_float(name, v) for v in value)
        assert x is not None and y is not None
        return EyeSample(x, y, *pupils)


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


def decode_header(obj: Any, path: Path) -> SessionHeader:
    """Line 1 → the header, or `FormatError` naming the field."""
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise FormatError(path, 1, "format", f"not a gazehdr session log (expected '{FORMAT}')")
    f = _Fields({"k": "header", **obj}, path, 1)
    f.only(("k", "format", "version", "created", "tracker", "screen", "clock"))
    version = obj.get("version")
    if version not in READS or isinstance(version, bool):
        readable = ", ".join(map(str, READS))
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
