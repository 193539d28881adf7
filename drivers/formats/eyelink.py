"""EyeLink ASC files (SR Research's EDF2ASC output) → a session log.

Written from the EyeLink 1000 User Manual (SR Research, 2005-2008), §4.9 "The ASC File Format"
(§4.9.1 structure, §4.9.2 sample lines, §4.9.3 event lines, §4.9.4 data-specification lines),
and checked against the column layout the `eyelinker` R package derives from the same manual
(a-hurst/eyelinker, `R/eyelink_parser.R`: `get_raw_header`, `get_event_header`,
`get_resolution`).

- Lines: blank or comment lines (first character `#`, `/` or `;`) and the `**` preamble are
  skipped (the preamble's `** DATE:`, `** VERSION:`, `** SERIAL NUMBER:` and `** EYELINK ...`
  lines go into the header's `tracker`). A line that begins with a digit is a sample; any other
  begins with a keyword. Keywords not listed here (SSACC/ESACC, INPUT, BUTTON, VPRESCALER,
  PUPIL, ...) are skipped: saccades are the gaps between fixations here.
- `SAMPLES <type> <eyes> <options>` says what sample lines hold; `<type>` must be GAZE (screen
  pixels). A monocular sample is `<time> <xp> <yp> <ps> ...`, a binocular one `<time> <xpl>
  <ypl> <psl> <xpr> <ypr> <psr> ...`; velocity, resolution, input, CR flags and remote-mode
  columns may follow and are ignored. A missing value is `.` (or the string given to `edf2asc
  -miss`, our `missing`). Times are milliseconds on the tracker clock, possibly with a
  fraction (`-ftime`, 2000 Hz): we keep them exactly, as integer ns (ms × 10⁶). Without
  `-ftime` a 2000 Hz file has two consecutive rows per time stamp, "the second row refers to
  the sample collected at 0.5 ms after the reported time stamp" (manual §4.9.2): it gets
  that time.
- Position values are divided by `PRESCALER` (always 1 for EDF2ASC) and shifted so that the
  screen's top-left is 0, 0.
- Validity: a monocular sample is valid when x and y are present; a binocular one when either
  eye is, its position the mean of the eyes that are (both are kept per eye; a lost eye is NaN).
  Pupil size is in the tracker's arbitrary area or diameter units, not millimetres, so it is
  not kept.
- `SFIX <eye> <time>` / `EFIX <eye> <stime> <etime> <dur> <axp> <ayp> <aps>` become
  `fixation_start` / `fixation_end` (mean position, duration from `<dur>`); with `EVENTS HREF`
  the gaze averages follow three HREF columns. `SBLINK`/`EBLINK` become `blink_start` /
  `blink_end`. Events keep their eye; a fixation's or blink's start and end share an id. An
  end whose start is missing (`edf2asc -nse`) gets a start at its `<stime>`.
- `MSG <time> <message>` becomes a note. A message that begins with an integer carries a
  time offset (SR Research FAQ "How can I take advantage of the timing offset in sending
  messages?", sr-research.com/support/thread-170; EyeLink Data Viewer and Experiment Builder
  write them): the event happened at `<time> − offset`, and the note holds the rest. The
  screen comes from the `GAZE_COORDS <left> <top> <right> <bottom>` message (the space gaze
  positions are in; width = right − left + 1), else from `DISPLAY_COORDS`; the file records
  no physical size or distance (`geometry` gives them).
- `START`/`END` delimit recording blocks; at each `END` an invalid sample is added, so a replay
  does not hold a stale gaze through the unrecorded gap before the next block.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from gazehdr.drivers.formats.common import decimal_ns, finite_float, geometry_with, mean_of_eyes
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
_OFFSET = re.compile(r"(-?\d+)\s+(\S.*)")
_EYE = {"L": "left", "R": "right"}
_COORDS = re.compile(r"\b(DISPLAY_COORDS|GAZE_COORDS)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)")
_PREAMBLE = {
    "DATE": "date",
    "VERSION": "version",
    "SERIAL NUMBER": "serial",
    "SOURCE": "source",
    "CAMERA": "camera",
}


def read_eyelink_asc(
    path: Path, *, geometry: ScreenGeometry | None = None, missing: str = "."
) -> SessionLog:
    """Read an EyeLink ASC file; `geometry` supplies what the file lacks (diagonal, distance)."""
    parser = _Parser(Path(path), missing)
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, 1):
            parser.line(number, line)
    return parser.finish(geometry)


class _Parser:
    def __init__(self, path: Path, missing: str) -> None:
        self.path = path
        self.missing = missing
        self.tracker: dict[str, object] = {"format": "eyelink-asc", "file": path.name}
        self.samples: list[GazeSample] = []
        self.events: list[GazeEvent] = []
        self.notes: list[Note] = []
        self.eyes: tuple[str, ...] | None = None  # from the SAMPLES line
        self.event_type = "GAZE"
        self.prescaler = 1.0
        self.coords: dict[str, tuple[float, float, float, float]] = {}
        self.open: dict[tuple[str, str], int] = {}
        self.next_id = {"fixation": 1, "blink": 1}
        self.block_samples = 0
        self.last_stamp: str | None = None  # the previous sample's time text, for 2000 Hz pairs

    def error(self, line: int, field: str | None, reason: str) -> FormatError:
        return FormatError(self.path, line, field, reason)

    def time(self, line: int, text: str, field: str = "time") -> int:
        try:
            return decimal_ns(text, _MS)
        except ValueError:
            raise self.error(line, field, f"expected a time in ms, got {text!r}") from None

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

    def line(self, number: int, raw: str) -> None:
        text = raw.strip()
        if not text or text[0] in "#/;":
            return
        if text.startswith("**"):
            self.preamble(text[2:].strip())
            return
        if text[0].isdigit():
            self.sample(number, text.split())
            return
        tokens = text.split()
        keyword = tokens[0]
        if keyword == "MSG":
            self.message(number, text)
        elif keyword in ("SAMPLES", "EVENTS"):
            self.specification(number, keyword, tokens)
        elif keyword == "PRESCALER":
            try:
                self.prescaler = finite_float(tokens[1])
            except (IndexError, ValueError):
                raise self.error(number, "prescaler", "PRESCALER needs a number") from None
        elif keyword == "START":
            self.block_samples = 0
        elif keyword == "END":
            self.end(number, tokens)
        elif keyword in ("SFIX", "SBLINK"):
            self.start_event(number, keyword, tokens)
        elif keyword in ("EFIX", "EBLINK"):
            self.end_event(number, keyword, tokens)

    def preamble(self, text: str) -> None:
        key, sep, value = text.partition(":")
        if sep and key.strip().upper() in _PREAMBLE:
            self.tracker[_PREAMBLE[key.strip().upper()]] = value.strip()
        elif text.upper().startswith("EYELINK"):
            self.tracker["model"] = text

    def specification(self, number: int, keyword: str, tokens: list[str]) -> None:
        if len(tokens) < 3:
            raise self.error(number, "eyes", f"{keyword} needs a data type and the eyes")
        eyes = tuple(_EYE[t[0]] for t in tokens[2:] if t in ("LEFT", "RIGHT"))
        if not eyes:
            raise self.error(number, "eyes", f"{keyword} line names neither LEFT nor RIGHT")
        if keyword == "EVENTS":
            self.event_type = tokens[1]
            return
        if tokens[1] != "GAZE":
            raise self.error(
                number,
                "data type",
                f"samples are {tokens[1]}; gazehdr imports GAZE samples (screen pixels): "
                "convert the EDF with edf2asc -sg",
            )
        self.eyes = eyes
        self.tracker["eyes"] = list(eyes)
        if "RATE" in tokens[2:-1]:
            rate = tokens[tokens.index("RATE") + 1]
            try:
                self.tracker["rate_hz"] = finite_float(rate)
            except ValueError:
                raise self.error(number, "RATE", f"expected a number, got {rate!r}") from None

    def position(self, x: float | None, y: float | None) -> tuple[float, float] | None:
        if x is None or y is None:
            return None
        box = self.coords.get("GAZE_COORDS") or self.coords.get("DISPLAY_COORDS")
        left, top = box[:2] if box else (0.0, 0.0)
        return x / self.prescaler - left, y / self.prescaler - top

    def sample(self, number: int, tokens: list[str]) -> None:
        if self.eyes is None:
            raise self.error(
                number, "time", "a sample before any SAMPLES line saying which eyes it holds"
            )
        binocular = len(self.eyes) == 2
        names = ("xpl", "ypl", "psl", "xpr", "ypr", "psr") if binocular else ("xp", "yp", "ps")
        if len(tokens) < 1 + len(names):
            raise self.error(
                number,
                names[len(tokens) - 1] if len(tokens) > 0 else "time",
                f"a {'binocular' if binocular else 'monocular'} sample has time, "
                f"{', '.join(names)}; this line has {len(tokens)} fields",
            )
        t = self.time(number, tokens[0])
        if tokens[0] == self.last_stamp and "." not in tokens[0]:
            t += _HALF_MS  # the second row of a 2000 Hz time stamp without -ftime
        self.last_stamp = None if tokens[0] == self.last_stamp else tokens[0]
        if self.samples and t < self.samples[-1].t_ns:
            raise self.error(number, "time", f"{tokens[0]} ms goes back in time")
        values = [
            self.value(number, tok, name) for tok, name in zip(tokens[1:], names, strict=False)
        ]
        if binocular:
            eyes = []
            for x, y in ((values[0], values[1]), (values[3], values[4])):
                p = self.position(x, y)
                eyes.append(EyeSample(*p) if p else EyeSample(math.nan, math.nan))
            gaze = mean_of_eyes(*eyes)
            sample = (
                GazeSample(t, gaze[0], gaze[1], True, eyes[0], eyes[1])
                if gaze
                else GazeSample(t, math.nan, math.nan, False, eyes[0], eyes[1])
            )
        else:
            p = self.position(values[0], values[1])
            sample = GazeSample(t, *p) if p else GazeSample(t, math.nan, math.nan, False)
        self.samples.append(sample)
        self.block_samples += 1

    def message(self, number: int, text: str) -> None:
        parts = text.split(None, 2)
        if len(parts) < 2:
            raise self.error(number, "time", "MSG needs a time")
        t = self.time(number, parts[1])
        body = parts[2] if len(parts) > 2 else ""
        offset = _OFFSET.fullmatch(body)
        if offset:  # "MSG <time> <offset> <text>": the event was at time - offset
            t -= int(offset[1]) * _MS
            body = offset[2]
        self.notes.append(Note(t, body))
        match = _COORDS.search(body)
        if match:
            try:
                box = tuple(finite_float(v) for v in match.group(2, 3, 4, 5))
            except ValueError:
                raise self.error(
                    number, match[1], f"expected four numbers, got {match[0]!r}"
                ) from None
            if box[2] <= box[0] or box[3] <= box[1]:
                raise self.error(number, match[1], f"an empty screen: {match[0]!r}")
            self.coords.setdefault(match[1], box)

    def eye(self, number: int, tokens: list[str]) -> str:
        if len(tokens) < 2 or tokens[1] not in _EYE:
            raise self.error(number, "eye", f"{tokens[0]} needs the eye, L or R")
        return _EYE[tokens[1]]

    def start_event(self, number: int, keyword: str, tokens: list[str]) -> None:
        family = "fixation" if keyword == "SFIX" else "blink"
        eye = self.eye(number, tokens)
        if len(tokens) < 3:
            raise self.error(number, "time", f"{keyword} needs a time")
        t = self.time(number, tokens[2])
        ident = self.next_id[family]
        self.next_id[family] += 1
        self.open[(family, eye)] = ident
        self.events.append(GazeEvent(f"{family}_start", ident, t, eye=eye))

    def end_event(self, number: int, keyword: str, tokens: list[str]) -> None:
        family = "fixation" if keyword == "EFIX" else "blink"
        eye = self.eye(number, tokens)
        needed = ["stime", "etime", "dur"]
        if family == "fixation":
            href = self.event_type == "HREF"
            needed += (["href_axp", "href_ayp", "href_aps"] if href else []) + ["axp", "ayp"]
        if len(tokens) < 2 + len(needed):
            raise self.error(
                number,
                needed[max(len(tokens) - 2, 0)],
                f"{keyword} has <eye> {' '.join(f'<{n}>' for n in needed)} ...; "
                f"this line has {len(tokens)} fields",
            )
        start = self.time(number, tokens[2], "stime")
        end = self.time(number, tokens[3], "etime")
        duration = self.time(number, tokens[4], "dur")
        ident = self.open.pop((family, eye), None)
        if ident is None:
            ident = self.next_id[family]
            self.next_id[family] += 1
            self.events.append(GazeEvent(f"{family}_start", ident, start, eye=eye))
        x = y = math.nan
        if family == "fixation":
            p = self.position(
                self.value(number, tokens[len(needed)], "axp"),
                self.value(number, tokens[len(needed) + 1], "ayp"),
            )
            if p:
                x, y = p
        self.events.append(GazeEvent(f"{family}_end", ident, end, x, y, duration, None, eye))

    def end(self, number: int, tokens: list[str]) -> None:
        if len(tokens) < 2:
            raise self.error(number, "time", "END needs a time")
        t = self.time(number, tokens[1])
        if self.block_samples and self.samples:
            t = max(t, self.samples[-1].t_ns + 1)
            self.samples.append(GazeSample(t, math.nan, math.nan, False))
        self.block_samples = 0

    def finish(self, geometry: ScreenGeometry | None) -> SessionLog:
        box = self.coords.get("GAZE_COORDS") or self.coords.get("DISPLAY_COORDS")
        if box is None and geometry is None:
            raise FormatError(
                self.path,
                None,
                "DISPLAY_COORDS",
                "no DISPLAY_COORDS or GAZE_COORDS message gives the screen size; "
                "pass it (--screen WxH)",
            )
        if box is not None:
            width, height = round(box[2] - box[0] + 1), round(box[3] - box[1] + 1)
            geometry = geometry_with(geometry, width_px=width, height_px=height)
        header = SessionHeader(
            tracker=self.tracker,
            screen=geometry,
            clock=ClockInfo(source="EyeLink tracker clock"),
        )
        log = SessionLog(header, self.samples, path=self.path)
        log.events = sorted(self.events, key=lambda e: e.t_ns)
        log.notes = sorted(self.notes, key=lambda n: n.t_ns)
        return log
