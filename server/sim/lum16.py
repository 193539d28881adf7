"""G and the acuity levels in 16 bits a channel: the kernels' format (common.cl, `to_lum16v`).

A luminance in cd/m² keeps a float's exponent in 6 bits, counted from 2^-30, and the top 10
bits of its mantissa, rounded to nearest: 9.3e-10 .. 1.7e10 cd/m² (`Params.radiance_max` is
1e10) within 2^-11 of the value, 0 below that range and 1.7e10 above it. Half a float's
bytes: the acuity stage takes 0.79× as long at 1920×1080 as with float levels and a float G
(docs/performance.md, "Acuity"). IEEE half floats would not do: they end at 65504 cd/m². What
the display shows of G is 10 bits a channel after a compressive tone curve, so 2^-11 of G
moves it less than half of a 10-bit step; the tests hold G to this precision against the
float64 reference.
"""

from __future__ import annotations

import numpy as np

#: The float32 bits of 2^-30, the smallest exponent kept (code 0 stands for 0).
EXP0 = (127 - 30) << 23
#: The largest relative error of a value inside the range (half a step of 10 mantissa bits).
PRECISION = 2.0**-11
SMALLEST = 2.0**-30 * (1 + 2.0**-10)  # code 1
LARGEST = 2.0**33 * (2 - 2.0**-10)  # code 65535


def encode(x: np.ndarray) -> np.ndarray:
    """cd/m² (float32 or wider, >= 0) to codes, as the kernels' `to_lum16v`, bit for bit."""
    bits = np.asarray(x, np.float32).view(np.int32).astype(np.int64)
    return np.clip((bits - EXP0 + (1 << 12)) >> 13, 0, 65535).astype(np.uint16)


def decode(codes: np.ndarray) -> np.ndarray:
    """Codes to float32 cd/m², as the kernels' `from_lum16v`."""
    c = np.asarray(codes, np.uint16).astype(np.uint32)
    values = ((c << 13) + EXP0).view(np.float32)
    return np.where(c == 0, np.float32(0), values)
