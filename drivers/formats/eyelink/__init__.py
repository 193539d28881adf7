"""EyeLink ASC files (SR Research's EDF2ASC output) → a session log.

Written from the EyeLink 1000 Plus User Manual (SR Research, 2013-2017, v1.0.12), §4.9 "The ASC
File Format" (§4.9.1 file structure, §4.9.2 sample lines with the corneal-reflection and remote
fields, §4.9.3 event lines, §4.9.4 data-specification lines) and §4.10 "Processing ASC Files";
the column layouts checked against the `eyelinker` R package (a-hurst/eyelinker,
`R/eyelink_parser.R`), and the whole against real EDF2ASC output: SR Research's test files that
cili ships, an EyeLink 1000 Plus recording from syelink, a Portable Duo recording from
pymovements (tests/data/formats/eyelink_real/README.md). `parser` reads the lines, `messages`
what EyeLink's own messages say.

- Lines (§4.9, §4.10): blank and comment lines (first non-blank character `#`, `/` or `;`) are
  skipped; the `**` preamble gives the header's `tracker` (`DATE`, `VERSION`, `SERIAL NUMBER`,
  `SOURCE`, `CAMERA`, and the `EYELINK ...` model line). A line whose first character is a digit
  is a sample (EDF2ASC writes the time flush left); one that begins with a letter, with a
  keyword. Any other line continues the message before it: EDF2ASC writes a message's text as it
  is, and the calibration report (`!CAL`) holds lines such as `>>>>>>> CALIBRATION ... <<<` and
  indented rows of numbers (`\t  -66     6   -53     5`), which §4.10's first-token rule would
  take for samples.
- Lines not understood (an unknown keyword, a field that is not a number, a time going back, an
  event without its eye, ...) become notes, `line N not read: <why>: <line>`, at the last time
  read, and the header counts them (`unread_lines`); `strict=True` refuses the file at the first
  instead. A file is refused only when no sample could be placed (`FormatError` naming the line
  and the reason of the first that could not), or when the screen size is known neither from the
  file nor from `geometry`. A file that is not text (an EDF, an image), or that has none of the
  lines every EDF2ASC file has (`**` preamble, MSG, START, SAMPLES) and lines that are no
  sample, is refused as not an ASC file, saying which.
- `SAMPLES <type> <eyes> <options>` (§4.9.4) says what the sample lines of its block hold;
  `<type>` must be GAZE (screen pixels; HREF or PUPIL samples cannot be placed: convert with
  `edf2asc -sg`). A monocular sample is `<time> <xp> <yp> <ps> ...`, a binocular one `<time>
  <xpl> <ypl> <psl> <xpr> <ypr> <psr> ...`; what may follow is not read: velocity (`VEL`,
  `edf2asc -vel`), resolution (`RES`, `-res`), the `INPUT` port, the corneal-reflection flags
  (`...` or `.....`: interpolated, CR missing, CR recovery; a flagged sample keeps its
  position), and the remote mode's target x, y, distance and 13 status flags (`HTARGET`, §4.9.2;
  the binocular remote files from SR Research that cili ships declare it without the columns).
  Each `START` clears the specification, so blocks may differ in eyes and rate; the header has
  the eyes seen, `rate_hz` (the first block's) and `rates_hz` when blocks differ. A sample-only
  file (`edf2asc -s`, §4.9.1) has no specification and names no eye (GAZE, EDF2ASC's default):
  5-character CR flags are both eyes, 3-character ones one eye, and without flags (`-nflags`) 6
  or 9 to 13 values both eyes, 3 to 5 one; which one eye, `eye` says (else the file is refused),
  and 6 to 8 values without flags are refused unless `eye` says. A binocular block's sample in
  one eye's layout (3-character flags) is the eyes' mean (`edf2asc -avg`, derived: its output is
  undocumented). A missing value is `.` (or the string given to `edf2asc -miss`, our `missing`).
- Lost track: EyeLink writes a lost eye's pupil as 0 and its x, y as missing, and `edf2asc
  -miss` replaces only the x, y: an eye with a pupil of 0 is lost whatever its x, y say (the
  header's `lost_track_written_as` counts what they said).
- Times are milliseconds on the tracker clock, with a fraction under `-ftime`: kept exactly, as
  integer ns. Without `-ftime` a 2000 Hz file has two rows per time stamp, "the second row
  refers to the sample collected at 0.5 ms after the reported time stamp" (§4.9.2): it gets that
  time. Positions are divided by `PRESCALER` (1 for EDF2ASC; `VPRESCALER` scales the velocity,
  not read) and shifted so that the screen's top-left is 0, 0.
- Validity: a monocular sample is valid when x and y are present; a binocular one when either
  eye is, its position the mean of the eyes that are (both kept per eye; a lost eye is NaN).
  Pupil size is in the tracker's arbitrary units (`PUPIL AREA` or `DIAMETER`, kept as the
  header's `pupil`), not millimetres, so it is not kept.
- `SFIX <eye> <time>` / `EFIX <eye> <stime> <etime> <dur> <axp> <ayp> <aps>` become
  `fixation_start` / `fixation_end` (mean position, duration from `<dur>`); with `EVENTS HREF`
  the gaze averages follow three HREF columns. `SBLINK`/`EBLINK` become `blink_start` /
  `blink_end`. `SSACC <eye> <time>` / `ESACC <eye> <stime> <etime> <dur> <sxp> <syp> <exp> <eyp>
  ...` become `saccade_start` (where it began) / `saccade_end` (where it landed; no position
  with `EVENTS HREF`). Events keep their eye; an event's start and end share an id, numbered per
  kind and eye in the order the events start, and events at one time come in
  `common.sort_events`' order, so that a conversion without some lines numbers and orders them
  as the default does. An end whose start is missing (`edf2asc -nse`) gets a start at its
  `<stime>`. A file of events only (`edf2asc -e`) is a log with no sample: its eyes and rate
  come from its `EVENTS` lines.
- `MSG <time> <message>` becomes a note, with the lines that continue it. A message that begins
  with an integer carries a time offset (SR Research FAQ "How can I take advantage of the timing
  offset in sending messages?"): the event happened at `<time> − offset`, and the note holds the
  rest. `INPUT <time> <port>` and `BUTTON <time> <button> <state>` are read for their time but
  not kept: a session log has no record for port states. From the messages (`messages`): the
  screen from `GAZE_COORDS <left> <top> <right> <bottom>` (the space gaze positions are in;
  width = right − left + 1), else `DISPLAY_COORDS` (the file records no physical size or
  distance: `geometry` gives them); the header's `tracking` (CR or P) from `RECCFG` / `!MODE
  RECORD`, `mount` from `ELCLCFG`, and `validations` from `!CAL VALIDATION` (eye, verdict,
  average and largest error in degrees).
- `START`/`END` delimit recording blocks; at each `END` an invalid sample is added, so a replay
  does not hold a stale gaze through the unrecorded gap before the next block. An `END` more
  than `END_GAP_NS` (1 s) after its block's last sample (samples missing: a file cut short) puts
  it one sample period after that sample instead, with a note.
"""

