"""The kernels' parameter block `params_t`, generated from `Params`: one table, three views.

`FIELDS` lists the block in order. A field named after a `Params` field takes its C type and
length from that field's annotation (float, int, Vec3, Mat3), so the kernels see `Params` as
it is; the few derived fields (the plateau's logs, the tables of the display gamma and of n,
the contrast floor, the colour matrices, the band thresholds) say how they are computed. From
the table come the NumPy record (`PARAMS_DTYPE`, `pack_params`) and the C struct
(`params_struct`), which `cl_program.build_program` puts in front of every program: the two
cannot disagree, and the kernel files keep only a comment saying so.
Print the struct with `python -m gazehdr.sim.kernel_params`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from gazehdr.sim.layout import LMS_TO_RGB, RGB_TO_LMS, contrast_floor
from gazehdr.sim.params import MAX_BANDS, OURS, Params

#: Params annotation -> (C type, number of values); every field is 4 bytes, so neither side pads.
ANNOTATION_TYPES = {"float": ("float", 1), "int": ("int", 1), "bool": ("int", 1),
                    "Vec3": ("float", 3), "Mat3": ("float", 9)}  # fmt: skip
NUMPY_TYPES = {"float": "f4", "int": "i4"}


@dataclass(frozen=True)
class BlockField:
    """One member of `params_t`: its C type, how many values, and where they come from."""

    name: str
    ctype: str  # a key of NUMPY_TYPES
    count: int
    value: Callable[[Params], object]  # scalar or array-like of at most `count` values
    note: str  # the C comment

    @property
    def declaration(self) -> str:
        return f"{self.ctype} {self.name}" + (f"[{self.count}]" if self.count > 1 else "") + ";"


PARAMS_FIELDS = {f.name: f for f in dataclasses.fields(Params)}


def from_params(name: str) -> BlockField:
    """The `Params` field `name`, typed by its annotation (an unknown one is an error here)."""
    annotation = PARAMS_FIELDS[name].type
    if annotation not in ANNOTATION_TYPES:
        raise TypeError(f"Params.{name}: {annotation!r} has no C type in the kernels' block")
    ctype, count = ANNOTATION_TYPES[annotation]
    note = "ours" if name in OURS else "Appendix A"
    return BlockField(name, ctype, count, lambda p: getattr(p, name), f"Params.{name} ({note})")


def plateau_m(p: Params) -> float:
    """m of the plateau M(I) = I^m / (I^m + K^m) (ours, see Params.plateau_m_over_n)."""
    return p.n * p.plateau_m_over_n


@cache
def power_poly(power: float) -> tuple[float, ...]:
    """c0..c4 of q(t) with m^power = 1 + t q(t), t = m - 1 in [0, 1): a power's mantissa factor
    for `powv_binades` (kernels/common.cl), exact at m = 1. Least squares in the relative error
    on Chebyshev nodes, reweighted toward the largest errors (minimax). Kept per power: every
    session's block would fit the same one again (3 ms)."""
    k = np.arange(2000)
    t = (1 - np.cos(np.pi * (k + 0.5) / k.size)) / 2
    m = 1 + t
    target, weight = (m**power - 1) / t, t / m**power  # q's error times weight: the relative
    rows = np.vander(t, 5, increasing=True) * weight[:, None]
    reweight = np.ones_like(t)
    for _ in range(30):
        c = np.linalg.lstsq(rows * reweight[:, None], target * weight * reweight, rcond=None)[0]
        miss = np.abs(rows @ c - target * weight)
        reweight = np.sqrt(miss / miss.max() + 1e-3)
    return tuple(c)


