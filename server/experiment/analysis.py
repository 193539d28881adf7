"""The analysis of Sec. 4's experiments: one psychometric fit per observer and condition with a
bootstrap interval of its PSE, the paper's rank-sum test across observers, and the palette
counts of Sec. 4.3 (docs/experiment-analysis.md). Pure: observers in, results out.
"""

from __future__ import annotations

import math
import zlib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from gazehdr.drivers.errors import InputError
from gazehdr.experiment import psychometric as pm
from gazehdr.experiment.dataset import Observer

FITTED = ("control", "manipulated")


@dataclass(frozen=True)
class Settings:
    bootstrap: int = 1000
    seed: int = 0
    ci: float = 0.95
    lapse_max: float = pm.LAPSE_MAX

    def __post_init__(self) -> None:
        if self.bootstrap < 0:
            raise InputError(f"bootstrap must be 0 or more resamples, got {self.bootstrap}")
        if self.seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {self.seed}")
        if not 0.0 < self.ci < 1.0:
            raise InputError(f"ci must be a level between 0 and 1 such as 0.95, got {self.ci}")
        if not 0.0 <= self.lapse_max < 1.0:
            raise InputError(f"lapse-max must be in [0, 1), got {self.lapse_max}")


@dataclass(frozen=True)
class ConditionFit:
    condition: str
    levels: pm.Levels
    fit: pm.Fit
    missed: int  # trials without a response, left out
    ci: tuple[float, float] | None = None
    resamples: int = 0  # bootstrap resamples that gave a PSE

    @property
    def ci_open(self) -> tuple[bool, bool]:
        """Whether the interval reaches the PSE search bound (the data cannot close it)."""
        if self.ci is None or self.fit.bounds is None:
            return False, False
        lo, hi = self.fit.bounds
        return bool(self.ci[0] <= lo), bool(self.ci[1] >= hi)


@dataclass
class ObserverResult:
    observer: Observer
    fits: dict[str, ConditionFit] = field(default_factory=dict)

    def shift(self) -> float | None:
        """Manipulated minus control PSE (rank values), where both are usable."""
        c, m = self.fits.get("control"), self.fits.get("manipulated")
        if c and m and c.fit.usable and m.fit.usable:
            assert c.fit.rank_value is not None and m.fit.rank_value is not None
            return m.fit.rank_value - c.fit.rank_value
        return None


@dataclass(frozen=True)
class RankSum:
    """Wilcoxon rank-sum of x (control) against y (manipulated), as MATLAB's ranksum."""

    n_x: int
    n_y: int
    W: float  # rank sum of x
    U: float  # Mann-Whitney U of x
    z: float  # the normal approximation's, with tie and continuity corrections
    p: float  # by `method`
    method: str  # "exact" or "approximate", chosen as MATLAB does
    p_exact: float | None
    p_approximate: float


@dataclass(frozen=True)
class SignedRank:
    """The paired test over observers with both PSEs (not the paper's; they were paired)."""

    n: int
    statistic: float
    p: float


@dataclass(frozen=True)
class Group:
    n_control: int
    n_manipulated: int
    median_control: float | None
    median_manipulated: float | None
    ranksum: RankSum | None
    signed_rank: SignedRank | None


@dataclass
class TaskResult:
    task: str
    observers: list[ObserverResult]
    group: Group
    palette: dict[str, dict[float, int]]  # option -> flash strength -> times chosen
    palette_trials: dict[float, int]  # flash strength -> palette trials answered

    @property
    def included(self) -> list[ObserverResult]:
        return [o for o in self.observers if not o.observer.excluded]

    @property
    def excluded(self) -> list[ObserverResult]:
        return [o for o in self.observers if o.observer.excluded]


def _rng(settings: Settings, *names: str) -> np.random.Generator:
    """A generator per (task, observer, condition): results do not depend on what else ran."""
    key = zlib.crc32("/".join(names).encode())
    return np.random.default_rng(np.random.SeedSequence([settings.seed, key]))


def fit_condition(levels: pm.Levels, settings: Settings, rng: np.random.Generator) -> tuple:
    """The fit, its bootstrap interval (separable: the gap; unbounded: none) and resamples."""
    result = pm.fit(levels, settings.lapse_max)
    if result.flag == "separable":
        return result, result.interval, 0
    if result.flag not in ("ok", "extrapolated") or settings.bootstrap == 0:
        return result, None, 0
    samples = pm.bootstrap_pse(levels, result, settings.bootstrap, rng, settings.lapse_max)
    return result, pm.percentile_interval(samples, settings.ci), len(samples)


def analyse_observer(observer: Observer, settings: Settings) -> ObserverResult:
    result = ObserverResult(observer)
    for condition in FITTED:
        trials = [t for t in observer.trials if t.condition == condition]
        if not trials:
            continue
        answered = [t for t in trials if t.chose_test is not None and t.x is not None]
        levels = pm.Levels.from_trials(
            np.array([t.x for t in answered]), np.array([t.chose_test for t in answered])
        )
        rng = _rng(settings, observer.task, observer.participant, condition)
        fit, ci, resamples = fit_condition(levels, settings, rng)
        result.fits[condition] = ConditionFit(
            condition, levels, fit, len(trials) - len(answered), ci, resamples
        )
    return result


