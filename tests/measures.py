"""Measurements on simulated maps that several model tests make."""

from __future__ import annotations

import math

import numpy as np


def spread(plane: np.ndarray, axis: int, centre: int) -> tuple[float, float]:
    """Mean offset from `centre` and RMS spread about it, in cells, of a plane's marginal
    (summed over `axis`: 0 gives the spread along x): how far a blur moved and widened a point."""
    marginal = plane.sum(axis=axis)
    d = np.arange(marginal.size) - centre
    mean = float((marginal * d).sum() / marginal.sum())
    return mean, math.sqrt((marginal * d**2).sum() / marginal.sum())
