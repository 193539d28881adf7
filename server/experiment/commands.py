"""`gazehdr experiment analyse` and `gazehdr experiment recovery`: their parsers and what they
run. Only the standard library is imported here; scipy and matplotlib when a command runs."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from gazehdr.drivers.errors import InputError

PROG = "gazehdr"


def _need_extra() -> None:
    wanted = ("scipy", "matplotlib", "threadpoolctl")
    missing = [m for m in wanted if importlib.util.find_spec(m) is None]
    if missing:
        raise InputError(
            f"the analysis needs {', '.join(missing)}: pip install 'gazehdr[experiment]'"
        )


def _common(p: argparse.ArgumentParser, bootstrap: int) -> None:
    p.add_argument(
        "--bootstrap",
        type=int,
        default=bootstrap,
        metavar="N",
        help=f"parametric bootstrap resamples per PSE interval; 0: none (default: {bootstrap})",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the bootstrap (default: 0)")
    p.add_argument(
        "--ci", type=float, default=0.95, metavar="LEVEL", help="interval level (default: 0.95)"
    )
    p.add_argument(
        "--lapse-max",
        type=float,
        default=0.1,
        metavar="L",
        help="upper bound of the fitted lapse rate; 0: the paper's plain probit (default: 0.1)",
    )


def _settings(args: argparse.Namespace):
    from gazehdr.experiment.analysis import Settings

    return Settings(args.bootstrap, args.seed, args.ci, args.lapse_max)


def add_analyse_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`analyse RESULTS...`: psychometric fits, rank-sum, Figs. 13-14, one HTML report."""
    what = "fit psychometric functions to experiment results and write an HTML report"
    p = sub.add_parser(
        "analyse",
        aliases=["analyze"],
        help=what,
        description=what + " (gazehdr docs experiment-analysis)",
        epilog="examples:\n"
        "  gazehdr experiment analyse results/ --out report/report.html\n"
        "  gazehdr experiment analyse results/sub-01 results/sub-02 --bootstrap 2000 --seed 7",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "results",
        nargs="+",
        metavar="RESULTS",
        help="BIDS dataset folders, subject folders or *_beh.tsv files",
    )
    p.add_argument(
        "--out",
        default="report.html",
        metavar="FILE.html",
        help="the report; results.json and pse.tsv go beside it (default: report.html)",
    )
    _common(p, 1000)
    p.add_argument(
        "--exclude",
        action="append",
        default=[],
        metavar="SUBJECT",
        help="leave this participant out (e.g. after debriefing, Sec. 4.2); repeatable",
    )
    p.add_argument(
        "--training-criterion",
        type=float,
        default=0.7,
        metavar="FRACTION",
        help="exclude observers below this share of training trials correct, where "
        "participants.tsv says nothing (default: 0.7, Sec. 4.1.1; 0: off)",
    )
    p.set_defaults(experiment_run=run_analyse)
    return p


def run_analyse(args: argparse.Namespace) -> int:
    _need_extra()
    from gazehdr.experiment.analysis import analyse
    from gazehdr.experiment.dataset import load
    from gazehdr.experiment.report import write_report

    settings = _settings(args)
    if not 0.0 <= args.training_criterion <= 1.0:
        raise InputError(f"training criterion must be in [0, 1], got {args.training_criterion}")
    out = Path(args.out)
    if out.is_dir():
        raise InputError(f"{out} is a folder: give the report's file name, e.g. {out}/report.html")
    observers = load([Path(r) for r in args.results], args.exclude, args.training_criterion)
    tasks = analyse(observers, settings)
    paths = write_report(tasks, settings, out)
    for t in tasks:
        g = t.group
        test = f"rank-sum p = {g.ranksum.p:.3g}" if g.ranksum else "no rank-sum"
        print(
            f"{t.task}: {len(t.included)} observers, {len(t.excluded)} excluded; "
            f"PSEs {g.n_control} control, {g.n_manipulated} manipulated; {test}"
        )
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def add_recovery_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`recovery`: how often the bootstrap interval holds the echo observer's given PSE."""
    what = "check that the analysis recovers the PSE an echo observer is given (interval coverage)"
    p = sub.add_parser(
        "recovery",
        help=what,
        description=what + " (gazehdr docs experiment-analysis)",
        epilog="example:\n  gazehdr experiment recovery --runs 200",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--runs", type=int, default=200, help="experiments (default: 200)")
    p.add_argument(
        "--runner",
        default="headless",
        help="headless: Sec. 4.1's preset through the experiment's trial code (default); "
        "synthetic: the bare trial list, the fit alone",
    )
    p.add_argument("--pse-control", type=float, default=0.0, metavar="LOG10", help="default: 0")
    p.add_argument(
        "--pse-manipulated", type=float, default=-0.05, metavar="LOG10", help="default: -0.05"
    )
    p.add_argument("--sigma", type=float, default=0.08, metavar="LOG10", help="default: 0.08")
    p.add_argument("--lapse", type=float, default=0.02, help="default: 0.02")
    p.add_argument(
        "--require",
        type=float,
        default=0.9,
        metavar="FRACTION",
        help="exit with 1 if any condition's coverage is significantly lower (one-sided "
        "binomial test at 1 %%, so that a few runs do not fail by chance; default: 0.9)",
    )
    _common(p, 1000)
    p.set_defaults(experiment_run=run_recovery)
    return p


def run_recovery(args: argparse.Namespace) -> int:
    _need_extra()
    from gazehdr.experiment.observer import EchoObserver
    from gazehdr.experiment.recovery import RUNNERS, recover

    if args.runner not in RUNNERS:
        raise InputError(f"unknown runner {args.runner!r}; choices: {', '.join(RUNNERS)}")
    truth = EchoObserver(
        pse={"control": args.pse_control, "manipulated": args.pse_manipulated},
        sigma=args.sigma,
        lapse=args.lapse,
    )
    settings = _settings(args)

    def progress(done: int, runs: int) -> None:
        if done == runs or done % max(1, runs // 10) == 0:
            sys.stderr.write(f"{done}/{runs} runs\n")

    coverage = recover(RUNNERS[args.runner], truth, args.runs, settings, progress=progress)
    ok = True
    for c in coverage:
        ok &= not below(c.covered, c.runs, args.require)
        print(
            f"{c.condition}: true PSE {c.true_pse:+.3f}: {c.covered}/{c.runs} intervals hold it "
            f"({c.rate:.1%}); {c.no_interval} without an interval; mean error "
            f"{c.mean_error:+.4f}, mean {settings.ci:.0%} interval width {c.mean_width:.4f}"
        )
    total = sum(c.runs for c in coverage)
    covered = sum(c.covered for c in coverage)
    rate = covered / total if total else 0.0
    print(f"coverage {covered}/{total} = {rate:.1%} (required: {args.require:.0%})")
    if not ok:
        sys.stderr.write(f"{PROG}: coverage significantly below {args.require:.0%}\n")
    return 0 if ok else 1


def below(covered: int, runs: int, require: float, alpha: float = 0.01) -> bool:
    """Whether `covered` of `runs` intervals is significantly fewer than the share `require`
    (one-sided exact binomial test): for 0.9, 14 of 20 is not, 160 of 200 is."""
    from scipy.stats import binomtest

    return runs > 0 and binomtest(covered, runs, require, alternative="less").pvalue < alpha


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """This module's `gazehdr experiment` subcommands."""
    add_analyse_parser(sub)
    add_recovery_parser(sub)
