"""Mikamo et al. 2012, "Perceptually based afterimage synthesis": the NumPy reference.

Per retina cell (the grid of Jacobs et al., locked to the retina), our reading of the paper
(docs/baselines/mikamo.md):

- trigger: the cell's photopic input falls by at least `mikamo_drop_log10` log units within one
  step (the light goes off, the eyes close or the eye moves off the light) while its previous
  input was in the top `mikamo_top_fraction` of the luminance of I_on, the scene of the
  previous step (Sec. 3-4: the threshold mask of I_on);
- at the trigger it latches Z = (L*_on / L*_on_max)^gamma (Eq. 2-4) and the normalised colour
  difference (Delta a, Delta b) of I'_on from Padgham's reference chromaticity at the same
  luminance (Eq. 1), and its age restarts at 0;
- then L_A = L_M(age) Z, a_A = a_M(age) Z + tau_M(age) Delta a, b_A likewise (Eq. 2-4), with
  L_M, a_M, b_M from the colour sequence file and tau_M = L_M / L_M(0); after the file's last
  row the cell is cleared;
- L*a*b* -> XYZ -> linear RGB, negatives clamped and the luminance restored (the gamut fix),
  a fixed Gaussian low-pass, times `mikamo_strength`: the additive maps[3:6]; gains are 1.

State planes: the previous input L, M, S (I_on at the cell), Z, Delta a, Delta b, age. With
Z = Delta a = Delta b = 0 a cell shows nothing, so a fresh or reset retina has no afterimage.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Generic

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.layout import LMS_TO_RGB, RGB_TO_XYZ
from gazehdr.sim.models import Gaze, ReferenceStageBackend, StageBackendT
from gazehdr.sim.params import Params
from gazehdr.sim.reference import blur2d, retina_input

SHIPPED_SEQUENCE = "padgham1968.csv"
COLUMNS = ("t_s", "Y", "x", "y")
STATE_CHANNELS = 7
XYZ_TO_RGB = np.linalg.inv(RGB_TO_XYZ)
LMS_TO_XYZ = RGB_TO_XYZ @ LMS_TO_RGB
#: The L*a*b* white: display white, D65 with Y = 1 (1 = display white in the additive map).
WHITE_XYZ = RGB_TO_XYZ.sum(axis=1)
_KNEE = (6.0 / 29.0) ** 3
LUMINANCE_EPS = 1e-12  # display units; a clamped colour darker than this is black
#: Ours: the mask keeps cells within this relative distance below the threshold, so that the
#: interior of a flat light at the threshold is not holed by the rounding of bilinear samples.
MASK_SLACK = 1e-5


class SequenceError(InputError):
    """A colour sequence file that cannot be used; the message names file, line and field."""


# --- colour spaces ---------------------------------------------------------------------------


def lab_f(t: np.ndarray) -> np.ndarray:
    """The CIE L*a*b* companding function (cube root, linear below the knee)."""
    t = np.asarray(t, np.float64)
    return np.where(t > _KNEE, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)


def lab_f_inv(f: np.ndarray) -> np.ndarray:
    f = np.asarray(f, np.float64)
    return np.where(f > 6 / 29, f**3, 3 * (6 / 29) ** 2 * (f - 4 / 29))


def xyY_to_XYZ(Y: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Yxy -> XYZ, stacked on the first axis (y > 0)."""
    Y, x, y = (np.asarray(v, np.float64) for v in (Y, x, y))
    return np.stack([x / y * Y, Y, (1 - x - y) / y * Y])


def lab_of_ratios(r: np.ndarray) -> np.ndarray:
    """L*a*b* of X/X_n, Y/Y_n, Z/Z_n (first axis)."""
    fx, fy, fz = lab_f(r)
    return np.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)])


def XYZ_to_lab(xyz: np.ndarray, white: np.ndarray = WHITE_XYZ) -> np.ndarray:
    """XYZ (first axis) -> L*a*b* for a white of the same units."""
    w = np.asarray(white, np.float64).reshape((3,) + (1,) * (np.ndim(xyz) - 1))
    return lab_of_ratios(np.asarray(xyz, np.float64) / w)


