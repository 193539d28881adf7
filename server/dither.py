"""Temporal dithering to 8 bits, the rule the browser shader applies (Sec. 2.4 of the paper).

Each channel of each pixel of each frame is rounded up or down on its own, with probability
given by its fraction: `floor(255·v + u)`, `u ~ U[0, 1)`. The mean over frames is `255·v`, so
an 8-bit display shows dark gradations finer than one code value without banding.
"""

from __future__ import annotations

import numpy as np

from gazehdr.drivers.errors import InputError


def dither8(v: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Quantise display values `v` in [0, 1] to uint8 with a fresh uniform offset per entry.

    Values outside [0, 1] are clipped; NaN or Inf is an error (the simulator must not emit it,
    and casting it to uint8 would silently give garbage).
    """
    v = np.asarray(v, dtype=np.float32)
    if not np.isfinite(v).all():
        raise InputError("display values contain NaN or Inf")
    codes = np.floor(255.0 * v + rng.random(v.shape, dtype=np.float32))
    return np.clip(codes, 0, 255).astype(np.uint8)
