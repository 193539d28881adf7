"""The trial order of a run: blocks in the design's order, each trial's cell (condition, test)
repeated as the design says with the test first in exactly half, shuffled within the block; and
the training score with its exclusion rule (Sec. 4.1.1: fewer than 70 % correct). Pure: the seed
fixes everything."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from gazehdr.experiment.design import Design


def log_ratio(test: float, standard: float) -> float:
    """log10(test / standard) of two positive intensities, as a difference of logs: finite
    for any two finite positive numbers (their quotient may overflow)."""
    return math.log10(test) - math.log10(standard)


@dataclass(frozen=True)
class Trial:
    number: int  # in the run, from 1, in presentation order
    block: int  # from 1
    block_name: str
    condition: str
    standard: float  # cd/m^2 on screen; a palette trial's: its flash image's
    test: float  # cd/m^2 on screen; a palette trial's: the simulated flash's luminance
    test_interval: int  # 1 or 2; a palette trial has one interval
    feedback: bool

    @property
    def palette(self) -> bool:
        return self.condition == "palette"

    @property
    def log_relative_intensity(self) -> float:
        return log_ratio(self.test, self.standard)

    @property
    def intensities(self) -> tuple[float, ...]:
        """The on-screen intensities of the intervals."""
        if self.palette:
            return (self.standard,)
        return (self.test, self.standard) if self.test_interval == 1 else (self.standard, self.test)

    def chose_test(self, interval: int) -> bool:
        """Whether answering "interval `interval` was brighter" chose the test."""
        return interval == self.test_interval

    def correct(self, interval: int) -> bool | None:
        """Whether the brighter image was chosen; None when test and standard are equal."""
        if self.palette or self.test == self.standard:
            return None
        return self.chose_test(interval) == (self.test > self.standard)


def schedule(design: Design, seed: int) -> list[Trial]:
    """Every trial of a run, in presentation order."""
    rng = np.random.default_rng(seed)
    trials: list[Trial] = []
    for b, block in enumerate(design.blocks, 1):
        cells = [
            (condition, test, interval)
            for condition, n in block.repeats.items()
            for test in block.tests
            for interval in ((1,) if condition == "palette" else (1, 2))
            for _ in range(n if condition == "palette" else n // 2)
        ]
        for i in rng.permutation(len(cells)):
            condition, test, interval = cells[i]
            trials.append(
                Trial(
                    len(trials) + 1, b, block.name, condition, design.standard, test, interval,
                    block.feedback,
                )
            )  # fmt: skip
    return trials


def training_score(results: Iterable[tuple[Trial, bool | None]], block: int) -> float | None:
    """Fraction correct in `block` of (trial, correct) pairs; None before any is scored."""
    scored = [ok for trial, ok in results if trial.block == block and ok is not None]
    return sum(scored) / len(scored) if scored else None


def excluded(score: float | None, min_correct: float) -> bool:
    """The paper's rule: an observer correct less than `min_correct` of the time is excluded."""
    return score is not None and score < min_correct
