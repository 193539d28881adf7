"""An estimate of a relative image's absolute scale (cd/m^2 per unit), labelled as one.

Most HDR files (photographs, HDRIs, renders) are relative: their values are right in ratio
but in no stated unit. The rule maps what a light meter would read to what the photographic
exposure tables give for such a scene:

- the statistic: the median of log10 luminance (Rec.709 weights) over the pixels that have
  light. An averaging reflected-light meter reads about the log-average of the scene (the
  image's "key", Reinhard et al. 2002, "Photographic tone reproduction for digital images");
  the median is that, robust to a sun disc or a black border;
- the typical luminance: the exposure value tabulated for the scene kind at ISO 100 (ANSI
  PH2.7-1986 exposure guide, as tabulated in Wikipedia's "Exposure value", Table 2), turned
  into the luminance a meter calibrated per ISO 2720 reads for it: L = 2^EV · K / S with
  K = 12.5 cd/m², S = 100;
- the scale is L / 10^median.

The kind is the user's choice; without one, a kind named by a word of the scene's name
(Blender's `night.exr`, `interior.exr`, `sunset.exr`) is taken, else `daylight`, the commonest
HDRI. The estimate says all of this in its `note`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError

#: Rec.709 luminance weights (the model's w_P).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)
METER_K = 12.5  # cd/m^2, ISO 2720's reflected-light meter calibration constant
METER_S = 100.0  # ISO speed of the table


@dataclass(frozen=True)
class Kind:
    ev: float  # EV100 of the ANSI PH2.7 table
    what: str  # the table's line


#: Scene kinds, each with the table's exposure value (the middle of a range).
KINDS: dict[str, Kind] = {
    "daylight": Kind(15.0, "typical scene in full or slightly hazy sunlight"),
    "overcast": Kind(12.0, "typical scene, heavy overcast"),
    "sunset": Kind(12.0, "at sunset"),
    "office": Kind(7.5, "offices and work areas"),
    "interior": Kind(6.0, "home interiors"),
    "street": Kind(7.5, "night street scenes and window displays"),
    "moonlight": Kind(-2.5, "full moonlight"),
}
DEFAULT_KIND = "daylight"
#: Words of a scene name that name a kind.
HINTS = {
    "sunrise": "sunset", "dusk": "sunset", "dawn": "sunset", "indoor": "interior",
    "room": "interior", "night": "street", "city": "daylight", "cloudy": "overcast",
    "moon": "moonlight",
}  # fmt: skip


@dataclass(frozen=True)
class Estimate:
    scale: float  # cd/m^2 per unit
    kind: str
    median_log10: float  # the statistic, log10 of the image's units
    note: str


def kind_luminance(kind: str) -> float:
    """The luminance (cd/m^2) a meter reads for a scene of `kind`."""
    return 2.0 ** KINDS[kind].ev * METER_K / METER_S


def guess_kind(name: str) -> str:
    """The kind a word of `name` names, else the default."""
    for word in re.split(r"[^a-z]+", name.lower()):
        if word in KINDS:
            return word
        if word in HINTS:
            return HINTS[word]
    return DEFAULT_KIND


def check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise InputError(f"unknown scene kind {kind!r}; one of {', '.join(KINDS)}")
    return kind


def median_log10_luminance(rgb: np.ndarray) -> float:
    """The statistic: median log10 luminance of the lit, finite pixels (0 if none)."""
    y = np.asarray(rgb, np.float32).reshape(-1, 3) @ LUMINANCE
    lit = y[np.isfinite(y) & (y > 0)]
    return float(np.median(np.log10(lit))) if lit.size else 0.0


def estimate(rgb: np.ndarray, kind: str) -> Estimate:
    """The scale that puts the median luminance of `rgb` at `kind`'s metered luminance."""
    return estimate_from(median_log10_luminance(rgb), kind)


def estimate_from(median: float, kind: str) -> Estimate:
    """`estimate` of an image whose statistic (`median_log10_luminance`) is `median`."""
    target = kind_luminance(check_kind(kind))
    scale = target / 10.0**median
    k = KINDS[kind]
    note = (
        f"estimate: median luminance {10**median:.3g} units → {target:.3g} cd/m² "
        f"({kind}: EV {k.ev:g}, {k.what})"
    )
    if not math.isfinite(scale) or scale <= 0:  # an image of extreme values: leave it as is
        return Estimate(1.0, kind, median, "estimate impossible (extreme values): 1 cd/m²/unit")
    return Estimate(scale, kind, median, note)