def ranksum(x: Sequence[float], y: Sequence[float]) -> RankSum:
    """MATLAB's `ranksum(x, y)` by scipy's `mannwhitneyu` (the same test: U = W − nx(nx+1)/2).

    MATLAB's default: the exact p when min(nx, ny) < 10 and nx + ny < 20, else the normal
    approximation with tie and continuity corrections (`method="asymptotic"`,
    `use_continuity=True`; `scipy.stats.ranksums` has neither correction). Both p are kept.
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    nx, ny = len(x), len(y)
    if nx == 0 or ny == 0:
        raise InputError("a rank-sum test needs at least one value in each sample")
    ranks = stats.rankdata(np.concatenate([x, y]))
    W = float(ranks[:nx].sum())
    approx = stats.mannwhitneyu(x, y, alternative="two-sided", method="asymptotic")
    _, ties = np.unique(ranks, return_counts=True)
    n = nx + ny
    tie_term = float(np.sum(ties**3 - ties)) / (n * (n - 1)) if n > 1 else 0.0
    var = nx * ny * ((n + 1) - tie_term) / 12.0
    wc = W - nx * (n + 1) / 2.0
    z = (wc - 0.5 * np.sign(wc)) / math.sqrt(var) if var > 0 else 0.0
    p_exact = None
    if np.all(ties == 1):
        p_exact = float(stats.mannwhitneyu(x, y, method="exact").pvalue)
    elif min(nx, ny) >= 2 and math.comb(n, nx) <= 200_000:
        # Exhaustive permutations of the midranks, as MATLAB's (scipy's permutation test
        # needs two values a side; a group of one gets the normal approximation).
        perm = stats.PermutationMethod(n_resamples=math.inf)
        p_exact = float(stats.mannwhitneyu(x, y, method=perm).pvalue)
    exact = min(nx, ny) < 10 and n < 20 and p_exact is not None
    p_approx = float(approx.pvalue)
    return RankSum(
        nx,
        ny,
        W,
        float(approx.statistic),
        float(z),
        p_exact if exact and p_exact is not None else p_approx,
        "exact" if exact else "approximate",
        p_exact,
        p_approx,
    )


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def group_statistics(observers: Sequence[ObserverResult]) -> Group:
    """Control against manipulated PSEs over the included observers with a usable fit."""

    def pses(condition: str) -> dict[str, float]:
        out = {}
        for o in observers:
            f = o.fits.get(condition)
            if not o.observer.excluded and f and f.fit.usable and f.fit.rank_value is not None:
                out[o.observer.participant] = f.fit.rank_value
        return out

    control, manipulated = pses("control"), pses("manipulated")
    test = None
    if control and manipulated and len(control) + len(manipulated) > 2:
        test = ranksum(list(control.values()), list(manipulated.values()))
    paired = sorted(set(control) & set(manipulated))
    signed = None
    diffs = [manipulated[p] - control[p] for p in paired]
    if len(paired) >= 2 and any(d != 0 for d in diffs):
        res = stats.wilcoxon(diffs)
        signed = SignedRank(len(paired), float(res.statistic), float(res.pvalue))
    return Group(
        len(control),
        len(manipulated),
        _median(list(control.values())),
        _median(list(manipulated.values())),
        test,
        signed,
    )


def palette_counts(observers: Sequence[Observer]) -> tuple[dict, dict]:
    """Sec. 4.3: how often each palette option was picked per flash strength (test_intensity)."""
    chosen: dict[str, Counter] = {}
    trials: Counter = Counter()
    for obs in observers:
        for t in obs.trials:
            if t.condition != "palette" or t.test_intensity is None:
                continue
            trials[t.test_intensity] += 1
            for option in t.palette_choice:
                chosen.setdefault(option, Counter())[t.test_intensity] += 1
    return {k: dict(v) for k, v in sorted(chosen.items())}, dict(sorted(trials.items()))


def analyse(observers: Sequence[Observer], settings: Settings) -> list[TaskResult]:
    """Each task's included observers fitted, grouped and counted; the excluded listed only."""
    out = []
    for task in sorted({o.task for o in observers}):
        mine = [o for o in observers if o.task == task]
        results = [ObserverResult(o) if o.excluded else analyse_observer(o, settings) for o in mine]
        palette, palette_trials = palette_counts([o for o in mine if not o.excluded])
        out.append(TaskResult(task, results, group_statistics(results), palette, palette_trials))
    return out


def representatives(task: TaskResult) -> list[tuple[str, ObserverResult]]:
    """Fig. 13's three: the most leftward, the median and the most rightward PSE shift."""
    shifted = sorted(
        (o for o in task.included if o.shift() is not None),
        key=lambda o: (o.shift(), o.observer.participant),
    )
    if not shifted:
        return []
    picks = [
        ("most leftward shift", 0),
        ("median shift", len(shifted) // 2),
        ("most rightward shift", len(shifted) - 1),
    ]
    seen: set[int] = set()
    out = []
    for label, i in picks:
        if i not in seen:
            seen.add(i)
            out.append((label, shifted[i]))
    return out
