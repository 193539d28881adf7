"""The line-by-line reader behind `read_eyelink_asc`: one `AscParser` per file, fed every line,
`finish()` giving the session log. The package docstring says what each line means."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.common import (
    decimal_ns,
    finite_float,
    geometry_with,
    is_number,
    mean_of_eyes,
)
from gazehdr.drivers.formats.eyelink import messages
from gazehdr.drivers.samples import EyeSample, GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    ClockInfo,
    FormatError,
    GazeEvent,
    Note,
    SessionHeader,
    SessionLog,
)

_MS = 1_000_000
_HALF_MS = _MS // 2  # the second sample of a 2000 Hz time stamp (manual §4.9.2)
# A time stamp or duration: ms on the tracker clock, with `-ftime` a fraction. Bounded, so that
# a garbled field cannot make a number of a billion digits.
_TIME = re.compile(r"\d{1,12}(?:\.\d{1,6})?", re.ASCII)
_EYE = {"L": "left", "R": "right"}
_MONO = ("xp", "yp", "ps")
_BINO = ("xpl", "ypl", "psl", "xpr", "ypr", "psr")
_PREAMBLE = {
    "DATE": "date",
    "VERSION": "version",
    "SERIAL NUMBER": "serial",
    "SOURCE": "source",
    "CAMERA": "camera",
}
# Understood, nothing kept: saccades are the gaps between fixations here, and sample velocity
# (which VPRESCALER scales) is not read.
_SKIPPED = frozenset({"SSACC", "ESACC", "VPRESCALER"})
# Lines every EDF2ASC file has one of: a file with none, and lines that are no sample, is not ASC
_ASC_KEYWORDS = frozenset({"MSG", "START", "END", "SAMPLES", "EVENTS"})


class AscParser:
    """The state of one file being read: the current recording block's data specification,
    open events, and what has been read. `strict` refuses the file at its first line not
    understood; otherwise such a line becomes a note and reading goes on."""

    def __init__(self, path: Path, missing: str = ".", strict: bool = False) -> None:
        self.path = path
        self.missing = missing
        self.strict = strict
        self.tracker: dict[str, Any] = {"format": "eyelink-asc", "file": path.name}
        self.samples: list[GazeSample] = []
        self.events: list[GazeEvent] = []
        self.notes: list[Note] = []
        self.early: list[str] = []  # notes of lines before any time stamp
        self.now: int | None = None  # the last time stamp read, for notes of unread lines
        self.structured = False  # a START or data-specification line was seen (§4.9.1)
        self.eyes: tuple[str, ...] | None = None  # the block's SAMPLES line
        self.spec_error: FormatError | None = None  # why this block's samples cannot be placed
        self.refusal: FormatError | None = None  # the first reason a sample was not placed
        self.event_type = "GAZE"
        self.prescaler = 1.0
        self.coords: dict[str, messages.Box] = {}
        self.open: dict[tuple[str, str], int] = {}
        self.next_id = {"fixation": 1, "blink": 1}
        self.block_samples = 0
        self.last_stamp: str | None = None  # the previous sample's time text, for 2000 Hz pairs
        self.open_message: int | None = None  # the note that an indented line continues
        self.eyes_seen: set[str] = set()
        self.rates: list[float] = []
        self.blocks = 0
        self.unread_lines = 0
        self.asc_lines = False  # a `**` preamble, MSG, START, END, SAMPLES or EVENTS line seen
        self.foreign: tuple[int, str] | None = None  # the first line not read that is no sample
        self.validations: list[dict[str, Any]] = []
        self.keywords: dict[str, Callable[[int, list[str], str], None]] = {
            "MSG": self.message,
            "SAMPLES": self.samples_spec,
            "EVENTS": self.events_spec,
            "PRESCALER": self.set_prescaler,
            "PUPIL": self.pupil,
            "START": self.start,
            "END": self.end,
            "SFIX": self.start_event,
            "SBLINK": self.start_event,
            "EFIX": self.end_event,
            "EBLINK": self.end_event,
            "INPUT": self.port,
            "BUTTON": self.port,
        }

    # --- helpers ------------------------------------------------------------------------------

    def error(self, line: int | None, field: str | None, reason: str) -> FormatError:
        return FormatError(self.path, line, field, reason)

    def time(self, line: int, text: str, field: str = "time") -> int:
        """A time or duration in ms (text) as ns."""
        if not _TIME.fullmatch(text):
            raise self.error(line, field, f"expected a time in ms, got {text!r}")
        return decimal_ns(text, _MS)

    def stamp(self, line: int, text: str, field: str = "time") -> int:
        """A line's time stamp: also where the notes of lines not read are placed."""
        t = self.time(line, text, field)
        if self.now is None:  # the first: the lines not read before it are placed here
            self.notes += [Note(t, early) for early in self.early]
        self.now = t
        return t

    def value(self, line: int, text: str, field: str) -> float | None:
        if text == self.missing:
            return None
        try:
            value = float(text)
        except ValueError:
            raise self.error(
                line, field, f"expected a number or {self.missing!r} (missing), got {text!r}"
            ) from None
        return value if math.isfinite(value) else None

    def position(self, x: float | None, y: float | None) -> tuple[float, float] | None:
        if x is None or y is None:
            return None
        box = self.coords.get("GAZE_COORDS") or self.coords.get("DISPLAY_COORDS")
        left, top = box[:2] if box else (0.0, 0.0)
        p = (x / self.prescaler - left, y / self.prescaler - top)
        return p if math.isfinite(p[0]) and math.isfinite(p[1]) else None

    # --- lines --------------------------------------------------------------------------------

    def line(self, number: int, raw: str) -> None:
        """Read one line (manual §4.9, §4.10): what its first character says it is."""
        text = raw.strip()
        if not text or text[0] in "#/;":  # blank or comment
            return
        continued, self.open_message = self.open_message, None
        first = raw[0]
        try:
            if first.isdigit():
                self.sample(number, text.split())
            elif first.isalpha():
                tokens = text.split()
                if tokens[0] in _SKIPPED:
                    return
                handler = self.keywords.get(tokens[0])
                self.asc_lines |= tokens[0] in _ASC_KEYWORDS
                if handler is None:
                    raise self.error(number, None, f"unknown keyword {tokens[0]!r}")
                handler(number, tokens, text)
            elif raw.startswith("**"):
                self.asc_lines = True
                self.preamble(text[2:].strip())
            elif continued is not None:  # a message's next line: indented, or `>>>>>>> ...`
                note = self.notes[continued]
                self.notes[continued] = Note(note.t_ns, f"{note.text}\n{raw.rstrip()}")
                self.open_message = continued
            else:
                raise self.error(number, None, "neither a sample, a keyword nor a message's line")
        except FormatError as err:
            if self.strict:
                raise
            self.unread(number, err, text, is_sample=first.isdigit())

    def unread(self, number: int, err: FormatError, text: str, *, is_sample: bool) -> None:
        """A line not understood: kept as a note that says why, at the last time read."""
        self.unread_lines += 1
        if is_sample and self.refusal is None:
            self.refusal = err
        if not is_sample and self.foreign is None:
            self.foreign = (number, text)
        field = f"field '{err.field}': " if err.field else ""
        note = f"line {number} not read: {field}{err.reason}: {text}"
        if self.now is None:
            self.early.append(note)
        else:
            self.notes.append(Note(self.now, note))

    def preamble(self, text: str) -> None:
        key, sep, value = text.partition(":")
        if sep and key.strip().upper() in _PREAMBLE:
            self.tracker[_PREAMBLE[key.strip().upper()]] = value.strip()
        elif text.upper().startswith("EYELINK"):
            self.tracker["model"] = text

    # --- data specification (§4.9.4) ----------------------------------------------------------

    def eyes_of(self, number: int, tokens: list[str]) -> tuple[str, ...]:
        if len(tokens) < 3:
            raise self.error(number, "eyes", f"{tokens[0]} needs a data type and the eyes")
        eyes = tuple(eye for eye in ("left", "right") if eye.upper() in tokens[2:])
        if not eyes:
            raise self.error(number, "eyes", f"{tokens[0]} line names neither LEFT nor RIGHT")
        return eyes

    def events_spec(self, number: int, tokens: list[str], text: str) -> None:
        self.structured = True
        self.eyes_of(number, tokens)
        self.event_type = tokens[1]

    def samples_spec(self, number: int, tokens: list[str], text: str) -> None:
        self.structured = True
        self.eyes = None
        try:
            eyes = self.eyes_of(number, tokens)
            if tokens[1] != "GAZE":
                raise self.error(
                    number,
                    "data type",
                    f"samples are {tokens[1]}; gazehdr imports GAZE samples (screen pixels): "
                    "convert the EDF with edf2asc -sg",
                )
            rate = None
            if "RATE" in tokens[2:-1]:
                text_rate = tokens[tokens.index("RATE") + 1]
                try:
                    rate = finite_float(text_rate)
                except ValueError:
                    raise self.error(
                        number, "RATE", f"expected a number, got {text_rate!r}"
                    ) from None
        except FormatError as err:
            self.spec_error = err  # the block's samples are skipped, and counted
            raise
        self.eyes, self.spec_error = eyes, None
        self.eyes_seen.update(eyes)
        if rate is not None and rate not in self.rates:
            self.rates.append(rate)

    def set_prescaler(self, number: int, tokens: list[str], text: str) -> None:
        try:
            prescaler = finite_float(tokens[1])
        except (IndexError, ValueError):
            prescaler = 0.0
        if prescaler <= 0:
            raise self.error(number, "prescaler", "PRESCALER needs a positive number")
        self.prescaler = prescaler

    def pupil(self, number: int, tokens: list[str], text: str) -> None:
        if len(tokens) < 2 or tokens[1] not in ("AREA", "DIAMETER"):
            raise self.error(number, "pupil", "PUPIL is AREA or DIAMETER")
        self.tracker["pupil"] = tokens[1].lower()

    def start(self, number: int, tokens: list[str], text: str) -> None:
        if len(tokens) < 2:
            raise self.error(number, "time", "START needs a time")
        self.stamp(number, tokens[1])
        self.structured = True
        self.eyes, self.spec_error = None, None  # each block says again what it holds
        self.block_samples = 0
        self.blocks += 1

    def end(self, number: int, tokens: list[str], text: str) -> None:
        if len(tokens) < 2:
            raise self.error(number, "time", "END needs a time")
        t = self.stamp(number, tokens[1])
        if self.block_samples and self.samples:
            t = max(t, self.samples[-1].t_ns + 1)
            self.samples.append(GazeSample(t, math.nan, math.nan, False))
        self.block_samples = 0

    # --- samples (§4.9.2) ---------------------------------------------------------------------

    def sample_eyes(self, number: int, tokens: list[str]) -> tuple[str, ...] | None:
        """The eyes of a sample line: the block's SAMPLES line; in a sample-only file (edf2asc
        -s, no data-specification lines, §4.9.1) the count of values: 3 one eye, 6 both."""
        if self.eyes is not None or self.spec_error is not None:
            return self.eyes
        if self.structured:
            self.spec_error = self.error(
                number, "time", "a sample before any SAMPLES line saying which eyes it holds"
            )
            raise self.spec_error
        count = 0
        for token in tokens[1:]:
            if token != self.missing and not is_number(token):
                break
            count += 1
        if count not in (3, 6):
            raise self.error(
                number,
                "time",
                f"a sample-only file (edf2asc -s) whose samples have {count} values: cannot "
                "tell which eyes they hold; convert with events, or without -vel/-res",
            )
        self.eyes = ("left",) if count == 3 else ("left", "right")
        self.eyes_seen.update(self.eyes)
        return self.eyes

    def sample(self, number: int, tokens: list[str]) -> None:
        eyes = self.sample_eyes(number, tokens)
        if eyes is None:  # the block's samples cannot be placed; its SAMPLES line said why
            self.refusal = self.refusal or self.spec_error
            self.unread_lines += 1
            return
        binocular = len(eyes) == 2
        names = _BINO if binocular else _MONO
        if len(tokens) < 1 + len(names):
            raise self.error(
                number,
                names[len(tokens) - 1],
                f"a {'binocular' if binocular else 'monocular'} sample has time, "
                f"{', '.join(names)}; this line has {len(tokens)} fields",
            )
        t = self.stamp(number, tokens[0])
        paired = tokens[0] == self.last_stamp
        if paired and "." not in tokens[0]:
            t += _HALF_MS  # the second row of a 2000 Hz time stamp without -ftime
        if self.samples and t < self.samples[-1].t_ns:
            raise self.error(number, "time", f"{tokens[0]} ms goes back in time")
        values = [
            self.value(number, tok, name) for tok, name in zip(tokens[1:], names, strict=False)
        ]
        self.last_stamp = None if paired else tokens[0]
        if binocular:
            left, right = (
                self.position(values[i], values[i + 1]) or (math.nan, math.nan) for i in (0, 3)
            )
            sides = EyeSample(*left), EyeSample(*right)
            gaze = mean_of_eyes(*sides)
            if gaze and math.isfinite(gaze[0]) and math.isfinite(gaze[1]):
                sample = GazeSample(t, gaze[0], gaze[1], True, *sides)
            else:
                sample = GazeSample(t, math.nan, math.nan, False, *sides)
        else:
            p = self.position(values[0], values[1])
            sample = GazeSample(t, *p) if p else GazeSample(t, math.nan, math.nan, False)
        self.samples.append(sample)
        self.block_samples += 1

    # --- events (§4.9.3) ----------------------------------------------------------------------

    def message(self, number: int, tokens: list[str], text: str) -> None:
        parts = text.split(None, 2)
        if len(parts) < 2:
            raise self.error(number, "time", "MSG needs a time")
        t = self.stamp(number, parts[1])
        offset, body = messages.split_offset(parts[2] if len(parts) > 2 else "")
        self.notes.append(Note(t - offset * _MS, body))
        self.open_message = len(self.notes) - 1
        self.tracker.update(messages.tracker_facts(body))
        if (result := messages.validation(body)) is not None:
            self.validations.append(result)
        try:
            box = messages.screen_box(body)
        except messages.BadFieldError as err:
            raise self.error(number, err.field, err.reason) from None
        if box is not None:
            self.coords.setdefault(*box)

    def port(self, number: int, tokens: list[str], text: str) -> None:
        """`INPUT <time> <port>`, `BUTTON <time> <button> <state>`: checked for their time, not
        kept (a session log has no record for port states)."""
        needed = 3 if tokens[0] == "INPUT" else 4
        if len(tokens) < needed:
            raise self.error(
                number, None, f"{tokens[0]} has {needed} fields, this line {len(tokens)}"
            )
        self.stamp(number, tokens[1])

    def eye(self, number: int, tokens: list[str]) -> str:
        if len(tokens) < 2 or tokens[1] not in _EYE:
            raise self.error(number, "eye", f"{tokens[0]} needs the eye, L or R")
        return _EYE[tokens[1]]

    def start_event(self, number: int, tokens: list[str], text: str) -> None:
        family = "fixation" if tokens[0] == "SFIX" else "blink"
        eye = self.eye(number, tokens)
        if len(tokens) < 3:
            raise self.error(number, "time", f"{tokens[0]} needs a time")
        t = self.stamp(number, tokens[2])
        ident = self.next_id[family]
        self.next_id[family] += 1
        self.open[(family, eye)] = ident
        self.events.append(GazeEvent(f"{family}_start", ident, t, eye=eye))

    def end_event(self, number: int, tokens: list[str], text: str) -> None:
        family = "fixation" if tokens[0] == "EFIX" else "blink"
        eye = self.eye(number, tokens)
        needed = ["stime", "etime", "dur"]
        if family == "fixation":
            href = self.event_type == "HREF"
            needed += (["href_axp", "href_ayp", "href_aps"] if href else []) + ["axp", "ayp"]
        if len(tokens) < 2 + len(needed):
            raise self.error(
                number,
                needed[max(len(tokens) - 2, 0)],
                f"{tokens[0]} has <eye> {' '.join(f'<{n}>' for n in needed)} ...; "
                f"this line has {len(tokens)} fields",
            )
        start = self.time(number, tokens[2], "stime")
        end = self.stamp(number, tokens[3], "etime")
        duration = self.time(number, tokens[4], "dur")
        x = y = math.nan
        if family == "fixation":
            p = self.position(
                self.value(number, tokens[len(needed)], "axp"),
                self.value(number, tokens[len(needed) + 1], "ayp"),
            )
            if p:
                x, y = p
        ident = self.open.pop((family, eye), None)
        if ident is None:  # edf2asc -nse: no start lines; the start is the end's <stime>
            ident = self.next_id[family]
            self.next_id[family] += 1
            self.events.append(GazeEvent(f"{family}_start", ident, start, eye=eye))
        self.events.append(GazeEvent(f"{family}_end", ident, end, x, y, duration, None, eye))

    # --- the log ------------------------------------------------------------------------------

    def finish(self, geometry: ScreenGeometry | None) -> SessionLog:
        """The session log; FormatError when no sample could be placed or no screen is known."""
        if not self.samples and not self.asc_lines and self.foreign is not None:
            number, text = self.foreign  # a sample-only file (edf2asc -s) has samples only
            raise self.error(
                number,
                None,
                "not an EyeLink ASC file: it has no '**' preamble, MSG, START or SAMPLES line, "
                f"and this line is none of what EDF2ASC writes: {text[:60]!r}",
            )
        if not self.samples:
            raise self.refusal or self.error(
                None,
                "samples",
                "no sample lines: events only (edf2asc -e?), or not an ASC file; "
                "convert the EDF with samples",
            )
        box = self.coords.get("GAZE_COORDS") or self.coords.get("DISPLAY_COORDS")
        if box is None and geometry is None:
            raise self.error(
                None,
                "DISPLAY_COORDS",
                "no DISPLAY_COORDS or GAZE_COORDS message gives the screen size; "
                "pass it (--screen WxH)",
            )
        if box is not None:
            width, height = round(box[2] - box[0] + 1), round(box[3] - box[1] + 1)
            geometry = geometry_with(geometry, width_px=width, height_px=height)
        self.tracker.update(self.summary())
        header = SessionHeader(
            tracker=self.tracker,
            screen=geometry,
            clock=ClockInfo(source="EyeLink tracker clock"),
        )
        log = SessionLog(header, self.samples, path=self.path)
        log.events = sorted(self.events, key=lambda e: e.t_ns)
        log.notes = sorted(self.notes, key=lambda n: n.t_ns)
        return log

    def summary(self) -> dict[str, Any]:
        """The header's account of the recording: eyes, rate(s), blocks, validations, and how
        many lines were not read."""
        out: dict[str, Any] = {"eyes": [e for e in ("left", "right") if e in self.eyes_seen]}
        if self.rates:
            out["rate_hz"] = self.rates[0]
        if len(self.rates) > 1:
            out["rates_hz"] = sorted(self.rates)
        if self.blocks:
            out["blocks"] = self.blocks
        if self.validations:
            out["validations"] = self.validations
        if self.unread_lines:
            out["unread_lines"] = self.unread_lines
        return out
