"""Every kind of gaze source in one table, and the two ways of opening one.

A kind opens as a *stream* (`open_source`: samples as a tracker produces them, for the daemon)
or as a *track* (`open_track`: the gaze at any time t, for offline rendering and for sessions on
the server), or as both. Each `SourceKind` in `KINDS` says, for each way it opens, the spec users
write, a line of help, and where its code lives: a "module:function" path imported only when a
spec of that kind is opened (as `gazehdr.sim.models` finds models). So an optional dependency
(hidapi) is loaded only for its own source, and this module imports no source's module: those
import this one, `sources` and `samples`, never the other way round.

Adding a source (`lsl`, `pupil`, ...) is one `SourceKind` here plus its module, whose opener takes
a `samples.StreamRequest` and returns a `sources.Source` (or takes a `samples.TrackRequest` and
returns a `GazeTrack`). A missing optional dependency (an ImportError while loading or opening)
becomes a `SourceUnavailableError` naming the kind; an opener raises that itself for a source
that is not there (no device). Help texts and the errors that list the choices are made from the
table.

A stream spec is `NAME[:ARG]`, ARG as the kind's syntax says. A track spec is a kind's name, or
matches its `pattern` (`X,Y`), or else names a file with its `suffix`, which must exist.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from gazehdr.drivers.errors import GazehdrError, InputError
from gazehdr.drivers.samples import GazeTrack, ScreenGeometry, StreamRequest, TrackRequest

if TYPE_CHECKING:  # sources brings numpy; the table stays light for `gazehdr --help`
    from gazehdr.drivers.sources import Clock, Sleep, Source

How = Literal["stream", "track"]
STREAM: How = "stream"
TRACK: How = "track"


class SourceUnavailableError(GazehdrError, RuntimeError):
    """A source that cannot be opened here (missing driver, no device); the text says why."""


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


@dataclass(frozen=True)
class Opening:
    """One way a kind opens: the spec syntax, a line of help, and the opener's "module:function".

    For tracks, `pattern` is a regular expression the whole spec matches (default: the kind's
    name), and `suffix` makes the kind a file of that (lower-case) suffix instead.
    """

    syntax: str
    help: str
    code: str
    pattern: str | None = None
    suffix: str | None = None

    @property
    def module(self) -> str:
        return self.code.partition(":")[0]

    def load(self) -> Callable[[Any], Any]:
        """The opener, its module imported now."""
        return getattr(importlib.import_module(self.module), self.code.partition(":")[2])


@dataclass(frozen=True)
class SourceKind:
    """A kind of gaze source: its name, how it opens (stream, track or both), `title`, how
    messages name it (default: its name), and `confidence`: its samples carry one, and its
    stream takes `min_confidence` (the confidence below which a sample is invalid)."""

    name: str
    stream: Opening | None = None
    track: Opening | None = None
    title: str = ""
    confidence: bool = False

    def opening(self, how: How) -> Opening | None:
        return self.stream if how == STREAM else self.track


_D = "gazehdr.drivers"
#: Every kind, in the order help texts and error messages list them.
KINDS: tuple[SourceKind, ...] = (
    SourceKind(
        "synthetic",
        stream=Opening(
            "synthetic[:SEED]",
            "a seeded scan path, seed 0 by default, sampled in real time",
            f"{_D}.sources:open_synthetic",
        ),
        track=Opening(
            "synthetic", "seeded scan path, fixation to fixation", f"{_D}.tracks:synthetic_track"
        ),
    ),
    SourceKind("fixed", track=Opening("fixed", "centre", f"{_D}.tracks:fixed_track")),
    SourceKind(
        "point",
        track=Opening(
            "X,Y",
            "normalised point",
            f"{_D}.tracks:point_track",
            pattern=rf"\s*{_NUMBER}\s*,\s*{_NUMBER}\s*",
        ),
    ),
    SourceKind(
        "csv",
        track=Opening(
            "FILE.csv", "t,x,y[,eyes_open] rows", f"{_D}.tracks:csv_track", suffix=".csv"
        ),
        title="CSV",
    ),
    SourceKind(
        "replay",
        stream=Opening(
            "replay:FILE[@SPEED]",
            "a session log or any recording 'gazehdr import' reads (a BIDS dataset, a folder "
            "in one or a physio file; FILE#sub-01_run-2 picks a run), at recorded speed or "
            "SPEED times it: 2, 0.5, or max (as fast as it is read)",
            f"{_D}.replay:open_replay",
        ),
        track=Opening(
            "LOG.jsonl",
            "a session log's fixations",
            f"{_D}.tracks:session_log_track",
            suffix=".jsonl",
        ),
    ),
    SourceKind(
        "hid",
        stream=Opening(
            "hid[:PATH]",
            "a USB HID eye tracker (usage page 0x12): the one at PATH, else the first found",
            f"{_D}.hid.source:open_hid",
        ),
        title="HID",
    ),
    SourceKind(
        "pupil",
        stream=Opening(
            "pupil[:HOST[:PORT][/SURFACE]]",
            "Pupil Capture's gaze on the surface SURFACE (default screen), through Pupil Remote "
            "at HOST:PORT (default 127.0.0.1:50020)",
            f"{_D}.pupil.source:open_pupil",
        ),
        title="Pupil",
        confidence=True,
    ),
    SourceKind(
        "lsl",
        stream=Opening(
            "lsl[:QUERY]",
            "a Lab Streaming Layer gaze stream: of type Gaze (or gaze, Eyetracker), or the one "
            "named QUERY, or PROPERTY=VALUE (type, source_id, hostname, ...), or an XPath "
            "predicate such as \"name='Tobii' and hostname='lab3'\"",
            f"{_D}.lsl.source:open_lsl",
        ),
        title="LSL",
        confidence=True,
    ),
)


def kinds(how: How | None = None) -> tuple[SourceKind, ...]:
    """The kinds that open `how` (a stream or a track), or all of them."""
    return tuple(k for k in KINDS if how is None or k.opening(how) is not None)


def named_tracks() -> tuple[SourceKind, ...]:
    """The kinds that open as a track by their name alone (no file, no point): what a live
    session can follow by name."""
    return tuple(
        k for k in kinds(TRACK) if k.track and k.track.pattern is None and k.track.suffix is None
    )


def with_confidence() -> tuple[str, ...]:
    """The names of the stream kinds that take `min_confidence`."""
    return tuple(k.name for k in kinds(STREAM) if k.confidence)


def choices(how: How) -> str:
    """The specs of the kinds that open `how`, as error messages list them."""
    openings = [o for k in kinds(how) if (o := k.opening(how)) is not None]
    text = ", ".join(o.syntax for o in openings if o.suffix is None)
    suffixes = sorted(o.suffix for o in openings if o.suffix is not None)
    return f"{text} or a file ending in {', '.join(suffixes)}" if suffixes else text


def describe(how: How) -> str:
    """Each kind that opens `how` as `SYNTAX (help)`, for command-line help."""
    parts = [f"{o.syntax} ({o.help})" for k in kinds(how) if (o := k.opening(how)) is not None]
    return " or ".join([", ".join(parts[:-1]), parts[-1]]) if len(parts) > 1 else "".join(parts)


def _open(kind: SourceKind, opening: Opening, request: Any) -> Any:
    try:
        return opening.load()(request)
    except ImportError as e:  # an optional dependency, missing here
        raise SourceUnavailableError(f"{kind.title or kind.name} source unavailable: {e}") from None


def open_source(
    spec: str,
    *,
    rate_hz: float | None = None,
    realtime: bool = True,
    geometry: ScreenGeometry | None = None,
    screen: Mapping[str, float] | None = None,
    wait: bool = False,
    clock: Clock | None = None,
    sleep: Sleep | None = None,
    **options: Any,
) -> Source:
    """The stream a spec names: `synthetic[:SEED]`, `replay:FILE[@SPEED]`, `hid[:PATH]`, ...

    `rate_hz` and `realtime` apply to the synthetic source; `geometry` to it and to imported
    recordings that do not record their screen, and replaces what a HID tracker reports.
    `screen` overrides single `ScreenGeometry` fields (see `gazehdr.drivers.sources`). `wait`
    (hid, pupil): when no tracker is plugged in (no Pupil Capture answers), wait for one with
    back-off, a message per attempt, instead of failing. Other `options` go to the source
    (`min_confidence` to a kind that has `confidence`: lsl, pupil; refused for the others).
    Raises `ValueError` for a spec it does not know or a geometry that is not one, and
    `SourceUnavailableError` for a source that cannot run here.
    """
    name, _, arg = spec.partition(":")
    kind = next((k for k in KINDS if k.name == name), None)
    if kind is None or kind.stream is None:
        raise InputError(f"unknown gaze source {spec!r}; known: {choices(STREAM)}")
    if "min_confidence" in options and not kind.confidence:
        raise InputError(
            f"a minimum confidence is for sources whose samples carry one "
            f"({', '.join(with_confidence())}); {kind.title or kind.name} samples do not"
        )
    request = StreamRequest(
        arg, rate_hz, realtime, geometry, dict(screen or {}), wait, clock, sleep, options
    )
    return _open(kind, kind.stream, request)


def _track_kind(spec: str) -> tuple[SourceKind, Opening]:
    """The kind of a track spec: by name or pattern first, then by file suffix."""
    tracks = [(k, k.track) for k in kinds(TRACK) if k.track is not None]
    for kind, opening in tracks:
        pattern = opening.pattern or re.escape(kind.name)
        if opening.suffix is None and re.fullmatch(pattern, spec):
            return kind, opening
    suffix = Path(spec).suffix.lower()
    for kind, opening in tracks:
        if opening.suffix == suffix:
            return kind, opening
    raise InputError(f"gaze {spec!r}: expected {choices(TRACK)}")


def open_track(spec: str, *, seed: int = 0, duration: float = 60.0) -> GazeTrack:
    """The track a gaze spec names: `synthetic`, `fixed`, `X,Y` (normalised), or a file path.

    `seed` and `duration` configure the synthetic scan path and are ignored otherwise. Like a
    recorded session, the scan path is followed from fixation to fixation (SPEC §4): a
    saccade does not sweep the retina. ValueError for a spec of no kind, or a missing file.
    """
    kind, opening = _track_kind(spec)
    request = TrackRequest(spec, seed, duration)
    if opening.suffix is not None and not request.path.is_file():
        raise InputError(f"gaze file {spec!r} not found")
    return _open(kind, opening, request)