def lab_to_XYZ(lab: np.ndarray, white: np.ndarray = WHITE_XYZ) -> np.ndarray:
    L, a, b = np.asarray(lab, np.float64)
    fy = (L + 16) / 116
    w = np.asarray(white, np.float64).reshape((3,) + (1,) * (np.ndim(L)))
    return w * lab_f_inv(np.stack([fy + a / 500, fy, fy - b / 200]))


def xy_of_rgb(rgb: np.ndarray) -> np.ndarray:
    """Chromaticity (x, y) of linear RGB (first axis); for tests and figures."""
    xyz = np.tensordot(RGB_TO_XYZ, np.asarray(rgb, np.float64), axes=1)
    s = xyz.sum(axis=0)
    return xyz[:2] / np.where(s > 0, s, 1.0)


def chroma_of_xy(x: float, y: float) -> tuple[float, float]:
    """(a*, b*) of chromaticity (x, y) at L* = 100, i.e. with the white scaled to its
    luminance. Above the L*a*b* knee the direction of a colour difference does not depend on
    that scale, so this is Eq. 1's direction for any white."""
    _, a, b = XYZ_to_lab(xyY_to_XYZ(1.0, x, y))
    return float(a), float(b)


# --- the colour sequence file ----------------------------------------------------------------


@dataclass(frozen=True)
class ColourSequence:
    """Padgham's afterimage sequence: time (s), luminance relative to the start, chromaticity."""

    t: np.ndarray
    Y: np.ndarray
    x: np.ndarray
    y: np.ndarray
    source: str

    @property
    def duration(self) -> float:
        """Seconds after which the afterimage is gone (the last row)."""
        return float(self.t[-1])

    def lab(self) -> np.ndarray:
        """(n, 3) L_M, a_M, b_M of the rows (display white, so Y = 1 gives L* = 100)."""
        return XYZ_to_lab(xyY_to_XYZ(self.Y, self.x, self.y)).T


def _number(text: str, source: str, line: int, field: str) -> float:
    try:
        value = float(text)
    except ValueError:
        problem = f"{text!r} is not a number"
        raise SequenceError(f"{source}, line {line}: field {field!r}: {problem}") from None
    if not math.isfinite(value):
        raise SequenceError(f"{source}, line {line}: field {field!r}: must be finite, got {text}")
    return value


def parse_sequence(text: str, source: str) -> ColourSequence:
    """Parse the CSV format of data/padgham1968.csv; every problem is a SequenceError."""
    header: list[str] | None = None
    rows: list[tuple[float, ...]] = []
    last_line = 0
    for line, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if header is None:
            if sorted(fields) != sorted(COLUMNS):
                # The line is not echoed: the path may point at a file that is not ours.
                raise SequenceError(
                    f"{source}, line {line}: field 'header': must name the columns "
                    f"{','.join(COLUMNS)} (any order)"
                )
            header = fields
            continue
        if len(fields) != len(header):
            raise SequenceError(
                f"{source}, line {line}: expected {len(header)} fields, got {len(fields)}"
            )
        v = {name: _number(f, source, line, name) for name, f in zip(header, fields, strict=True)}

        def bad(field: str, problem: str, line: int = line) -> SequenceError:
            return SequenceError(f"{source}, line {line}: field {field!r}: {problem}")

        if not rows and v["t_s"] != 0.0:
            raise bad("t_s", f"the first row must be at t_s = 0, got {v['t_s']}")
        if rows and v["t_s"] <= rows[-1][0]:
            raise bad("t_s", f"times must increase strictly, {v['t_s']} after {rows[-1][0]}")
        if v["Y"] < 0 or (not rows and v["Y"] <= 0):
            raise bad("Y", f"must be {'> 0 in the first row' if not rows else '>= 0'}")
        for field in ("x", "y"):
            if v[field] <= 0:
                raise bad(field, f"a chromaticity must be > 0, got {v[field]}")
        if v["x"] + v["y"] > 1:
            raise bad("y", f"x + y must be <= 1, got {v['x'] + v['y']}")
        rows.append(tuple(v[c] for c in COLUMNS))
        last_line = line
    if header is None:
        raise SequenceError(f"{source}: no header line {','.join(COLUMNS)}")
    if len(rows) < 2:
        raise SequenceError(
            f"{source}, line {last_line}: needs at least two rows, found {len(rows)}"
        )
    t, Y, x, y = (np.array(c, np.float64) for c in zip(*rows, strict=True))
    return ColourSequence(t, Y, x, y, source)


