"""The model observer's brightness of one interval of a trial, computed from the frames shown
(docs/experiment-analysis.md, "The model observer").

An interval is what the page shows: display values `v` per frame, for the design's monitor
(`DisplayModel`), from which the model takes cd/m² per channel (linear Rec. 709 / sRGB, D65).

1. **Colour: the Helmholtz–Kohlrausch effect** (Nayatani 1997, "Simple estimation methods for
   the Helmholtz–Kohlrausch effect", Color Res. Appl. 22:385–401). Each pixel's luminance Y is
   replaced by the luminance of the grey that looks as bright, `Y_eq = Y · Γ`, Nayatani's
   estimate for luminous colours:

       Γ_obj = 1 + (c · q(θ) + 0.0872 · K_Br(L_a)) · s_uv,      Γ = 0.4462 · (Γ_obj + 0.3086)³

   with s_uv = 13·|(u', v') − (u'_w, v'_w)| the saturation and θ the hue angle in the CIE 1976
   u'v' diagram around the display's white (D65), q(θ) Nayatani's hue function, K_Br his
   adapting-luminance factor (1 at 63.66 cd/m², 0.27 in the dark), L_a the frame's mean
   luminance, and c = −0.1340 for the variable-achromatic-colour method (VAC: the grey is
   matched to the colour, the default) or −0.8660 for the variable-chromatic-colour one (VCC).
   Γ is divided by its value for a grey (0.99993) so that a grey is exactly its luminance.
   `hk = "none"` keeps Y: a luminance-only observer.
2. **Space**: a frame's signal E(t) is the mean of Y_eq over the frame (the whole image: the
   flash and its afterimage, or the ColorChecker, the gaze on the fixation target).
3. **Time: Bloch's law.** Below a critical duration t_c light is summed (brightness depends on
   luminance × time), beyond it not; t_c ≈ 0.1 s in the dark-adapted eye (Barlow 1958,
   J. Physiol. 141:337–350). The interval's brightness B is the largest mean of E over any
   window of `window` s within it (cd/m²), so a 50 ms flash is summed with the first 50 ms
   after it, where an afterimage adds; `window = inf` averages the whole interval
   (Talbot–Plateau: what a long integration would give the afterimage at most).

`log10_brightness` returns log10 B; the observer (`observer.ModelObserver`) adds its noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.display import DisplayModel
from gazehdr.sim.layout import RGB_TO_XYZ

#: Nayatani's (1997) method coefficients of q(θ): the grey adjusted to the colour (VAC) or the
#: colour adjusted to the grey (VCC); "none": luminance only.
HK_METHODS = {"VAC": -0.1340, "VCC": -0.8660, "none": 0.0}
#: u'v' of the display's white, D65 (the white of linear Rec. 709 / sRGB).
WHITE_UV = (0.19783001, 0.46831999)
#: Bloch's critical duration in the dark-adapted eye, s (Barlow 1958).
BLOCH_S = 0.1
#: B below this counts as this (log10 B = -30 for an all-black interval, never -inf).
FLOOR_CD_M2 = 1e-30
_GREY = 0.4462 * 1.3086**3  # Γ of an achromatic colour, to which Γ is normalised
_CHUNK = 16  # frames converted at a time: a 480×270 clip would need 0.5 GB at once


@dataclass(frozen=True, eq=False)
class Interval:
    """One interval as shown: `frames` (N×H×W×3 display values v for `display`), the time each
    frame starts at (s, increasing) and when the last one ends."""

    frames: np.ndarray
    times: np.ndarray
    end: float
    display: DisplayModel

    def __post_init__(self) -> None:
        f, t = np.asarray(self.frames), np.asarray(self.times, dtype=float)
        if f.ndim != 4 or f.shape[-1] != 3 or len(f) == 0:
            raise InputError(f"frames must be N×H×W×3 with N >= 1, got shape {f.shape}")
        if t.shape != (len(f),):
            raise InputError(f"one time per frame: {len(f)} frames, times of shape {t.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0) and t[-1] < self.end):
            raise InputError("frame times must be finite, increasing and end before `end`")
        if not np.all(np.isfinite(f)):
            raise InputError("frames hold NaN or infinite display values")


def q_nayatani(theta: np.ndarray) -> np.ndarray:
    """Nayatani's (1997) hue function q(θ), θ the u'v' hue angle in radians."""
    t = np.asarray(theta, dtype=float)
    return (
        -0.01585
        - 0.03017 * np.cos(t)
        - 0.04556 * np.cos(2 * t)
        - 0.02667 * np.cos(3 * t)
        - 0.00295 * np.cos(4 * t)
        + 0.14592 * np.sin(t)
        + 0.05084 * np.sin(2 * t)
        - 0.01900 * np.sin(3 * t)
        - 0.00764 * np.sin(4 * t)
    )


