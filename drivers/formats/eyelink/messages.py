"""What EyeLink's own messages say, one message at a time (`MSG <time> <message>`, EyeLink 1000
Plus User Manual §4.9.3): the time offset some writers put first, the screen
(`DISPLAY_COORDS`, `GAZE_COORDS`), the recording configuration (`RECCFG`, `!MODE RECORD`,
`ELCLCFG`) and the validation results (`!CAL VALIDATION`). Pure functions of the text; the
parser keeps the state and the file's line numbers."""

from __future__ import annotations

import re
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.common import MAX_SCREEN_PX, finite_float

Box = tuple[float, float, float, float]

_OFFSET = re.compile(r"(-?\d{1,9})\s+(\S.*)", re.ASCII)
# Experiment Builder writes `DISPLAY_COORDS 0 0 1279 1023`; some other writers put an `=`.
_COORDS = re.compile(r"\b(DISPLAY_COORDS|GAZE_COORDS)\s*=?\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)")
_TRACKING = re.compile(r"^(?:RECCFG|!MODE\s+RECORD)\s+(CR|P)\b")
_MOUNT = re.compile(r"^ELCLCFG\s+(\S+)")
# `!CAL VALIDATION HV13 LR LEFT  GOOD ERROR 0.30 avg. 0.90 max  OFFSET ...`
_VALIDATION = re.compile(
    r"^!CAL\s+VALIDATION\s+(\S+)\s+\S+\s+(LEFT|RIGHT)\s+(\S+)\s+ERROR\s+(\S+)\s+avg\.\s+(\S+)\s+max"
)


class BadFieldError(InputError):
    """A message that names a thing this module reads, with a value that is not one."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(reason)
        self.field = field
        self.reason = reason


def split_offset(body: str) -> tuple[int, str]:
    """`<offset> <text>` → (offset in ms, text); (0, body) for a message without one.

    The event happened `offset` ms before the message's time stamp (SR Research FAQ "How can I
    take advantage of the timing offset in sending messages?"; Experiment Builder and Data
    Viewer write them).
    """
    match = _OFFSET.fullmatch(body)
    return (int(match[1]), match[2]) if match else (0, body)


def screen_box(body: str) -> tuple[str, Box] | None:
    """The `<left> <top> <right> <bottom>` of a `DISPLAY_COORDS` or `GAZE_COORDS` message, with
    its keyword; None for any other message; `BadFieldError` when the numbers are not a screen."""
    match = _COORDS.search(body)
    if match is None:
        return None
    try:
        box = tuple(finite_float(v) for v in match.group(2, 3, 4, 5))
    except ValueError:
        raise BadFieldError(match[1], f"expected four numbers, got {match[0]!r}") from None
    left, top, right, bottom = box
    if right <= left or bottom <= top:
        raise BadFieldError(match[1], f"an empty screen: {match[0]!r}")
    if right - left >= MAX_SCREEN_PX or bottom - top >= MAX_SCREEN_PX:
        raise BadFieldError(match[1], f"larger than any screen: {match[0]!r}")
    return match[1], (left, top, right, bottom)


def tracker_facts(body: str) -> dict[str, Any]:
    """What a configuration message says of the recording: `tracking` ("CR" or "P", from
    `RECCFG <mode> <rate> <filters> <eyes>` or `!MODE RECORD ...`), `mount` (`ELCLCFG`'s
    mount code, e.g. BTABLER for a desktop mount); {} for any other message."""
    facts: dict[str, Any] = {}
    if match := _TRACKING.match(body):
        facts["tracking"] = match[1]
    if match := _MOUNT.match(body):
        facts["mount"] = match[1]
    return facts


def validation(body: str) -> dict[str, Any] | None:
    """One eye's result of `!CAL VALIDATION ...`: eye, the calibration type (HV9, HV13, ...),
    the tracker's verdict (GOOD, FAIR, POOR) and the average and largest error in degrees;
    None for any other message (an aborted validation reports no error)."""
    match = _VALIDATION.match(body)
    if match is None:
        return None
    try:
        average, largest = finite_float(match[4]), finite_float(match[5])
    except ValueError:
        return None
    return {
        "eye": match[2].lower(),
        "type": match[1],
        "result": match[3],
        "error_avg_deg": average,
        "error_max_deg": largest,
    }