def power_binades(power: float, share: int) -> np.ndarray:
    """2^(power (b - share)) for b in [0, 32), then 2^(power (32 a - 127 + share)) for a in
    [0, 16): 2^(power (e - 127)) of a biased exponent e = 32 a + b as two lookups
    (`powv_binades`), the first holding `share` of the bias. 31 for x in (0, 1] (the display
    gamma): both are then at most 1, and exactly 1 at x = 1. 0 for any x (the tone curve's I):
    the first is then at least 1, so the second runs to Inf only where x^power does. In float32
    the first stays finite and above 0 (power <= 4), so their product is never NaN."""
    exponents = np.arange(32) - share, 32 * np.arange(16) - 127 + share
    with np.errstate(over="ignore"):
        return (2.0 ** (power * np.concatenate(exponents))).astype(np.float32)


FIELDS: tuple[BlockField, ...] = (
    *map(from_params, ("gamma", "n", "a1", "a2", "b1", "b2", "c2", "j1", "j2", "m1", "m2",
                       "w_P", "w_S", "k_s", "g", "A_min", "bleach_display_gain",
                       "bleach_equivalent_light", "gain_along_adapting_light", "alpha_eps",
                       "Y_min", "surround")),
    BlockField("w_S_tone", "float", 3, Params.tone_scotopic_weights,
               "Params.tone_scotopic_weights(): w_S, or w_P without the Purkinje shift"),
    BlockField("ln_K_m", "float", 1, lambda p: plateau_m(p) * math.log(p.plateau_K),
               "m ln K of the plateau (ours)"),
    BlockField("n_minus_m", "float", 1, lambda p: p.n - plateau_m(p), "n - m"),
    BlockField("gamma_poly", "float", 5, lambda p: power_poly(p.gamma),
               "power_poly(gamma): m^gamma = 1 + t q(t), t = m - 1, q's coefficients"),
    BlockField("gamma_binades", "float", 48, lambda p: power_binades(p.gamma, 31),
               "power_binades(gamma, 31): 2^(gamma (b - 31)), then 2^(gamma (32 a - 96))"),
    BlockField("n_poly", "float", 5, lambda p: power_poly(p.n), "power_poly(n)"),
    BlockField("n_binades", "float", 48, lambda p: power_binades(p.n, 0),
               "power_binades(n, 0): 2^(n b), then 2^(n (32 a - 127))"),
    BlockField("contrast_floor", "float", 1, contrast_floor,
               "layout.contrast_floor: x below which a cone counts as dark"),
    from_params("H"),
    BlockField("rgb2lms", "float", 9, lambda p: RGB_TO_LMS, "layout.RGB_TO_LMS, row-major"),
    BlockField("lms2rgb", "float", 9, lambda p: LMS_TO_RGB, "layout.LMS_TO_RGB, row-major"),
    BlockField("rho_i", "float", MAX_BANDS, lambda p: p.rho_i(),
               "Params.rho_i(): band thresholds, finest band first; 0 past `bands`"),
    from_params("bands"),
)  # fmt: skip

PARAMS_DTYPE = np.dtype(
    [
        (f.name, NUMPY_TYPES[f.ctype]) if f.count == 1 else (f.name, NUMPY_TYPES[f.ctype], f.count)
        for f in FIELDS
    ]
)


def pack_params(p: Params) -> np.ndarray:
    """The block for `p` as one `PARAMS_DTYPE` record, the bytes the kernels read."""
    rec = np.zeros(1, PARAMS_DTYPE)
    for f in FIELDS:
        values = np.asarray(f.value(p)).ravel()
        row = np.zeros(f.count, NUMPY_TYPES[f.ctype])
        row[: values.size] = values
        rec[f.name] = row.reshape(rec[f.name].shape)
    return rec


def params_struct() -> str:
    """The C declaration of `params_t`, field for field as `PARAMS_DTYPE`."""
    members = [f"    {f.declaration:<19} // {f.note}" for f in FIELDS]
    header = "// params_t: generated by gazehdr.sim.kernel_params from Params; do not edit."
    return "\n".join([header, "typedef struct {", *members, "} params_t;", ""])


if __name__ == "__main__":
    print(params_struct(), end="")
