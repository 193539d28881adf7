"""What the importers share: exact decimal times, finite floats, telling numbers from labels, the
mean of two eyes, the order of events at one time, and a screen geometry with what a file
records put in."""

from __future__ import annotations

import math
from dataclasses import replace
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import EyeSample, ScreenGeometry


def decimal_ns(text: str, unit_ns: int) -> int:
    """A decimal time string in some unit (`unit_ns` ns each) → integer ns, exactly.

    Through `Decimal`, so "2154556.5" ms is 2154556500000 ns with no float rounding.
    Raises ValueError for anything but a finite number.
    """
    try:
        value = Decimal(text.strip())
    except InvalidOperation:
        raise InputError(f"not a number: {text!r}") from None
    if not value.is_finite():
        raise InputError(f"not a finite number: {text!r}")
    return int((value * unit_ns).to_integral_value(ROUND_HALF_EVEN))


def finite_float(text: str) -> float:
    """A finite float from text, or ValueError."""
    value = float(text)
    if not math.isfinite(value):
        raise InputError(f"not a finite number: {text!r}")
    return value


def is_number(text: str) -> bool:
    """Whether `text` reads as a float (inf and nan included): what tells data from labels."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def mean_of_eyes(*eyes: EyeSample | None) -> tuple[float, float] | None:
    """The mean position of the eyes that have one, or None when no eye has."""
    found = [e for e in eyes if e is not None and math.isfinite(e.x) and math.isfinite(e.y)]
    if not found:
        return None
    return sum(e.x for e in found) / len(found), sum(e.y for e in found) / len(found)


#: Pixels on a side beyond any display: a screen resolution this large is garbled, and would make
#: every later conversion to degrees meaningless. The readers refuse it.
MAX_SCREEN_PX = 65_536

_END_ORDER = {"blink": 0, "saccade": 1, "fixation": 2}
_START_ORDER = {"saccade": 0, "blink": 1, "fixation": 2}


def sort_events(events: list[Any]) -> list[Any]:
    """Events in the order importers give them at one time, so that every format gives one log
    the same order: left eye (or none) before right; ends before starts, but an event that
    starts and ends at one time starts first; a blink ends before the saccade around it, and
    that saccade starts before the blink (EyeLink nests them so)."""
    starts = {
        (e.kind.partition("_")[0], e.id, e.eye, e.t_ns) for e in events if e.kind.endswith("_start")
    }

    def key(e: Any) -> tuple[int, bool, int, int]:
        family, _, phase = e.kind.partition("_")
        if phase != "end":
            return (e.t_ns, e.eye == "right", 1, _START_ORDER.get(family, 3))
        instant = (family, e.id, e.eye, e.t_ns) in starts
        return (e.t_ns, e.eye == "right", 2 if instant else 0, _END_ORDER.get(family, 3))

    return sorted(events, key=key)


def geometry_with(
    base: ScreenGeometry | None,
    *,
    width_px: int | None = None,
    height_px: int | None = None,
    diagonal_m: float | None = None,
    distance_m: float | None = None,
) -> ScreenGeometry:
    """`base` (or the defaults) with the values a file recorded put in."""
    g = base or ScreenGeometry()
    changes: dict[str, Any] = {}
    if width_px is not None:
        changes["screen_width_px"] = int(width_px)
    if height_px is not None:
        changes["screen_height_px"] = int(height_px)
    if diagonal_m is not None:
        changes["screen_diagonal_m"] = float(diagonal_m)
    if distance_m is not None:
        changes["viewing_distance_m"] = float(distance_m)
    return replace(g, **changes)
