"""A simulated observer: a psychometric model with a known point of subjective equality (PSE)
per condition, answering 2AFC brightness trials. The experiment runner drives it headless, and
the browser tests through the real page; the analysis must recover its PSE (issue 17).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def cumulative_gaussian(x: np.ndarray | float, pse: float, sigma: float, lapse: float):
    """P(choose the test) at log relative intensity `x`: lapses guess at random (half right)."""
    z = (np.asarray(x, dtype=float) - pse) / (sigma * math.sqrt(2.0))
    phi = 0.5 * (1.0 + _erf(z))
    return 0.5 * lapse + (1.0 - lapse) * phi


def _erf(z: np.ndarray) -> np.ndarray:
    return np.vectorize(math.erf, otypes=[float])(z)


@dataclass
class SimulatedObserver:
    """Answers "was the test brighter?" with P = `cumulative_gaussian(x, pse[c], sigma, lapse)`.

    `pse` maps a condition to its PSE in log10 units (conditions not named use 0); training trials
    use PSE 0. Seeded: the same seed gives the same answers to the same trials.
    """

    pse: dict[str, float] = field(default_factory=dict)
    sigma: float = 0.08
    lapse: float = 0.02
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.sigma > 0 and math.isfinite(self.sigma)):
            raise ValueError(f"sigma must be a positive number, got {self.sigma!r}")
        if not 0.0 <= self.lapse < 1.0:
            raise ValueError(f"lapse must be in [0, 1), got {self.lapse!r}")
        self._rng = np.random.default_rng(self.seed)

    def p_choose_test(self, log_relative_intensity: float, condition: str) -> float:
        pse = 0.0 if condition == "training" else self.pse.get(condition, 0.0)
        return float(cumulative_gaussian(log_relative_intensity, pse, self.sigma, self.lapse))

    def chooses_test(self, log_relative_intensity: float, condition: str) -> bool:
        """One answer: True if the observer says the test was brighter."""
        return bool(self._rng.random() < self.p_choose_test(log_relative_intensity, condition))