def k_br(adapting_cd_m2: np.ndarray | float) -> np.ndarray:
    """Nayatani's (1997) K_Br: how the effect grows with the adapting luminance L_a (cd/m²)."""
    a = np.power(np.maximum(np.asarray(adapting_cd_m2, dtype=float), 0.0), 0.4495)
    return 0.2717 * (6.469 + 6.362 * a) / (6.469 + a)


def hk_gamma(xyz: np.ndarray, adapting_cd_m2: np.ndarray | float, method: str) -> np.ndarray:
    """Γ = Y_eq / Y of each colour (XYZ in the last axis), normalised to 1 for a grey; black
    pixels, which have no chromaticity, count as grey."""
    c = HK_METHODS[method]
    X, Y, Z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    den = X + 15.0 * Y + 3.0 * Z
    lit = den > 1e-12
    safe = np.where(lit, den, 1.0)
    du = np.where(lit, 4.0 * X / safe, WHITE_UV[0]) - WHITE_UV[0]
    dv = np.where(lit, 9.0 * Y / safe, WHITE_UV[1]) - WHITE_UV[1]
    s_uv = 13.0 * np.hypot(du, dv)
    g_obj = 1.0 + (c * q_nayatani(np.arctan2(dv, du)) + 0.0872 * k_br(adapting_cd_m2)) * s_uv
    return 0.4462 * np.maximum(g_obj + 0.3086, 0.0) ** 3 / _GREY


def frame_signal(interval: Interval, hk: str = "VAC") -> np.ndarray:
    """E(t): each frame's mean equivalent luminance Y_eq (cd/m²)."""
    if hk not in HK_METHODS:
        raise InputError(f"hk must be one of {', '.join(HK_METHODS)}, got {hk!r}")
    out = []
    for i in range(0, len(interval.frames), _CHUNK):
        rgb = interval.display.cd_m2(interval.frames[i : i + _CHUNK])
        xyz = rgb @ RGB_TO_XYZ.T
        Y = xyz[..., 1]
        n = len(Y)
        if hk == "none":
            out.append(Y.reshape(n, -1).mean(axis=1))
            continue
        L_a = Y.reshape(n, -1).mean(axis=1)[:, None, None]
        out.append((Y * hk_gamma(xyz, L_a, hk)).reshape(n, -1).mean(axis=1))
    return np.concatenate(out)


def windowed_peak(signal: np.ndarray, times: np.ndarray, end: float, window: float) -> float:
    """The largest mean of the piecewise-constant `signal` (frame i from times[i] to the next
    frame's time, or `end`) over any window of `window` s inside [times[0], end]; a window at
    least as long as that is the mean over all of it."""
    if not window > 0:
        raise InputError(f"window must be a positive number of seconds, got {window!r}")
    bounds = np.append(np.asarray(times, dtype=float), float(end))
    area = np.concatenate([[0.0], np.cumsum(signal * np.diff(bounds))])
    total = bounds[-1] - bounds[0]
    if window >= total:
        return float(area[-1] / total)
    starts = np.concatenate([bounds, bounds - window])
    starts = starts[(starts >= bounds[0]) & (starts + window <= bounds[-1])]
    sums = np.interp(starts + window, bounds, area) - np.interp(starts, bounds, area)
    return float(sums.max() / window)


def log10_brightness(interval: Interval, window: float = BLOCH_S, hk: str = "VAC") -> float:
    """log10 of the interval's brightness B (cd/m² of an equally bright grey, held over the
    window): finite for every interval, black included."""
    b = windowed_peak(frame_signal(interval, hk), interval.times, interval.end, window)
    return math.log10(max(b, FLOOR_CD_M2))