from __future__ import annotations

from pathlib import Path

from gazehdr.drivers.formats.eyelink.parser import AscParser
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sessionlog import FormatError, SessionLog


def read_eyelink_asc(
    path: Path,
    *,
    geometry: ScreenGeometry | None = None,
    missing: str | None = None,
    strict: bool = False,
    eye: str | None = None,
) -> SessionLog:
    """Read an EyeLink ASC file; `geometry` supplies what the file lacks (diagonal, distance),
    `missing` is `edf2asc -miss`'s string (`.` is always missing), `strict` refuses a file at
    its first line not understood (by default such lines become notes), `eye` (left, right or
    both) says what a sample-only file's samples hold, which it does not say itself."""
    path = Path(path)
    _refuse_binary(path)
    parser = AscParser(path, missing, strict, eye)
    with open(path, encoding="utf-8-sig", errors="replace") as f:  # an editor's BOM dropped
        for number, line in enumerate(f, 1):
            parser.line(number, line)
    return parser.finish(geometry)


_ASC_STARTS = (b"**", b"MSG", b"START", b"SAMPLES", b"EVENTS")


def _refuse_binary(path: Path) -> None:
    """A file that is not text (a NUL byte, or many control characters in its first 64 KiB)
    and has none of EDF2ASC's lines there: an EDF, an image, ... refused as such rather than
    read as lines of nothing. (An ASC file with a stray NUL is read: that line becomes a note.)"""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    control = sum(b < 32 and b not in b"\t\n\r\f\v" for b in head)
    asc = any(line.lstrip(b"\xef\xbb\xbf").startswith(_ASC_STARTS) for line in head.splitlines())
    if (b"\0" in head or control > len(head) // 100) and not asc:
        edf = path.suffix.lower() == ".edf"
        raise FormatError(
            path,
            None,
            None,
            "not an EyeLink ASC file: binary, not text"
            + (
                "; an EDF file is SR Research's binary format: convert it with SR Research's "
                f"edf2asc first (edf2asc {path.name}), then import the .asc"
                if edf
                else ""
            ),
        )


__all__ = ["read_eyelink_asc"]
