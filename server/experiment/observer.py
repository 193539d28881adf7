"""The simulated observers that answer 2AFC brightness trials headless (docs/experiments.md,
docs/experiment-analysis.md):

- `ModelObserver`, the model observer: it looks. It computes a brightness for each interval from
  the frames shown (`brightness.log10_brightness`: the Helmholtz–Kohlrausch effect, Bloch's
  temporal summation) and answers which was brighter through Weber noise. It is given no PSE;
  what its answers imply is a prediction.
- `EchoObserver`, a pipeline check: it answers from a psychometric function around the PSE it is
  given per condition, whatever the frames, so that the analysis must find that PSE again
  (`gazehdr experiment recovery`).

The runner calls `answer(trial, percepts)`; `percepts()` gives the log10 brightness of each
interval in the order shown, computed (and kept) by the runner with the observer's `perceive`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.experiment.brightness import BLOCH_S, HK_METHODS, Interval, log10_brightness
from gazehdr.experiment.schedule import Trial

#: The Weber fraction of brightness, ΔI/I = 0.079 for two brief flashes seen one after the other
#: (Cornsweet & Pinsker 1965, J. Physiol. 176:294–310, as tabulated by Teghtsoonian 1971,
#: Psychol. Rev. 78:71–80).
WEBER = 0.079

Percepts = Callable[[], Sequence[float]]


class Observer(Protocol):
    """What `runner.run_headless` needs of an observer."""

    seed: int

    def answer(self, trial: Trial, percepts: Percepts) -> bool: ...


def cumulative_gaussian(x: np.ndarray | float, pse: float, sigma: float, lapse: float):
    """P(choose the test) at log relative intensity `x`: lapses guess at random (half right)."""
    z = (np.asarray(x, dtype=float) - pse) / (sigma * math.sqrt(2.0))
    phi = 0.5 * (1.0 + _erf(z))
    return 0.5 * lapse + (1.0 - lapse) * phi


def _erf(z: np.ndarray) -> np.ndarray:
    return np.vectorize(math.erf, otypes=[float])(z)


def _check_lapse(lapse: float) -> None:
    if not 0.0 <= lapse < 1.0:
        raise InputError(f"lapse must be in [0, 1), got {lapse!r}")


@dataclass
class EchoObserver:
    """A pipeline check, not a model: answers "was the test brighter?" with
    P = `cumulative_gaussian(x, pse[c], sigma, lapse)` at the trial's log relative intensity x,
    never looking at the frames, so that the analysis must recover the PSE it is given.

    `pse` maps a condition to its PSE in log10 units (conditions not named use 0); training trials
    use PSE 0. Seeded: the same seed gives the same answers to the same trials.
    """

    pse: dict[str, float] = field(default_factory=dict)
    sigma: float = 0.08
    lapse: float = 0.02
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.sigma > 0 and math.isfinite(self.sigma)):
            raise InputError(f"sigma must be a positive number, got {self.sigma!r}")
        _check_lapse(self.lapse)
        self._rng = np.random.default_rng(self.seed)

    def p_choose_test(self, log_relative_intensity: float, condition: str) -> float:
        pse = 0.0 if condition == "training" else self.pse.get(condition, 0.0)
        return float(cumulative_gaussian(log_relative_intensity, pse, self.sigma, self.lapse))

    def chooses_test(self, log_relative_intensity: float, condition: str) -> bool:
        """One answer: True if the observer says the test was brighter."""
        return bool(self._rng.random() < self.p_choose_test(log_relative_intensity, condition))

    def answer(self, trial: Trial, percepts: Percepts) -> bool:
        """The runner's call: the frames (`percepts`) are not looked at."""
        return self.chooses_test(trial.log_relative_intensity, trial.condition)

    def describe(self) -> str:
        given = ", ".join(f"{k}={v:+g}" for k, v in sorted(self.pse.items())) or "all 0"
        return (
            f"echo observer (answers from the PSEs it is given, {given}; sigma {self.sigma:g}, "
            f"lapse {self.lapse:g}): a pipeline check, not a prediction"
        )


@dataclass
class ModelObserver:
    """The model observer: decides from the frames shown, knowing nothing of conditions, PSEs or
    intensities. Each interval's internal response is log10 B + N(0, σ), B its brightness
    (`brightness.log10_brightness` with `window` and `hk`) and σ = log10(1 + `weber`), so that
    two intervals a Weber fraction apart are told apart 76 % of the time (d' = 1); it answers
    "the test" when the test's response is the larger. With probability `lapse` it guesses.
    Seeded: the same seed gives the same answers to the same frames.
    """

    weber: float = WEBER
    window: float = BLOCH_S
    hk: str = "VAC"
    lapse: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.weber > 0 and math.isfinite(self.weber)):
            raise InputError(f"weber must be a positive fraction, got {self.weber!r}")
        if not self.window > 0:
            raise InputError(f"window must be a positive number of seconds, got {self.window!r}")
        if self.hk not in HK_METHODS:
            raise InputError(f"hk must be one of {', '.join(HK_METHODS)}, got {self.hk!r}")
        _check_lapse(self.lapse)
        self._rng = np.random.default_rng(self.seed)

    @property
    def sigma(self) -> float:
        """The noise of one interval's response, log10 units."""
        return math.log10(1.0 + self.weber)

    @property
    def perception(self) -> tuple[Any, ...]:
        """What `perceive` depends on: equal keys, equal percepts of the same frames."""
        return ("model", float(self.window), self.hk)

    def perceive(self, interval: Interval) -> float:
        """log10 brightness of one interval as shown: deterministic, no noise."""
        return log10_brightness(interval, self.window, self.hk)

    def p_choose_test(self, test: float, standard: float) -> float:
        """P(answer "test") for intervals of log10 brightness `test` and `standard`."""
        # the difference of the two responses has sd √2·σ: P = Φ(Δ / (√2·σ)) = ½(1 + erf(Δ / 2σ))
        z = (test - standard) / (2.0 * self.sigma)
        return 0.5 * self.lapse + (1.0 - self.lapse) * 0.5 * (1.0 + math.erf(z))

    def chooses_test(self, test: float, standard: float) -> bool:
        """One answer from the two intervals' log10 brightness."""
        guess, coin = self._rng.random(), self._rng.random()
        noise = self._rng.normal(0.0, self.sigma, 2)
        if guess < self.lapse:
            return bool(coin < 0.5)
        return bool(test + noise[0] > standard + noise[1])

    def answer(self, trial: Trial, percepts: Percepts) -> bool:
        shown = percepts()
        if len(shown) != 2:
            raise InputError(f"a 2AFC trial shows two intervals, got {len(shown)}")
        test = shown[trial.test_interval - 1]
        return self.chooses_test(test, shown[2 - trial.test_interval])

    def describe(self) -> str:
        window = "the whole interval" if math.isinf(self.window) else f"{self.window:g} s"
        return (
            f"model observer (Weber fraction {self.weber:g}, summation window {window}, "
            f"Helmholtz-Kohlrausch {self.hk}, lapse {self.lapse:g})"
        )
