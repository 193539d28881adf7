"""Colour transforms of the palette's options (Sec. 4.3, Fig. 15: "the remaining images were
produced by applying color transforms to either our or Ritschel's model").

The paper does not give its transforms. Ours act on the HSV of *linear* light (the display
values `v` undone to J = v^(1/gamma), transformed, encoded again), so a transform's hue is the
hue the figures measure (`gazehdr.figures.common.hue_angle`), and every result stays in the
display's gamut (HSV keeps each pixel's value, its largest channel):

- `none`: the model's image as rendered.
- `hue+D`, `hue-D` (0 < D < 360 degrees): every pixel's hue rotated by D, its saturation and
  value kept. Greys (saturation 0) stay grey: a rotation cannot colour Ritschel's afterimage.
- `tint=H/S` (0 <= H < 360 degrees, 0 <= S <= 1): every pixel's hue set to H and its
  saturation to S, its value kept: how Ritschel's neutral afterimage gets a colour.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError

#: What the design file's `transform` may say (the loader's error repeats it).
SYNTAX = (
    "none; hue+D or hue-D (rotate the hue by D degrees, 0 < D < 360); or tint=H/S (set the "
    "hue to H degrees, 0 <= H < 360, and the saturation to S, 0 <= S <= 1)"
)
_NUMBER = r"(\d+(?:\.\d*)?|\.\d+)"
_HUE = re.compile(rf"hue([+-]){_NUMBER}")
_TINT = re.compile(rf"tint={_NUMBER}/{_NUMBER}")


@dataclass(frozen=True)
class Transform:
    kind: str = "none"  # "none", "hue" or "tint"
    hue: float = 0.0  # degrees: the rotation ("hue"), or the hue set ("tint")
    saturation: float = 0.0  # "tint" only

    def __str__(self) -> str:
        if self.kind == "hue":
            return f"hue{'+' if self.hue >= 0 else '-'}{abs(self.hue):g}"
        if self.kind == "tint":
            return f"tint={self.hue:g}/{self.saturation:g}"
        return "none"

    def apply(self, v: np.ndarray, gamma: float) -> np.ndarray:
        """Display values `v` (H×W×3 in [0, 1], v = J^gamma) transformed, as display values."""
        if self.kind == "none":
            return np.array(v, np.float32)  # a copy: options never share an image
        J = np.power(np.clip(np.asarray(v, np.float64), 0.0, 1.0), 1.0 / gamma)
        h, s, value = rgb_to_hsv(J)
        if self.kind == "hue":
            h = (h + self.hue / 360.0) % 1.0
        else:
            h, s = np.full_like(h, self.hue / 360.0), np.full_like(s, self.saturation)
        return np.power(hsv_to_rgb(h, s, value), gamma).astype(np.float32)


NONE = Transform()


def parse(text: str) -> Transform:
    """A transform from its name (`SYNTAX`); ValueError says what is wrong."""
    if not isinstance(text, str):
        raise InputError(f"must be a string: {SYNTAX}")
    name = text.strip().lower()
    if name == "none":
        return NONE
    if m := _HUE.fullmatch(name):
        degrees = float(m.group(2))
        if not 0 < degrees < 360:
            raise InputError(f"a hue rotation is by more than 0, less than 360 degrees: {SYNTAX}")
        return Transform("hue", degrees if m.group(1) == "+" else -degrees)
    if m := _TINT.fullmatch(name):
        hue, saturation = float(m.group(1)), float(m.group(2))
        if not (0 <= hue < 360 and 0 <= saturation <= 1 and math.isfinite(hue)):
            raise InputError(f"a tint's hue is in [0, 360) and its saturation in [0, 1]: {SYNTAX}")
        return Transform("tint", hue, saturation)
    raise InputError(f"not a colour transform: {SYNTAX}")


def rgb_to_hsv(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HSV of non-negative RGB along the last axis, each in [0, 1] (hue 0 red, 1/3 green)."""
    r, g, b = np.moveaxis(np.maximum(rgb, 0.0), -1, 0)
    value = np.maximum(np.maximum(r, g), b)
    chroma = value - np.minimum(np.minimum(r, g), b)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(value > 0, chroma / value, 0.0)
        c = np.where(chroma > 0, chroma, 1.0)
        h = np.where(
            value == r, (g - b) / c, np.where(value == g, 2.0 + (b - r) / c, 4.0 + (r - g) / c)
        )
    h = np.where(chroma > 0, (h / 6.0) % 1.0, 0.0)
    return h, s, value


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, value: np.ndarray) -> np.ndarray:
    """The inverse of `rgb_to_hsv`: H×W×3 RGB."""
    k = np.stack([(5.0 + h * 6.0) % 6.0, (3.0 + h * 6.0) % 6.0, (1.0 + h * 6.0) % 6.0], -1)
    ramp = np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
    return value[..., None] * (1.0 - s[..., None] * ramp)
