"""What every figure needs: simulators built from the run's options, stepping, images, PNGs.

Images are display values `v` in [0, 1] (H×W×3, what the simulator returns). A figure is a still,
so PNGs use plain rounding, `round(255·v)`, not the temporal dither of `gazehdr.dither`: dithering
helps only when frames average over time, and on a still it only adds noise.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from gazehdr.drivers.errors import GazehdrError
from gazehdr.sim import Geometry, Params, Simulator

#: Linear RGB -> photopic luminance (Rec.709), for measuring what the figures show.
LUMA = np.array(Params().w_P)


class ModelUnavailableError(GazehdrError, RuntimeError):
    """A figure needs a model (a baseline) that cannot be imported in this installation."""


@dataclass(frozen=True)
class Context:
    """The run's options, shared by every figure."""

    out_dir: Path
    width: int
    height: int
    backend: str
    seed: int


@dataclass
class Result:
    """What a figure made: its PNGs (file name, alt text), its measured numbers (JSON, shown on
    the page and checked by the tests) and statements derived from those numbers."""

    images: list[tuple[str, str]] = field(default_factory=list)
    measures: dict[str, Any] = field(default_factory=dict)
    findings: list[str] = field(default_factory=list)


def simulator(
    ctx: Context,
    size: tuple[int, int] | None = None,
    *,
    params: Params | None = None,
    afterimage: str = "jacobs",
    acuity: str = "stochastic",
) -> Simulator:
    """A simulator with the run's backend and seed; a model that does not import is an error
    naming it (never a silent fallback to another model)."""
    w, h = size or (ctx.width, ctx.height)
    try:
        return Simulator(
            w, h, params=params, backend=ctx.backend, seed=ctx.seed,
            afterimage=afterimage, acuity=acuity,
        )  # fmt: skip
    except ImportError as e:
        raise ModelUnavailableError(
            f"model afterimage={afterimage!r} acuity={acuity!r} is not available: {e}"
        ) from e


def advance(
    sim: Simulator,
    seconds: float,
    dt_max: float,
    gaze: tuple[float, float] | None = None,
    eyes_open: bool = True,
) -> np.ndarray:
    """Step `seconds` in equal frames of at most `dt_max` (the baselines integrate per frame, so
    their frame rate matters); returns the last display values."""
    n = max(1, math.ceil(seconds / dt_max - 1e-9))
    v = None
    for _ in range(n):
        v = sim.step(seconds / n, gaze=gaze, eyes_open=eyes_open)
    return v


def native_geometry(width: int, height: int) -> Params:
    """Params whose screen is this frame at the paper's pixel pitch (0.6 m 1920×1080 at 1 m,
    64 px/°): a small frame then shows a crop of the paper's monitor at full resolution, so the
    acuity bank (sigma_i in the paper's pixels) acts at its real size."""
    ref = Geometry()
    diagonal = ref.screen_diagonal_m * math.hypot(width, height)
    diagonal /= math.hypot(ref.screen_width_px, ref.screen_height_px)
    return Params(geometry=Geometry(diagonal, width, height, ref.viewing_distance_m))


def linear(v: np.ndarray, p: Params) -> np.ndarray:
    """Display values back to the linear J the model tone-mapped (undo v = J^gamma)."""
    return np.power(np.clip(np.asarray(v, np.float64), 0.0, 1.0), 1.0 / p.gamma)


def display(J: np.ndarray, p: Params) -> np.ndarray:
    return np.power(np.clip(J, 0.0, 1.0), p.gamma)


def normalise(v: np.ndarray, p: Params, mean_luminance: float) -> np.ndarray:
    """Scale the linear image so its mean luminance is `mean_luminance` (as the paper's Fig. 11
    keeps "the mean pixel brightnesses constant"), back to display values."""
    J = linear(v, p)
    return display(J * (mean_luminance / max(float((J @ LUMA).mean()), 1e-12)), p)


def grey(v: np.ndarray, p: Params) -> np.ndarray:
    """The luminance channel of a display image, as a grey display image."""
    Y = linear(v, p) @ LUMA
    return np.repeat(display(Y, p)[..., None], 3, axis=2)


def saturation(rgb: np.ndarray) -> np.ndarray:
    """(max - min) / max of linear RGB along the last axis: 0 for grey, 1 for a primary."""
    hi, lo = rgb.max(axis=-1), rgb.min(axis=-1)
    return (hi - lo) / np.maximum(hi, 1e-12)


#: The twelve hues of the RGB colour wheel, 30 degrees apart from red: primaries, secondaries
#: (yellow, cyan, magenta) and the tertiaries between them.
HUE_NAMES = (
    "red", "orange", "yellow", "chartreuse", "green", "spring green", "cyan", "azure", "blue",
    "violet", "magenta", "rose",
)  # fmt: skip


