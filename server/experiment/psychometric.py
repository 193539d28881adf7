"""The psychometric fit of one observer in one condition: a cumulative Gaussian in log10 relative
intensity with a symmetric lapse rate, by maximum likelihood, and a parametric bootstrap of its
PSE (docs/experiment-analysis.md).

The model is `observer.cumulative_gaussian`: P(test) = λ/2 + (1 − λ)·Φ((x − PSE)/σ). A lapse is a
random guess, so it pulls both tails towards 50 % and leaves P(PSE) = 50 %: the PSE is where the
underlying Gaussian is 50 %, and where the whole curve is. The likelihood is binomial per level,
minimised with scipy.optimize (L-BFGS-B, analytic gradient) inside bounds that make every data
set give finite numbers; data the model cannot pin down are classified before fitting and
flagged rather than fitted into NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special
from threadpoolctl import threadpool_limits

from gazehdr.drivers.errors import InputError

#: Why a fit has the PSE it has; `USABLE` flags enter the group statistics.
FLAGS = {
    "ok": "fitted within the tested levels",
    "extrapolated": "the PSE lies outside the tested levels (extrapolated, as the paper's "
    "participant 11 in Sec. 4.2)",
    "separable": "responses switch from all 'standard' to all 'test' between two levels: any PSE "
    "between them fits perfectly; the midpoint is reported, the interval is the two levels",
    "below_range": "'test brighter' always, but for lapses (the fitted curve has risen before "
    "the lowest level): the PSE is below every tested level, unbounded; ranked below every "
    "estimate",
    "above_range": "'standard brighter' always, but for lapses (the fitted curve rises only "
    "after the highest level): the PSE is above every tested level, unbounded; ranked above "
    "every estimate",
    "flat": "responses do not rise with intensity: no PSE",
    "one_level": "trials at one level only: no slope, no PSE",
    "no_data": "no answered trials",
}
USABLE = ("ok", "extrapolated", "separable", "below_range", "above_range")
UNBOUNDED = ("below_range", "above_range")
LAPSE_MAX = 0.1  # Wichmann & Hill (2001) bound lapses to a few percent; 10 % leaves room
_P_FLOOR = 1e-12
#: A fitted Gaussian that covers less than this of its rise across the levels says nothing of
#: where its PSE is, only on which side: unbounded.
_NO_RISE = 0.005


@dataclass(frozen=True)
class Levels:
    """Trials grouped by level: `k` of `n` trials at `x` were answered "test brighter"."""

    x: np.ndarray
    n: np.ndarray
    k: np.ndarray

    @staticmethod
    def from_trials(x: np.ndarray, chose_test: np.ndarray, decimals: int = 6) -> Levels:
        """Groups trials whose levels agree to `decimals` places (levels read back from text)."""
        xs = np.round(np.asarray(x, dtype=float), decimals)
        yes = np.asarray(chose_test, dtype=float)
        levels, inverse = np.unique(xs, return_inverse=True)
        n = np.bincount(inverse, minlength=len(levels)).astype(float)
        k = np.bincount(inverse, weights=yes, minlength=len(levels))
        return Levels(levels, n, k)

    @property
    def trials(self) -> int:
        return int(self.n.sum())

    @property
    def span(self) -> float:
        return float(self.x[-1] - self.x[0]) if len(self.x) else 0.0


@dataclass(frozen=True)
class Fit:
    """A maximum-likelihood fit. `pse` is None where the data give no PSE or an unbounded one;
    `rank_value` is the finite stand-in that orders it among the others (the search bound)."""

    flag: str
    pse: float | None
    sigma: float | None
    lapse: float | None
    nll: float | None
    rank_value: float | None
    interval: tuple[float, float] | None = None  # the set of equally good PSEs (separable)
    bounds: tuple[float, float] | None = None  # the PSE search range

    @property
    def usable(self) -> bool:
        return self.flag in USABLE


def one_blas_thread() -> threadpool_limits:
    """A context with BLAS on one thread: L-BFGS-B calls BLAS on 3-vectors, and a threaded
    OpenBLAS spends ~10× the work spinning threads for them (worse on a busy machine)."""
    return threadpool_limits(1, user_api="blas")


def psychometric(x: np.ndarray, pse: float, sigma: float, lapse: float) -> np.ndarray:
    """P(test brighter) of the model; the same function as `observer.cumulative_gaussian`."""
    return 0.5 * lapse + (1.0 - lapse) * special.ndtr((np.asarray(x, dtype=float) - pse) / sigma)


def _nll_and_grad(flat: np.ndarray, x: np.ndarray, n: np.ndarray, k: np.ndarray):
    """Binomial negative log-likelihood in (PSE, log σ, λ) and its gradient; `flat` holds one
    (PSE, log σ, λ) per row of `k` (data sets × levels), the result is summed over sets."""
    theta = flat.reshape(-1, 3)
    mu, sigma, lapse = theta[:, :1], np.exp(theta[:, 1:2]), theta[:, 2:3]
    z = (x - mu) / sigma
    phi = special.ndtr(z)
    p = np.clip(0.5 * lapse + (1.0 - lapse) * phi, _P_FLOOR, 1.0 - _P_FLOOR)
    nll = float(np.sum(_nll_each(p, n, k)))
    dnll_dp = -(k / p - (n - k) / (1.0 - p))
    dp_dz = (1.0 - lapse) * np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    grad = np.stack(
        [
            np.sum(dnll_dp * dp_dz, axis=1) * (-1.0 / sigma[:, 0]),
            np.sum(dnll_dp * dp_dz * (-z), axis=1),
            np.sum(dnll_dp * (0.5 - phi), axis=1),
        ],
        axis=1,
    )
    return nll, grad.ravel()


def _nll_each(p: np.ndarray, n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Each set's negative log-likelihood at probabilities `p` (sets × levels)."""
    return -np.sum(k * np.log(p) + (n - k) * np.log1p(-p), axis=1)