def load_sequence(path: str | Path = "") -> ColourSequence:
    """The sequence in `path`, or the shipped one for "" (Params.mikamo_sequence)."""
    if not str(path):
        res = resources.files("gazehdr.sim") / "data" / SHIPPED_SEQUENCE
        return parse_sequence(res.read_text(encoding="utf-8"), f"<shipped {SHIPPED_SEQUENCE}>")
    file = Path(path).expanduser()
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{file}: cannot read the colour sequence: {exc}") from exc
    return parse_sequence(text, str(file))


# --- the model ---------------------------------------------------------------------------------


def check_params(p: Params) -> None:
    """The Mikamo parameters must make sense before any frame is made."""
    checks = {
        "mikamo_top_fraction": 0 < p.mikamo_top_fraction <= 1,
        "mikamo_gamma": math.isfinite(p.mikamo_gamma) and p.mikamo_gamma > 0,
        "mikamo_drop_log10": math.isfinite(p.mikamo_drop_log10) and p.mikamo_drop_log10 > 0,
        "mikamo_lowpass_deg": math.isfinite(p.mikamo_lowpass_deg) and p.mikamo_lowpass_deg >= 0,
        "mikamo_strength": math.isfinite(p.mikamo_strength) and p.mikamo_strength >= 0,
    }
    for name, ok in checks.items():
        if not ok:
            raise InputError(f"parameter {name} is out of range: {getattr(p, name)}")
    x, y = p.mikamo_reference_xy
    if not (x > 0 and y > 0 and x + y < 1):
        raise InputError(f"mikamo_reference_xy must be a chromaticity, got {(x, y)}")


def scene_stats(yp: np.ndarray, p: Params) -> tuple[float, float]:
    """Mask threshold (the top fraction's quantile, less MASK_SLACK) and maximum of the low-res
    Y_P of I_on. The quantile is over the cells that have light (Y_P > Y_min): the black bars
    of a letterboxed image are no part of the scene, and counted in they made the image's
    ordinary content "the top 5 %", whose afterimage then covered the bars (an olive blob, the
    colour of Padgham's sequence) whenever the gaze moved there."""
    yp = np.asarray(yp, np.float64)
    lit = yp[yp > p.Y_min]
    thr = np.quantile(lit if lit.size else yp, 1.0 - p.mikamo_top_fraction) * (1.0 - MASK_SLACK)
    return float(thr), float(yp.max())


def delta_ab(lms: np.ndarray, ref_ab: tuple[float, float], p: Params) -> np.ndarray:
    """Eq. 1: (Delta a, Delta b) of the input's colour against the reference chromaticity at
    the same luminance, in L*a*b* with the white scaled to that luminance (L* = 100); 0 where
    the input is darker than Y_min (no colour to speak of)."""
    xyz = np.tensordot(LMS_TO_XYZ, lms, axes=1)
    Y = xyz[1]
    lit = Y > p.Y_min
    _, a, b = lab_of_ratios(xyz / (WHITE_XYZ[:, None, None] * np.where(lit, Y, 1.0)))
    da, db = a - ref_ab[0], b - ref_ab[1]
    norm = np.maximum(np.hypot(da, db), p.mikamo_delta_e_floor)
    return np.where(lit, np.stack([da, db]) / norm, 0.0)


def photopic(lms: np.ndarray, p: Params) -> np.ndarray:
    """Y_P of cone input (the luminance of the low-res map's plane 3)."""
    return np.tensordot(np.asarray(p.w_P), np.tensordot(LMS_TO_RGB, lms, axes=1), axes=1)


def z_weight(y_on: np.ndarray, y_max: float, gamma: float) -> np.ndarray:
    """Z = (L*_on / L*_on_max)^gamma (Eq. 2-4): L* of I'_on with I_on's brightest cell as the
    white, so L*_on_max = 100."""
    if not y_max > 0:
        return np.zeros_like(np.asarray(y_on, np.float64))
    L = np.clip(116 * lab_f(np.asarray(y_on, np.float64) / y_max) - 16, 0.0, 100.0)
    return (L / 100.0) ** gamma


