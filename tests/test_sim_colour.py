"""The colours of afterimages (Jacobs et al. 2015, Sec. 2.2.2-2.2.3, Fig. 9): an adaptation
afterimage is the complement of what was fixated, a bleaching afterimage is positive on a grey.

The simulations run on both backends. Hues are HSV hues of linear RGB (0 red, 60 yellow, 120
green, 180 cyan, 240 blue, 300 magenta); the complement of a colour about a grey is
grey - k (colour - grey), whose hue is the colour's plus 180 degrees.
"""

from __future__ import annotations

import colorsys
import math

import numpy as np
import pytest

from gazehdr.sim import Params
from gazehdr.sim.reference import gamut_map

P = Params()
LUMA = np.array(P.w_P)


def hue(rgb: np.ndarray) -> float:
    """HSV hue of a colour or of a change of colour (only the differences between channels
    count), degrees."""
    rgb = np.asarray(rgb, np.float64) - np.min(rgb)
    return colorsys.rgb_to_hsv(*(rgb / max(rgb.max(), 1e-12)))[0] * 360


def hue_error(measured: float, wanted: float) -> float:
    return abs((measured - wanted + 180) % 360 - 180)


def test_gamut_keeps_hue_and_a_bright_blue_stays_blue() -> None:
    """Out-of-gamut colours keep their hue; a saturated blue far brighter than the display's
    blue primary keeps its saturation (it loses luminance instead)."""
    rng = np.random.default_rng(0)
    rgb = rng.uniform(-0.5, 3.0, (3, 500))
    out = gamut_map(rgb, P.w_P)
    assert out.min() >= 0 and out.max() <= 1
    moved = np.abs(out - rgb).max(axis=0) > 1e-9
    for a, b in zip(rgb[:, moved].T, out[:, moved].T, strict=True):
        if np.ptp(b) > 1e-6:
            assert hue_error(hue(b), hue(a)) < 1e-6, (a, b)
    blue = gamut_map(np.array([0.0, 0.0, 0.6 / LUMA[2]])[:, None], P.w_P)[:, 0]
    assert blue[2] == pytest.approx(1.0) and (blue[2] - blue[:2].max()) / blue[2] > 0.9
    assert math.isclose(hue(blue), 240.0, abs_tol=1e-6)