def _p(theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    mu, sigma, lapse = theta[:, :1], np.exp(theta[:, 1:2]), theta[:, 2:3]
    return np.clip(psychometric(x, mu, sigma, lapse), _P_FLOOR, 1.0 - _P_FLOOR)


def _search_bounds(levels: Levels) -> tuple[float, float, float, float]:
    """PSE within one span beyond the levels; σ from span/200 (a step) to 2·span (flat)."""
    span, lo, hi = levels.span, float(levels.x[0]), float(levels.x[-1])
    return lo - span, hi + span, span / 200.0, 2.0 * span


def _separation(levels: Levels) -> tuple[float, float] | None:
    """The two levels between which all-'standard' turns into all-'test', if it does."""
    for i in range(1, len(levels.x)):
        if np.all(levels.k[:i] == 0) and np.all(levels.k[i:] == levels.n[i:]):
            return float(levels.x[i - 1]), float(levels.x[i])
    return None


def _box(levels: Levels, lapse_max: float) -> list[tuple[float, float]]:
    lo, hi, s_lo, s_hi = _search_bounds(levels)
    return [(lo, hi), (math.log(s_lo), math.log(s_hi)), (0.0, lapse_max)]


def _minimise(levels: Levels, k: np.ndarray, starts: list[np.ndarray], lapse_max: float):
    """The best (PSE, log σ, λ) of L-BFGS-B runs from each start, for the counts `k`."""
    box = _box(levels, lapse_max)
    low, high = np.array(box).T
    best, best_nll = starts[0], math.inf
    for start in starts:
        res = optimize.minimize(
            _nll_and_grad,
            np.clip(start, low, high),
            args=(levels.x, levels.n, k[None, :]),
            jac=True,
            method="L-BFGS-B",
            bounds=box,
        )
        if res.fun < best_nll:
            best, best_nll = res.x, float(res.fun)
    return best


def _grid_starts(levels: Levels, k: np.ndarray, lapse_max: float) -> np.ndarray:
    """Per row of `k`, the best point of a coarse grid over the search box: when σ is small
    beside the level spacing the likelihood has plateaus between levels, and a local search
    stays on the one it starts on."""
    (lo, hi), (ls_lo, ls_hi), _ = _box(levels, lapse_max)
    grid = np.stack(
        np.meshgrid(
            np.linspace(lo, hi, 61),
            np.linspace(ls_lo, ls_hi, 16),
            np.linspace(0.0, lapse_max, 4),
            indexing="ij",
        ),
        axis=-1,
    ).reshape(-1, 3)
    p = _p(grid, levels.x)
    nll = -(k @ np.log(p).T + (levels.n - k) @ np.log1p(-p).T)
    return grid[np.argmin(nll, axis=1)]


def _starts(levels: Levels, lapse_max: float) -> list[np.ndarray]:
    """The 50 % crossing by interpolation at three slopes (σ and λ trade off over five
    levels), and the grid's best."""
    p = levels.k / levels.n
    mu0 = float(np.interp(0.5, np.maximum.accumulate(p), levels.x)) if p[-1] > p[0] else 0.0
    s0 = levels.span / 4.0
    lapse0 = min(0.02, lapse_max)
    return [
        *(
            np.array([mu0, math.log(s), lam])
            for s, lam in ((s0, lapse0), (s0 / 3, 0.0), (s0 * 2, lapse0))
        ),
        _grid_starts(levels, levels.k[None, :], lapse_max)[0],
    ]


def _degenerate(levels: Levels) -> Fit | None:
    """The fit of data the likelihood cannot pin down, or None (levels with trials only)."""
    if levels.trials == 0:
        return Fit("no_data", None, None, None, None, None)
    if len(levels.x) == 1:
        return Fit("one_level", None, None, None, None, None)
    lo, hi, s_lo, _ = _search_bounds(levels)
    if np.all(levels.k == levels.n):
        return Fit("below_range", None, None, None, 0.0, lo, bounds=(lo, hi))
    if np.all(levels.k == 0):
        return Fit("above_range", None, None, None, 0.0, hi, bounds=(lo, hi))
    gap = _separation(levels)
    if gap is not None:
        mid = 0.5 * (gap[0] + gap[1])
        return Fit("separable", mid, s_lo, 0.0, 0.0, mid, interval=gap, bounds=(lo, hi))
    return None


def _classify(levels: Levels, theta: np.ndarray) -> Fit:
    """A fitted (PSE, log σ, λ) as a `Fit`: at a bound it is unbounded or flat, not a PSE."""
    lo, hi, _, s_hi = _search_bounds(levels)
    mu, log_sigma, lapse = (float(v) for v in theta)
    sigma = math.exp(log_sigma)
    nll = _nll_and_grad(theta, levels.x, levels.n, levels.k[None, :])[0]
    width = 1e-6 * levels.span
    if sigma >= s_hi * (1 - 1e-6):
        return Fit("flat", None, sigma, lapse, nll, None, bounds=(lo, hi))
    # The curve's rise between the levels: none, and the likelihood is flat in the PSE beyond.
    rise = special.ndtr((levels.x[[0, -1]] - mu) / sigma)
    if mu <= lo + width or rise[0] > 1.0 - _NO_RISE:
        return Fit("below_range", None, sigma, lapse, nll, lo, bounds=(lo, hi))
    if mu >= hi - width or rise[1] < _NO_RISE:
        return Fit("above_range", None, sigma, lapse, nll, hi, bounds=(lo, hi))
    flag = "ok" if levels.x[0] <= mu <= levels.x[-1] else "extrapolated"
    return Fit(flag, mu, sigma, lapse, nll, mu, bounds=(lo, hi))


def fit(levels: Levels, lapse_max: float = LAPSE_MAX) -> Fit:
    """Maximum-likelihood fit; degenerate data are classified first (see `FLAGS`).

    `lapse_max=0` gives the plain probit the paper fitted with MATLAB's glmfit. Four starts
    (`_starts`), the best kept.
    """
    if not 0.0 <= lapse_max < 1.0:
        raise InputError(f"lapse_max must be in [0, 1), got {lapse_max!r}")
    keep = levels.n > 0
    levels = Levels(levels.x[keep], levels.n[keep], levels.k[keep])
    degenerate = _degenerate(levels)
    if degenerate is not None:
        return degenerate
    with one_blas_thread():
        theta = _minimise(levels, levels.k, _starts(levels, lapse_max), lapse_max)
    return _classify(levels, theta)


def bootstrap_pse(
    levels: Levels,
    base: Fit,
    resamples: int,
    rng: np.random.Generator,
    lapse_max: float = LAPSE_MAX,
) -> np.ndarray:
    """PSEs (rank values) refitted to `resamples` parametric resamples of the fitted curve.

    Parametric: the counts at each level are redrawn from the binomial the fit predicts, the
    design (levels, trials per level) kept, as Wichmann & Hill (2001b) do for constant stimuli.
    Each resample is classified as `fit` does, the others fitted from two starts, the original
    estimate and the grid's best; a degenerate resample contributes its rank value (a bound,
    or the middle of a gap), so a wide interval shows as one reaching the search bound, never
    as NaN. Flat resamples (no PSE) are dropped.
    """
    if base.flag not in ("ok", "extrapolated"):
        raise InputError(f"no bootstrap for a fit flagged {base.flag!r}")
    assert base.pse is not None and base.sigma is not None and base.lapse is not None
    keep = levels.n > 0
    levels = Levels(levels.x[keep], levels.n[keep], levels.k[keep])
    p = psychometric(levels.x, base.pse, base.sigma, base.lapse)
    counts = rng.binomial(levels.n.astype(np.int64), p, size=(resamples, len(levels.x)))
    out = np.full(resamples, np.nan)
    todo = []
    for i, k in enumerate(counts.astype(float)):
        degenerate = _degenerate(Levels(levels.x, levels.n, k))
        if degenerate is None:
            todo.append(i)
        elif degenerate.rank_value is not None:
            out[i] = degenerate.rank_value
    if todo:
        k = counts[todo].astype(float)
        grid = _grid_starts(levels, k, lapse_max)
        start = np.array([base.pse, math.log(base.sigma), base.lapse])
        with one_blas_thread():
            for i, kk, g in zip(todo, k, grid, strict=True):
                theta = _minimise(levels, kk, [start, g], lapse_max)
                rank = _classify(Levels(levels.x, levels.n, kk), theta).rank_value
                out[i] = np.nan if rank is None else rank
    return out[np.isfinite(out)]


def percentile_interval(samples: np.ndarray, level: float) -> tuple[float, float] | None:
    """The central `level` percentile interval of bootstrap samples (None without samples)."""
    if not 0.0 < level < 1.0:
        raise InputError(f"confidence level must be in (0, 1), got {level!r}")
    if len(samples) == 0:
        return None
    tail = 50.0 * (1.0 - level)
    lo, hi = np.percentile(samples, [tail, 100.0 - tail])
    return float(lo), float(hi)
