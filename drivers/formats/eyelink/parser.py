"""The line-by-line reader behind `read_eyelink_asc`: one `AscParser` per file, fed every line,
`finish()` giving the session log. The package docstring says what each line means.

A little past 600 lines on purpose: the parser is one state (the block's eyes and layout, the
events still open, the screen so far) that every kind of line reads and changes, so its
methods stay together; what needs no state, the messages' meanings, is in `messages.py`."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.common import (
    decimal_ns,
    finite_float,
    geometry_with,
    is_number,
    mean_of_eyes,
    sort_events,
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
#: The corneal-reflection flags (§4.9.2): monocular `I C R`, binocular `I CL RL CR RR`, each a
#: letter or `.`; EDF2ASC writes them after the values unless `-nflags`.
_FLAGS_MONO = re.compile(r"[.I][.C][.R]")
_FLAGS_BINO = re.compile(r"[.I][.C][.R][.C][.R]")
#: An END this long after its block's last sample (a file cut short, or samples left out)
#: ends the block at that sample instead: a replay would hold the last gaze through the gap.
END_GAP_NS = 1_000_000_000
#: `--eye` for a sample-only file: what its sample lines hold.
SAMPLE_EYES = {"left": ("left",), "right": ("right",), "both": ("left", "right")}
_PREAMBLE = {
    "DATE": "date",
    "VERSION": "version",
    "SERIAL NUMBER": "serial",
    "SOURCE": "source",
    "CAMERA": "camera",
}
# Understood, nothing kept: sample velocity (which VPRESCALER scales) is not read.
_SKIPPED = frozenset({"VPRESCALER"})
# Lines every EDF2ASC file has one of: a file with none, and lines that are no sample, is not ASC
_ASC_KEYWORDS = frozenset({"MSG", "START", "END", "SAMPLES", "EVENTS"})
_FAMILY = {"FIX": "fixation", "BLINK": "blink", "SACC": "saccade"}


class AscParser:
    """The state of one file being read: the current recording block's data specification,
    open events, and what has been read. `strict` refuses the file at its first line not
    understood; otherwise such a line becomes a note and reading goes on."""

    def __init__(
        self,
        path: Path,
        missing: str | None = None,
        strict: bool = False,
        eye: str | None = None,
    ) -> None:
        self.path = path
        self.missing = None if missing in (None, ".") else missing
        self.strict = strict
        if eye is not None and eye not in SAMPLE_EYES:
            raise FormatError(path, None, "eye", f"{eye!r}; expected {', '.join(SAMPLE_EYES)}")
        self.eye_option = eye
        self.lost_as: dict[str, int] = {}  # what a lost eye's x, y are written as, but `.`
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
        self.next_id = {"fixation": 1, "blink": 1, "saccade": 1}  # renumbered by _numbered
        self.event_eyes: set[str] = set()  # the eyes EVENTS lines name (an events-only file)
        self.event_rates: list[float] = []
        self.averaged = 0  # samples of a binocular block written as one eye (edf2asc -avg)
        self.block_last: int | None = None  # the block's last sample time
        self.period_ns: int | None = None  # the block's sample period, from its RATE
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
            "SSACC": self.start_event,
            "EFIX": self.end_event,
            "EBLINK": self.end_event,
            "ESACC": self.end_event,
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

    def is_missing(self, text: str) -> bool:
        """EDF2ASC's missing value: `.`, or the string given to `edf2asc -miss` (`missing`)."""
        return text == "." or text == self.missing

    def value(self, line: int, text: str, field: str) -> float | None:
        if self.is_missing(text):
            return None
        try:
            value = float(text)
        except ValueError:
            given = f" or {self.missing!r}" if self.missing else ""
            raise self.error(
                line, field, f"expected a number or '.'{given} (missing), got {text!r}"
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
        self.event_eyes.update(self.eyes_of(number, tokens))
        self.event_type = tokens[1]
        if "RATE" in tokens[2:-1]:
            try:
                rate = finite_float(tokens[tokens.index("RATE") + 1])
            except ValueError:
                return
            if rate not in self.event_rates:
                self.event_rates.append(rate)

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
        self.period_ns = round(1e9 / rate) if rate else None

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
        self.block_last = None
        self.blocks += 1

    def end(self, number: int, tokens: list[str], text: str) -> None:
        if len(tokens) < 2:
            raise self.error(number, "time", "END needs a time")
        t = self.stamp(number, tokens[1])
        if self.block_samples and self.samples:
            last = self.samples[-1].t_ns
            if t - last > END_GAP_NS:  # samples missing (a file cut short): end at the last
                period = self.period_ns or _MS
                self.notes.append(
                    Note(
                        t,
                        f"END {tokens[1]} is {(t - last) / 1e9:g} s after its block's last "
                        "sample: the block's gaze ends at that sample",
                    )
                )
                t = last + period
            t = max(t, last + 1)
            before = self.samples[-1]  # the block's eyes, lost: what an eye's recording ends on
            lost = {e: EyeSample(math.nan, math.nan) for e in _EYE.values() if getattr(before, e)}
            self.samples.append(GazeSample(t, math.nan, math.nan, False, **lost))
        self.block_samples = 0

    # --- samples (§4.9.2) ---------------------------------------------------------------------

    def layout(self, tokens: list[str]) -> tuple[int, str | None]:
        """(how many values follow the time, the CR flags field or None): the values end at the
        first token that is neither a number nor missing."""
        count = 0
        for token in tokens[1:]:
            if not self.is_missing(token) and not is_number(token):
                flagged = _FLAGS_MONO.fullmatch(token) or _FLAGS_BINO.fullmatch(token)
                return count, token if flagged else None
            count += 1
        return count, None

    def sample_eyes(self, number: int, tokens: list[str]) -> tuple[str, ...] | None:
        """The eyes of a sample line: the block's SAMPLES line. A sample-only file (edf2asc -s,
        no data-specification lines, §4.9.1) names no eye: binocular samples are told by their
        CR flags (5 characters; 3 for one eye), or without flags (`-nflags`) by their count of
        values (6, or 9 to 13 with `-vel`, `-res`, `-input`: both eyes; 3 to 5: one eye); which
        one eye is said with `eye` (`--eye`), or the file is refused."""
        if self.eyes is not None or self.spec_error is not None:
            return self.eyes
        if self.structured:
            self.spec_error = self.error(
                number, "time", "a sample before any SAMPLES line saying which eyes it holds"
            )
            raise self.spec_error
        count, flags = self.layout(tokens)
        if flags is not None:
            binocular = len(flags) == 5
        elif count in (3, 4, 5):
            binocular = False
        elif 9 <= count <= 13:
            binocular = True
        elif self.eye_option is not None and count >= 3:
            binocular = self.eye_option == "both"
        else:
            raise self.error(
                number,
                "time",
                f"a sample-only file (edf2asc -s) whose samples have {count} values and no CR "
                "flags: cannot tell one eye with -vel/-res/-input from both eyes; convert "
                "without -nflags (or with events), or pass --eye left, right or both",
            )
        if binocular:
            if self.eye_option in ("left", "right"):
                self.spec_error = self.error(
                    number,
                    "eye",
                    f"--eye {self.eye_option}, but the samples hold both eyes "
                    f"({'CR flags ' + repr(flags) if flags else f'{count} values'}): "
                    "pass --eye both, or leave it out",
                )
                raise self.spec_error
            self.eyes = ("left", "right")
        elif self.eye_option in ("left", "right"):
            self.eyes = (self.eye_option,)
        else:
            self.spec_error = self.error(
                number,
                "eye",
                "a sample-only file (edf2asc -s) of one eye does not say which: pass --eye "
                "left or --eye right (or convert with events, which name it)"
                if self.eye_option is None
                else f"--eye both, but the samples hold one eye ({count} values"
                + (f", CR flags {flags!r})" if flags else ")"),
            )
            raise self.spec_error
        self.eyes_seen.update(self.eyes)
        return self.eyes

    def sample(self, number: int, tokens: list[str]) -> None:
        eyes = self.sample_eyes(number, tokens)
        if eyes is None:  # the block's samples cannot be placed; its SAMPLES line said why
            self.refusal = self.refusal or self.spec_error
            self.unread_lines += 1
            return
        binocular = len(eyes) == 2
        if binocular and self.structured:  # edf2asc -avg: a binocular block, one eye's layout
            _, flags = self.layout(tokens)
            if flags is not None and len(flags) == 3:
                binocular = False
                self.averaged += 1
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
            sides = self.eye_sample(tokens, values, 0), self.eye_sample(tokens, values, 3)
            gaze = mean_of_eyes(*sides)
            if gaze and math.isfinite(gaze[0]) and math.isfinite(gaze[1]):
                sample = GazeSample(t, gaze[0], gaze[1], True, *sides)
            else:
                sample = GazeSample(t, math.nan, math.nan, False, *sides)
        else:  # the eye the block names carries the pupil (-avg: the mean gaze, no eye)
            eye = self.eye_sample(tokens, values, 0)
            named = {} if len(eyes) != 1 else {eyes[0]: eye}
            sample = GazeSample(t, eye.x, eye.y, math.isfinite(eye.x), **named)
        self.samples.append(sample)
        self.block_samples += 1
        self.block_last = t

    def eye_sample(self, tokens: list[str], values: list[float | None], i: int) -> EyeSample:
        """One eye's x, y (NaN when lost) and its pupil (the tracker's units: `PUPIL` says
        area or diameter). A pupil of 0 is lost track (§4.9.2: EyeLink writes x, y missing and
        pupil 0.0): whatever x, y say, as `edf2asc -miss -1` or `-miss 0` write them
        (-1 -1 0.0); such a string is counted in `lost_as`."""
        pupil = values[i + 2]
        if pupil == 0.0:
            x_text, y_text = tokens[1 + i], tokens[2 + i]
            if not self.is_missing(x_text) or not self.is_missing(y_text):
                key = x_text if x_text == y_text else f"{x_text} {y_text}"
                self.lost_as[key] = self.lost_as.get(key, 0) + 1
            return EyeSample(math.nan, math.nan)
        x, y = self.position(values[i], values[i + 1]) or (math.nan, math.nan)
        return EyeSample(x, y, None, pupil if pupil is not None and math.isfinite(pupil) else None)

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
        family = _FAMILY[tokens[0][1:]]
        eye = self.eye(number, tokens)
        if len(tokens) < 3:
            raise self.error(number, "time", f"{tokens[0]} needs a time")
        t = self.stamp(number, tokens[2])
        ident = self.next_id[family]
        self.next_id[family] += 1
        self.open[(family, eye)] = ident
        self.events.append(GazeEvent(f"{family}_start", ident, t, eye=eye))

    def end_event(self, number: int, tokens: list[str], text: str) -> None:
        family = _FAMILY[tokens[0][1:]]
        eye = self.eye(number, tokens)
        needed = ["stime", "etime", "dur"]
        href = self.event_type == "HREF"
        if family == "fixation":
            needed += (["href_axp", "href_ayp", "href_aps"] if href else []) + ["axp", "ayp"]
        elif family == "saccade":
            needed += ["sxp", "syp", "exp", "eyp"]
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
        x = y = sx = sy = math.nan
        if family == "fixation":
            p = self.position(
                self.value(number, tokens[len(needed)], "axp"),
                self.value(number, tokens[len(needed) + 1], "ayp"),
            )
            if p:
                x, y = p
        elif family == "saccade" and not href:  # HREF saccades are not on the screen
            start_p = self.position(
                self.value(number, tokens[5], "sxp"), self.value(number, tokens[6], "syp")
            )
            end_p = self.position(
                self.value(number, tokens[7], "exp"), self.value(number, tokens[8], "eyp")
            )
            sx, sy = start_p or (math.nan, math.nan)
            x, y = end_p or (math.nan, math.nan)
        ident = self.open.pop((family, eye), None)
        if ident is None:  # edf2asc -nse: no start lines; the start is the end's <stime>
            ident = self.next_id[family]
            self.next_id[family] += 1
            self.events.append(GazeEvent(f"{family}_start", ident, start, eye=eye))
        if family == "saccade" and math.isfinite(sx):  # where it began, on its start
            for i in range(len(self.events) - 1, -1, -1):
                e = self.events[i]
                if (e.kind, e.id, e.eye) == ("saccade_start", ident, eye):
                    self.events[i] = GazeEvent(e.kind, e.id, e.t_ns, sx, sy, eye=eye)
                    break
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
        events_only = not self.samples and self.refusal is None and self.asc_lines
        if events_only and not self.events and not self.event_eyes:
            raise self.error(
                None,
                "samples",
                "no sample and no eye event: convert the EDF with samples or events",
            )
        if not self.samples and not events_only:
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
        log.events = _numbered(sort_events(self.events))
        log.notes = sorted(self.notes, key=lambda n: n.t_ns)
        return log

    def summary(self) -> dict[str, Any]:
        """The header's account of the recording: eyes, rate(s), blocks, validations, and how
        many lines were not read."""
        eyes = self.eyes_seen or (set() if self.samples else self.event_eyes)
        out: dict[str, Any] = {"eyes": [e for e in ("left", "right") if e in eyes]}
        rates = self.rates or (self.event_rates if not self.samples else [])
        if rates:
            out["rate_hz"] = rates[0]
        if len(rates) > 1:
            out["rates_hz"] = sorted(rates)
        if not self.samples:
            out["events_only"] = True
        if self.averaged:
            out["averaged_samples"] = self.averaged
        if self.lost_as:
            out["lost_track_written_as"] = dict(sorted(self.lost_as.items()))
        if self.blocks:
            out["blocks"] = self.blocks
        if self.validations:
            out["validations"] = self.validations
        if self.unread_lines:
            out["unread_lines"] = self.unread_lines
        return out


def _numbered(events: list[GazeEvent]) -> list[GazeEvent]:
    """Ids 1, 2, ... per kind and eye in the order the events start, so that a file converted
    without start lines (`-nse`) or with one eye (`-l`, `-r`) numbers them as the default
    conversion does."""
    new: dict[tuple[str, int, str | None], int] = {}
    count: dict[tuple[str, str | None], int] = {}
    out = []
    for e in events:
        family = e.kind.partition("_")[0]
        key = (family, e.id, e.eye)
        if key not in new:
            count[family, e.eye] = count.get((family, e.eye), 0) + 1
            new[key] = count[family, e.eye]
        out.append(replace(e, id=new[key]))
    return out
