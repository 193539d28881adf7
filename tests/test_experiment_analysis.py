"""`gazehdr experiment analyse`: the psychometric fit, its bootstrap interval,
degenerate data, the rank-sum test, the report, and PSE recovery from the echo observer."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from gazehdr.cli import main
from gazehdr.experiment import psychometric as pm
from gazehdr.experiment.analysis import Settings, analyse, ranksum
from gazehdr.experiment.dataset import ResultsError, load
from gazehdr.experiment.observer import EchoObserver, cumulative_gaussian
from gazehdr.experiment.recovery import headless_41_run, recover, synthetic_41_run
from gazehdr.experiment.report import write_report
from tests.experiment_data import write_dataset

X41 = np.log10(np.array([14.0, 19.0, 27.0, 35.0, 49.0]) / 27.0)


def _levels(pse: float, sigma: float, lapse: float, n: int, seed: int, x=X41) -> pm.Levels:
    rng = np.random.default_rng(seed)
    k = rng.binomial(n, pm.psychometric(x, pse, sigma, lapse))
    return pm.Levels(np.asarray(x, float), np.full(len(x), float(n)), k.astype(float))


def test_model_is_the_echo_observers_and_is_half_at_the_pse_whatever_the_lapse():
    x = np.linspace(-0.4, 0.4, 17)
    for lapse in (0.0, 0.05, 0.3):
        assert np.allclose(
            pm.psychometric(x, 0.03, 0.07, lapse), cumulative_gaussian(x, 0.03, 0.07, lapse)
        )
        assert pm.psychometric(0.03, 0.03, 0.07, lapse) == pytest.approx(0.5)


def test_large_n_recovers_pse_sigma_and_lapse():
    x = np.linspace(-0.3, 0.3, 7)
    fit = pm.fit(_levels(0.05, 0.08, 0.04, 20_000, seed=1, x=x))
    assert fit.flag == "ok"
    assert fit.pse == pytest.approx(0.05, abs=0.003)
    assert fit.sigma == pytest.approx(0.08, rel=0.05)
    assert fit.lapse == pytest.approx(0.04, abs=0.01)


def test_ignoring_lapses_flattens_the_fit_and_the_lapse_parameter_undoes_it():
    x = np.linspace(-0.3, 0.3, 7)
    levels = _levels(0.0, 0.05, 0.08, 20_000, seed=2, x=x)
    probit = pm.fit(levels, lapse_max=0.0)  # the paper's glmfit probit
    with_lapse = pm.fit(levels)
    assert probit.lapse == 0.0 and probit.sigma > 0.065  # lapses read as a shallower slope
    assert with_lapse.sigma == pytest.approx(0.05, rel=0.05)
    assert with_lapse.lapse == pytest.approx(0.08, abs=0.01)
    assert with_lapse.nll < probit.nll


def _levels_of(k: list[int], n: int = 30) -> pm.Levels:
    return pm.Levels(X41.copy(), np.full(5, float(n)), np.array(k, float))


@pytest.mark.parametrize(
    ("k", "flag"),
    [
        ([30, 30, 30, 30, 30], "below_range"),
        ([0, 0, 0, 0, 0], "above_range"),
        ([0, 0, 30, 30, 30], "separable"),
        ([15, 15, 15, 15, 15], "flat"),
        ([28, 20, 15, 9, 2], "flat"),  # falls with intensity: keys swapped?
        ([1, 1, 1, 1, 1], "above_range"),  # lapses only: the PSE beyond the top level
        ([0, 1, 2, 3, 4], "extrapolated"),  # rising slowly: the PSE far beyond the levels
        ([0, 5, 20, 29, 30], "ok"),
    ],
)
def test_degenerate_data_are_flagged_with_finite_numbers(k, flag):
    fit = pm.fit(_levels_of(k))
    assert fit.flag == flag, fit
    numbers = [fit.pse, fit.sigma, fit.lapse, fit.nll, fit.rank_value]
    assert all(v is None or math.isfinite(v) for v in numbers)
    if flag in pm.UNBOUNDED:
        assert fit.pse is None
        assert (fit.rank_value < X41[0]) if flag == "below_range" else (fit.rank_value > X41[-1])
    if flag == "separable":
        assert fit.interval == (pytest.approx(X41[1]), pytest.approx(X41[2]))
        assert fit.pse == pytest.approx((X41[1] + X41[2]) / 2)
    if flag == "flat":
        assert fit.pse is None and not fit.usable


def test_one_level_and_no_trials_give_no_pse():
    one = pm.fit(pm.Levels(np.array([0.0]), np.array([30.0]), np.array([12.0])))
    none = pm.fit(pm.Levels(np.array([0.0, 0.1]), np.array([0.0, 0.0]), np.array([0.0, 0.0])))
    assert (one.flag, one.pse, none.flag, none.pse) == ("one_level", None, "no_data", None)


def test_a_pse_beyond_the_levels_is_extrapolated_not_refused():
    fit = pm.fit(_levels(0.32, 0.12, 0.0, 2000, seed=3))
    assert fit.flag == "extrapolated"
    assert fit.pse == pytest.approx(0.32, abs=0.03)


def test_bootstrap_interval_is_seeded_and_reproducible():
    levels = _levels(-0.03, 0.08, 0.02, 30, seed=4)
    fit = pm.fit(levels)

    def interval(seed: int):
        samples = pm.bootstrap_pse(levels, fit, 200, np.random.default_rng(seed))
        return pm.percentile_interval(samples, 0.95)

    a, b, c = interval(7), interval(7), interval(8)
    assert a == b and a != c
    assert a[0] < fit.pse < a[1]
    assert pm.percentile_interval(np.array([]), 0.95) is None
    with pytest.raises(ValueError):
        pm.percentile_interval(np.array([1.0]), 1.5)


def test_ranksum_is_scipys_mann_whitney_with_matlabs_choice_of_method():
    rng = np.random.default_rng(5)
    x, y = rng.normal(0, 1, 12), rng.normal(0.8, 1, 11)  # nx + ny >= 20: approximate
    r = ranksum(x, y)
    scipy_approx = stats.mannwhitneyu(x, y, method="asymptotic", use_continuity=True)
    assert r.method == "approximate" and r.p == pytest.approx(scipy_approx.pvalue, rel=1e-12)
    assert r.U == scipy_approx.statistic
    assert r.W == pytest.approx(r.U + 12 * 13 / 2)
    assert r.p == pytest.approx(2 * stats.norm.sf(abs(r.z)), rel=1e-9)  # MATLAB's z, corrected
    small = ranksum([1.0, 2.5, 3.1, 4.0], [2.0, 5.0, 6.0, 7.5, 8.0])
    assert small.method == "exact"
    assert small.p == pytest.approx(
        stats.mannwhitneyu([1, 2.5, 3.1, 4], [2, 5, 6, 7.5, 8], method="exact").pvalue
    )
    tied = ranksum([1.0, 2.0, 2.0, 3.0], [2.0, 4.0, 5.0, 5.0])
    perm = stats.mannwhitneyu(
        [1, 2, 2, 3], [2, 4, 5, 5], method=stats.PermutationMethod(n_resamples=math.inf)
    )
    assert tied.method == "exact" and tied.p == pytest.approx(perm.pvalue)
    # One observer in a group, with ties (two fits at the same search bound): no exact p to be
    # had from the permutation test, the normal approximation instead of an error.
    lone = ranksum([0.3], [-0.6, -0.6, 0.2, 0.1])
    assert lone.method == "approximate" and 0 < lone.p <= 1 and lone.p_exact is None
    # The paper's mesopic p = 2.84e-6 is the exact p of 11 vs 11 observers without overlap.
    apart = ranksum(np.arange(11.0), np.arange(11.0) + 20)
    assert apart.p_exact == pytest.approx(2 / math.comb(22, 11)) == pytest.approx(2.84e-6, rel=2e-3)


def _dataset(tmp_path: Path) -> Path:
    observers = {
        f"sub-{i:02d}": EchoObserver(pse={"control": 0.0, "manipulated": 0.05 * i}, seed=i)
        for i in range(1, 5)
    }
    observers["sub-x1"] = EchoObserver(pse={"manipulated": 0.2}, seed=9)
    return write_dataset(tmp_path / "ds", observers, excluded=frozenset({"sub-x1"}), task="mesopic")


def test_cli_end_to_end_writes_a_self_contained_report_and_its_numbers(tmp_path, capsys):
    ds = _dataset(tmp_path)
    out = tmp_path / "rep" / "report.html"
    assert main(["experiment", "analyse", str(ds), "--out", str(out), "--bootstrap", "40"]) == 0
    printed = capsys.readouterr().out
    assert "mesopic: 4 observers, 1 excluded" in printed
    page = out.read_text()
    assert not re.search(r"https?://", page)
    assert all(
        src.startswith("data:image/png;base64,") for src in re.findall(r'src="([^"]*)"', page)
    )
    for participant in ("sub-01", "sub-02", "sub-03", "sub-04", "sub-x1"):
        assert participant in page
    assert "4 observers analysed, 1 excluded" in page
    data = json.loads((out.parent / "results.json").read_text())
    (task,) = data["tasks"]
    assert task["group"]["n_control"] == task["group"]["n_manipulated"] == 4
    excluded = [o for o in task["observers"] if o["excluded"]]
    assert [o["participant_id"] for o in excluded] == ["sub-x1"] and not excluded[0]["conditions"]
    tsv = (out.parent / "pse.tsv").read_text().splitlines()
    assert len(tsv) == 1 + 4 * 2 and not any("sub-x1" in line for line in tsv)
    row = dict(zip(tsv[0].split("\t"), tsv[1].split("\t"), strict=True))
    first = task["observers"][0]["conditions"][row["condition"]]
    assert float(row["pse"]) == first["pse"] and float(row["ci_low"]) == first["ci"][0]
    assert task["group"]["ranksum"]["p"] > 0 and task["group"]["ranksum"]["method"] == "exact"


def test_reports_degenerate_observers_without_nan(tmp_path):
    beh = tmp_path / "sub-07_task-afterimage_beh.tsv"
    rows = ["condition\tlog_relative_intensity\tchose_test"]
    rows += [f"control\t{x}\t1" for x in (-0.2, 0.0, 0.2) for _ in range(10)]  # all 'test'
    rows += [f"manipulated\t0.1\t{i % 2}" for i in range(10)]  # one level
    rows += ["manipulated\t0.1\tn/a"]  # no answer
    beh.write_text("\n".join(rows) + "\n")
    out = tmp_path / "report.html"
    assert main(["experiment", "analyse", str(beh), "--out", str(out), "--bootstrap", "20"]) == 0
    text = (tmp_path / "results.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    conditions = json.loads(text)["tasks"][0]["observers"][0]["conditions"]
    assert conditions["control"]["flag"] == "below_range"
    assert (conditions["manipulated"]["flag"], conditions["manipulated"]["missed"]) == (
        "one_level",
        1,
    )
    assert "&lt; -0.200" in out.read_text()


def test_excluded_by_participants_tsv_or_by_the_training_rule(tmp_path):
    ds = _dataset(tmp_path)
    bad = EchoObserver(pse={}, sigma=5.0, lapse=0.0, seed=3)  # guesses: fails training
    synthetic_41_run(11, bad, ds, task="mesopic", participant="sub-guess")
    observers = {o.participant: o for o in load([ds])}
    assert observers["sub-x1"].excluded and "participants.tsv" in observers["sub-x1"].exclusion
    guess = observers["sub-guess"]
    assert guess.excluded and "training" in guess.exclusion and guess.training[1] == 20
    assert not observers["sub-01"].excluded
    assert load([ds], exclude=["01"])[0].exclusion == "excluded on the command line"
    assert not {o.participant: o for o in load([ds], training_criterion=0)}["sub-guess"].excluded


def test_each_task_reads_its_own_exclusion_when_an_observer_ran_two(tmp_path):
    """One observer, 4.1 and 4.2 in one dataset, run through the experiment's own writer
    (`gazehdr experiment run --headless`): failing 4.2's training excludes them from 4.2 only,
    and each task shows its own training score."""
    from gazehdr.experiment.runner import run_headless

    good = EchoObserver({"manipulated": -0.05}, sigma=0.05, lapse=0.0, seed=1)
    guesser = EchoObserver(sigma=50.0, lapse=0.0, seed=2)  # fails any training
    run_headless("4.1", good, tmp_path, seed=1, observer_id="o1")
    run_headless("4.2", guesser, tmp_path, seed=2, observer_id="o1")
    by_task = {o.task: o for o in load([tmp_path], training_criterion=0.0)}
    assert not by_task["afterimage"].excluded and by_task["mesopic"].excluded
    assert "participants.tsv: mesopic_excluded" in by_task["mesopic"].exclusion
    assert by_task["afterimage"].training_score == 1.0
    assert by_task["mesopic"].training_score < 0.7


def test_unreadable_results_are_one_line_errors(tmp_path, capsys):
    assert (
        main(
            ["experiment", "analyse", str(tmp_path / "nothing"), "--out", str(tmp_path / "r.html")]
        )
        == 2
    )
    assert "no such file or folder" in capsys.readouterr().err
    (tmp_path / "participants.tsv").write_text("participant_id\texcluded\nsub-01\tmaybe\n")
    (tmp_path / "dataset_description.json").write_text("{}")
    beh = tmp_path / "sub-01" / "beh" / "sub-01_task-a_beh.tsv"
    beh.parent.mkdir(parents=True)
    beh.write_text("condition\tchose_test\ncontrol\tyes\n")
    with pytest.raises(ResultsError, match="chose_test"):
        load([beh])
    beh.write_text("condition\tchose_test\n")
    with pytest.raises(ResultsError, match="excluded"):
        load([tmp_path])


def test_palette_choices_are_counted_per_flash_strength_and_shown_escaped(tmp_path):
    beh = tmp_path / "sub-01_task-palette_beh.tsv"
    rows = ["condition\ttest_intensity\tchose_test\tpalette_choice"]
    rows += ["palette\t1000\tn/a\tH1,B1", "palette\t1000\tn/a\tH1", "palette\t31.25\tn/a\tG3"]
    rows += ["palette\t31.25\tn/a\tn/a", "palette\t31.25\tn/a\t<b>X</b>"]
    beh.write_text("\n".join(rows) + "\n")
    tasks = analyse(load([beh]), Settings(bootstrap=0))
    (task,) = tasks
    assert task.palette == {
        "<b>X</b>": {31.25: 1},
        "B1": {1000.0: 1},
        "G3": {31.25: 1},
        "H1": {1000.0: 2},
    }
    assert task.palette_trials == {31.25: 3, 1000.0: 2}
    write_report(tasks, Settings(bootstrap=0), tmp_path / "r.html")
    page = (tmp_path / "r.html").read_text()
    assert "&lt;b&gt;X&lt;/b&gt;" in page and "<b>X</b>" not in page


def test_recovery_intervals_hold_the_true_pse(tmp_path):
    """Sec. 4.1 run through the experiment's own trial code without a browser (the runner the
    page's runs use), answered by the echo observer, analysed as real results. Bounded and
    seeded; `gazehdr experiment recovery --runs 200` is the long run."""
    truth = EchoObserver(pse={"control": 0.0, "manipulated": -0.05}, sigma=0.08, lapse=0.02)
    coverage = recover(headless_41_run, truth, 12, Settings(bootstrap=100, seed=1))
    assert {c.condition for c in coverage} == {"control", "manipulated"}
    assert all(c.runs == 12 for c in coverage)
    covered = sum(c.covered for c in coverage)
    assert covered >= 21, coverage  # of 24: a broken interval (e.g. half as wide) covers ~16
    assert all(abs(c.mean_error) < 0.02 for c in coverage)


def test_recovery_fails_only_when_coverage_is_significantly_low() -> None:
    """`recovery --require 0.9` exits 1 only when the coverage is significantly below 0.9 for
    the runs made, so that `--runs 20` does not fail by chance. Guards the plain comparison
    (17 of 20 intervals, 85 %, failed a 0.9 requirement though 95 % intervals do that often)."""
    from gazehdr.experiment.commands import below

    assert not below(17, 20, 0.9) and not below(14, 20, 0.9) and not below(0, 0, 0.9)
    assert below(160, 200, 0.9) and below(5, 20, 0.9)