def gamut_fix(rgb: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Sec. 3: negative RGB clamped to 0, then the luminance set back to `Y` (at the clamped
    colour's chromaticity, so no channel goes negative again)."""
    c = np.maximum(rgb, 0.0)
    Yc = np.tensordot(RGB_TO_XYZ[1], c, axes=1)
    ok = Yc > LUMINANCE_EPS
    return c * np.where(ok, np.maximum(Y, 0.0) / np.where(ok, Yc, 1.0), 0.0)


class MikamoModel(Generic[StageBackendT]):
    """Host-side part both backends share: the sequence, its L*a*b* table, the parameters,
    and the I_on statistics of the mask (prepared() runs on every scene or eyelid change)."""

    state_channels = STATE_CHANNELS

    def __init__(self, backend: StageBackendT, seed: int) -> None:
        self.backend, self.p, self.lay = backend, backend.p, backend.lay
        check_params(self.p)
        self.sequence = load_sequence(self.p.mikamo_sequence)
        self.lab = self.sequence.lab()  # rows of L_M, a_M, b_M
        self.ref_ab = chroma_of_xy(*self.p.mikamo_reference_xy)
        self.lowpass_cells = self.lay.px(self.p.mikamo_lowpass_deg) / self.lay.cell
        self._scene = (0.0, 0.0)  # (threshold, max) of the scene on view now
        self._on: tuple[float, float] | None = None  # ... of the scene at the previous step

    def prepared(self) -> None:
        self._scene = scene_stats(self.backend.get("down")[3], self.p)

    def on_stats(self, reset: bool) -> tuple[float, float]:
        """The mask threshold and maximum of I_on: the scene the previous step saw, since a
        trigger compares the previous input with the current one."""
        on = self._scene if reset or self._on is None else self._on
        self._on = self._scene
        return on


class MikamoReference(MikamoModel[ReferenceStageBackend]):
    """The NumPy oracle of MikamoOpenCL."""

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        a = self.backend.a
        lms = retina_input(a["down"], a["surround"], gaze, self.lay)
        a["state"] = self.step(a["state"], lms, self.on_stats(reset), dt, reset)
        add = blur2d(self.afterimage_rgb(a["state"]), self.lowpass_cells)  # the fixed low-pass
        a["maps"] = np.concatenate([np.ones_like(add), add])

    def step(
        self, state: np.ndarray, lms: np.ndarray, on: tuple[float, float], dt: float, reset: bool
    ) -> np.ndarray:
        """Advance the cells' ages, clear the expired ones, latch Z and Eq. 1 where they fire."""
        if reset:
            return np.concatenate([lms, np.zeros((4, *lms.shape[1:]))])
        p = self.p
        lms_prev = state[:3]
        y_prev, y_now = (photopic(v, p) for v in (lms_prev, lms))
        age = state[6] + dt
        live = age <= self.sequence.duration
        latched = np.where(live, state[3:6], 0.0)
        age = np.where(live, age, 0.0)
        thr, y_max = on
        drop = 10.0**p.mikamo_drop_log10
        fire = (y_prev >= thr) & (np.maximum(y_prev, p.Y_min) >= drop * np.maximum(y_now, p.Y_min))
        on_cell = np.concatenate(
            [z_weight(y_prev, y_max, p.mikamo_gamma)[None], delta_ab(lms_prev, self.ref_ab, p)]
        )
        latched = np.where(fire, on_cell, latched)
        age = np.where(fire, 0.0, age)
        return np.concatenate([lms, latched, age[None]])

    def afterimage_rgb(self, state: np.ndarray) -> np.ndarray:
        """Eq. 2-4 at each cell's age, L*a*b* -> linear RGB, gamut fix, strength."""
        Z, da, db, age = state[3], state[4], state[5], state[6]
        t = self.sequence.t
        L_M, a_M, b_M = (np.interp(age, t, self.lab[:, k]) for k in range(3))
        tau = L_M / self.lab[0, 0]  # L_M(0) > 0: the file's first Y is positive
        xyz = lab_to_XYZ(np.stack([L_M * Z, a_M * Z + tau * da, b_M * Z + tau * db]))
        rgb = np.tensordot(XYZ_TO_RGB, xyz, axes=1)
        return self.p.mikamo_strength * gamut_fix(rgb, xyz[1])