def hue_angle(rgb: np.ndarray) -> float:
    """HSV hue of RGB (negatives clipped), degrees: 0 red, 60 yellow, 120 green, 240 blue."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    return colorsys.rgb_to_hsv(*(rgb / max(rgb.max(), 1e-12)))[0] * 360


def hue_name(rgb: np.ndarray, min_saturation: float = 0.15) -> str:
    """The nearest of `HUE_NAMES` to the hue of linear RGB ("grey" below `min_saturation`)."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    if rgb.max() <= 1e-6:
        return "black"
    s = saturation(rgb)
    if s < min_saturation or s == 0:  # no hue at all, even where any saturation is asked for
        return "grey"
    return HUE_NAMES[round(hue_angle(rgb) / 30) % 12]


def hue_difference(a: float, b: float) -> float:
    """|a - b| around the hue circle, degrees in [0, 180]."""
    return abs((a - b + 180) % 360 - 180)


def rect_mean(img: np.ndarray, rect: tuple[float, float, float, float], keep: float = 0.5):
    """Mean over the central `keep` fraction of a rectangle given in frame fractions."""
    h, w = img.shape[:2]
    x0, y0, x1, y1 = rect
    cx, cy, hx, hy = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) * keep / 2, (y1 - y0) * keep / 2
    c0, c1 = math.floor((cx - hx) * w), max(math.ceil((cx + hx) * w), math.floor((cx - hx) * w) + 1)
    r0, r1 = math.floor((cy - hy) * h), max(math.ceil((cy + hy) * h), math.floor((cy - hy) * h) + 1)
    return img[r0:r1, c0:c1].reshape(-1, img.shape[2]).mean(axis=0)


def to8(v: np.ndarray) -> np.ndarray:
    """Display values to 8 bits by plain rounding (see the module docstring)."""
    return np.clip(np.rint(np.asarray(v, np.float64) * 255.0), 0, 255).astype(np.uint8)


def zoom(v: np.ndarray, k: int) -> np.ndarray:
    """Nearest-neighbour enlargement, so the pixels of small frames stay visible as pixels."""
    return np.repeat(np.repeat(v, k, axis=0), k, axis=1)


def crop(v: np.ndarray, centre: tuple[float, float], size: tuple[float, float]) -> np.ndarray:
    """The part of `v` around `centre` (frame fractions) of `size` (fractions), kept on it."""
    h, w = v.shape[:2]
    cw, ch = max(1, round(size[0] * w)), max(1, round(size[1] * h))
    x0 = min(max(round(centre[0] * w - cw / 2), 0), w - cw)
    y0 = min(max(round(centre[1] * h - ch / 2), 0), h - ch)
    return v[y0 : y0 + ch, x0 : x0 + cw]


_FONT = ImageFont.load_default(size=13)
_GAP = 4


def _text_size(text: str) -> tuple[int, int]:
    box = _FONT.getbbox(text)
    return box[2] - box[0], box[3] - box[1]


def grid(
    cells: list[list[np.ndarray]],
    rows: list[str],
    columns: list[str],
    *,
    scale: int = 1,
) -> Image.Image:
    """Labelled image grid on white: one row per model or condition, one column per moment.

    Cells are display values; each column takes its widest cell, each row its tallest.
    """
    cells8 = [[to8(zoom(c, scale)) for c in row] for row in cells]
    col_w = [max(row[j].shape[1] for row in cells8) for j in range(len(columns))]
    row_h = [max(c.shape[0] for c in row) for row in cells8]
    label_w = max((_text_size(r)[0] for r in rows), default=0) + 2 * _GAP
    label_h = max((_text_size(c)[1] for c in columns), default=0) + 2 * _GAP
    width = label_w + sum(col_w) + _GAP * (len(columns) + 1)
    height = label_h + sum(row_h) + _GAP * (len(rows) + 1)
    image = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(image)
    x = label_w + _GAP
    for j, name in enumerate(columns):
        draw.text((x + (col_w[j] - _text_size(name)[0]) // 2, _GAP), name, fill="black", font=_FONT)
        x += col_w[j] + _GAP
    y = label_h + _GAP
    for i, name in enumerate(rows):
        draw.text((_GAP, y + (row_h[i] - _text_size(name)[1]) // 2), name, fill="black", font=_FONT)
        x = label_w + _GAP
        for j, cell in enumerate(cells8[i]):
            image.paste(Image.fromarray(cell), (x, y))
            x += col_w[j] + _GAP
        y += row_h[i] + _GAP
    return image


def save(ctx: Context, result: Result, name: str, image: Image.Image, alt: str) -> None:
    image.save(ctx.out_dir / name, optimize=True)
    result.images.append((name, alt))
