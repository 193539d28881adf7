"""The report's Fig. 14 (server/experiment/plots.py): each observer's PSE with its interval from
the analysis drawn as an error bar, on generated observers run through the real analysis."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import LineCollection

from gazehdr.experiment import psychometric as pm
from gazehdr.experiment.analysis import FITTED, Settings, TaskResult, analyse
from gazehdr.experiment.dataset import Observer, Trial
from gazehdr.experiment.plots import draw_figure14, figure14, interval_gid

X = np.log10(np.array([14.0, 19.0, 27.0, 35.0, 49.0]) / 27.0)  # Sec. 4.1's levels


def _observer(name: str, fits: dict[str, tuple[float, float]], seed: int, n: int = 20) -> Observer:
    """Trials of a cumulative-Gaussian observer: per condition (pse, sigma), n at each level;
    sigma 0 makes every answer "test brighter" (a PSE below the levels: no interval)."""
    rng = np.random.default_rng(seed)
    trials = []
    for condition, (pse, sigma) in fits.items():
        for x in X:
            p = 1.0 if sigma == 0 else pm.psychometric(np.array([x]), pse, sigma, 0.02)[0]
            for k in rng.random(n) < p:
                trials.append(Trial(condition, float(x), float(k), 27.0, None, ()))
    return Observer(name, "afterimage", trials)


@pytest.fixture(scope="module")
def task() -> TaskResult:
    observers = [
        _observer("sub-01", {"control": (0.0, 0.08), "manipulated": (0.05, 0.08)}, 1),
        _observer("sub-02", {"control": (0.02, 0.1), "manipulated": (0.1, 0.1)}, 2),
        _observer("sub-03", {"control": (-0.03, 0.06), "manipulated": (0.8, 0.4)}, 3),  # open
        _observer("sub-04", {"control": (0.0, 0.1), "manipulated": (0.0, 0.0)}, 4),  # unbounded
    ]
    (result,) = analyse(observers, Settings(bootstrap=60, seed=0))
    return result


def _drawn(fig) -> dict[str, LineCollection]:
    (ax,) = fig.axes
    return {c.get_gid(): c for c in ax.collections if isinstance(c, LineCollection)}


def test_fig14_draws_each_observers_interval_as_the_analysis_computed_it(task: TaskResult):
    """Per condition one LineCollection of error bars: a segment per observer with an interval,
    from the analysis' interval's low end to its high end, at the height of the observer's
    dot; none for an unbounded PSE (no interval). Guards: `draw_figure14` leaving the
    intervals out (the old Fig. 14), drawing them around the wrong observer or condition, or
    drawing something else than `ConditionFit.ci` (e.g. the PSE ± a fixed width)."""
    fits = {c: [o.fits[c] for o in task.included] for c in FITTED}
    assert sum(f.ci is not None for c in FITTED for f in fits[c]) >= 6
    assert any(f.ci is None for f in fits["manipulated"])  # sub-04's PSE is below the levels
    assert any(any(f.ci_open) for f in fits["manipulated"])  # sub-03's reaches the bound
    fig = draw_figure14(task)
    try:
        drawn = _drawn(fig)
        (ax,) = fig.axes
        for condition in FITTED:
            usable = [f for f in fits[condition] if f.fit.usable and f.fit.rank_value is not None]
            want = [f.ci for f in usable if f.ci is not None]
            segments = drawn[interval_gid(condition)].get_segments()
            assert len(segments) == len(want), condition
            for seg, ci in zip(segments, want, strict=True):
                assert seg[0][0] == pytest.approx(ci[0]) and seg[1][0] == pytest.approx(ci[1])
                assert seg[0][1] == seg[1][1]
            # each bar at its dot: the dots of this condition, in the same order
            dots = [
                (float(line.get_xdata()[0]), float(line.get_ydata()[0]))
                for line in ax.lines
                if line.get_marker() in ("o", "<", ">")
                and len(line.get_xdata()) == 1
                and line.get_alpha() == 0.8
                and abs(line.get_ydata()[0] - (1 if condition == "control" else 0)) < 0.5
            ]
            with_ci = [d for d, f in zip(dots, usable, strict=True) if f.ci is not None]
            assert [s[0][1] for s in segments] == [y for _, y in with_ci]
            assert [x for x, _ in dots] == [f.fit.rank_value for f in usable]
    finally:
        plt.close(fig)


def test_fig14_without_intervals_draws_no_bars_and_still_makes_its_png(task: TaskResult):
    """No bootstrap (--bootstrap 0): no interval, so no bars, and the PNG is still made.
    Guards: an empty LineCollection (or a crash) when no observer has an interval."""
    (bare,) = analyse([o.observer for o in task.observers], Settings(bootstrap=0, seed=0))
    assert all(
        f.ci is None or f.fit.flag == "separable" for o in bare.included for f in o.fits.values()
    )
    fig = draw_figure14(bare)
    try:
        with_ci = {c for c in FITTED if any(o.fits[c].ci for o in bare.included)}
        assert set(_drawn(fig)) == {interval_gid(c) for c in with_ci}
    finally:
        plt.close(fig)
    assert figure14(task).startswith(b"\x89PNG") and figure14(bare).startswith(b"\x89PNG")
