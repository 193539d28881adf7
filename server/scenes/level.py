"""What a server keeps of an uploaded image: a level no larger than any frame of it shows.

A session fits its scene to its frame (`gazehdr.sim.layout.fit_to_frame`: keeping the aspect,
area-averaged when shrinking). An image larger than that is of no use at full size, and a large
one would cost the server its memory: an 8192² file is 768 MiB as float32 RGB, and fitting it
takes several times that. So the decode worker (`gazehdr.scenes.sandbox`) reduces such an image
to its *level* before the server sees it: the smallest size, with the image's aspect, that is
at least as large as the image's fit in every frame a session of this server can have
(`session_frames`). Each session then fits the level to its own frame, always shrinking it
(or keeping it), never enlarging it. What the server holds of a scene is bounded by its frame
size, not by the file's.

An image no larger than its level is kept exactly as decoded (no copy, no arithmetic), so every
frame it gives is what it was. The reduction is an area average, computed in float64 over
bands of rows so that its own memory stays small (`BAND_VALUES`), whatever the image's shape.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.layout import MAX_SIZE

#: Values (pixels × channels) a band of the reduction reads at once: ~50 MiB as float64.
BAND_VALUES = 3 << 21
#: The frames of a server whose sessions' sizes are not known: any frame `check_frame_size`
#: allows (one frame covers them all: the largest).
ANY_FRAME: tuple[tuple[int, int], ...] = (MAX_SIZE,)


def session_frames(
    budget: tuple[int, int],
    fit_size: Callable[[tuple[int, int], tuple[float, float]], tuple[int, int]],
    step: int,
) -> tuple[tuple[int, int], ...]:
    """The frame sizes a session of frame size `budget` can have, as far as fitting an image
    goes: its own, and every size `fit_size` (`gazehdr.session.fit_size`, its sides multiples
    of `step`, `SIZE_STEP`) gives it for some viewer's viewport, keeping only those no other
    frame is both as wide and as tall as.

    fit_size's width is step·round(√(pixels·aspect)/step) and its height
    step·round(√(pixels/aspect)/step) (each clamped to [MIN_SIZE, MAX_SIZE]): for each width
    it can give, the narrowest aspect that gives it is the one with the tallest frame, so the
    aspects just inside each rounding edge cover them all."""
    width, height = budget
    pixels = width * height
    frames = {(int(width), int(height))}
    for k in range(MAX_SIZE[0] // step + 2):
        edge = max((k - 0.5) * step, 0.5)  # √(pixels·aspect) where the width rounds to k
        for nudge in (1 - 1e-9, 1 + 1e-9):
            frames.add(fit_size((width, height), ((edge * nudge) ** 2 / pixels, 1.0)))
    return _frontier(frames)


def _frontier(frames: Iterable[tuple[int, int]]) -> tuple[tuple[int, int], ...]:
    """`frames` less those another frame is at least as wide and as tall as."""
    kept: list[tuple[int, int]] = []
    for w, h in sorted(set(frames), key=lambda f: (-f[0], -f[1])):
        if not kept or h > kept[-1][1]:
            kept.append((w, h))
    return tuple(kept)


def level_size(
    width: int, height: int, frames: Iterable[tuple[int, int]] = ANY_FRAME
) -> tuple[int, int] | None:
    """The level of a `width`×`height` image for `frames` (W, H), or None when the image is no
    larger than it (it is kept as it is)."""
    sizes = np.asarray(list(frames) or ANY_FRAME, np.float64).reshape(-1, 2)
    scale = float(np.max(np.minimum(sizes[:, 0] / width, sizes[:, 1] / height)))
    if scale >= 1:
        return None
    # fit_to_frame makes round(side · s) of a side for a frame's scale s <= `scale`: never more
    # than the ceiling (a hair less than the product: floating-point error in `scale`).
    level = (min(width, max(1, math.ceil(width * scale - 1e-9))),
             min(height, max(1, math.ceil(height * scale - 1e-9))))  # fmt: skip
    return None if level == (width, height) else level


def reduce(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """H×W×C `rgb` area-averaged down to `size` (W, H) as float32, a band of rows at a time."""
    height, width = rgb.shape[:2]
    new_w, new_h = size
    if not (0 < new_w <= width and 0 < new_h <= height):
        raise InputError(f"cannot reduce {width}×{height} to {new_w}×{new_h}")
    out = np.empty((new_h, new_w, *rgb.shape[2:]), np.float32)
    channels = int(np.prod(rgb.shape[2:], dtype=np.int64))
    ry, rx = height / new_h, width / new_w
    rows = max(1, int(BAND_VALUES / (width * channels * ry)))  # output rows per band
    for j0 in range(0, new_h, rows):
        j1 = min(new_h, j0 + rows)
        lo, hi = math.floor(j0 * ry), min(height, math.ceil(j1 * ry))
        band = _reduce_columns(rgb[lo:hi], new_w, rx, channels)
        out[j0:j1] = _area(band, 0, j0 * ry - lo, ry, j1 - j0)
    return out


def _reduce_columns(rows: np.ndarray, new_w: int, rx: float, channels: int) -> np.ndarray:
    """`rows` (n×W×C) area-averaged along W to `new_w` columns, as float64."""
    n, width = rows.shape[:2]
    out = np.empty((n, new_w, *rows.shape[2:]), np.float64)
    cols = max(1, int(BAND_VALUES / (n * channels * rx)))  # output columns per piece
    for k0 in range(0, new_w, cols):
        k1 = min(new_w, k0 + cols)
        lo, hi = math.floor(k0 * rx), min(width, math.ceil(k1 * rx))
        out[:, k0:k1] = _area(rows[:, lo:hi], 1, k0 * rx - lo, rx, k1 - k0)
    return out


def _area(img: np.ndarray, axis: int, start: float, step: float, count: int) -> np.ndarray:
    """The means of `img` over `count` spans of `step` pixels along `axis` from `start` (its
    integral at each span's edges, as `gazehdr.sim.layout` fits an image), in float64."""
    img = np.moveaxis(img, axis, 0).astype(np.float64)
    n = img.shape[0]
    cum = np.concatenate([np.zeros((1, *img.shape[1:])), np.cumsum(img, axis=0)])
    del img
    edges = np.clip(start + step * np.arange(count + 1), 0.0, n)
    idx = np.minimum(np.floor(edges).astype(np.intp), n)
    frac = (edges - idx).reshape(-1, *([1] * (cum.ndim - 1)))
    integral = cum[idx] + frac * (cum[np.minimum(idx + 1, n)] - cum[idx])
    return np.moveaxis((integral[1:] - integral[:-1]) / step, 0, axis)
