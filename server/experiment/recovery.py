"""PSE recovery: repeated seeded experiments answered by an EchoObserver of known PSE, slope
and lapse, each analysed as a real result; the bootstrap interval must hold the true PSE in at
least 90 % of them. What runs the experiment is a callable, `run_once(seed, observer,
out_dir) -> beh.tsv`, so the same harness drives the real trial code's headless runner.

`synthetic_41_run` is not an experiment runner: it writes a trial list with Sec. 4.1's counts,
answered by the observer, so that the fit can be tested without the simulator.
"""

from __future__ import annotations

import csv
import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import NA
from gazehdr.experiment.analysis import Settings, analyse
from gazehdr.experiment.columns import BEH_COLUMNS
from gazehdr.experiment.dataset import load
from gazehdr.experiment.observer import EchoObserver

RunOnce = Callable[[int, EchoObserver, Path], Path]

#: Sec. 4.1.1: standard 27 cd/m², five tests; 20 training trials at large differences.
STANDARD = 27.0
TESTS = (14.0, 19.0, 27.0, 35.0, 49.0)
TRAINING_TESTS = (14.0, 49.0)
#: (block, condition, repetitions per test, tests): training, control, then the final block.
DESIGN_41 = (
    (1, "training", 10, TRAINING_TESTS),
    (2, "control", 20, TESTS),
    (3, "manipulated", 30, TESTS),
    (3, "control", 10, TESTS),
)
FLASH, BLACK = 0.05, 2.5


def synthetic_41_run(
    seed: int,
    observer: EchoObserver,
    out_dir: Path,
    *,
    task: str = "afterimage",
    participant: str | None = None,
) -> Path:
    """A `_beh.tsv` with Sec. 4.1's trial counts, shuffled within blocks, answered by `observer`.

    For tests of the analysis only: no frames are rendered, so durations are the design's.
    """
    rng = np.random.default_rng(seed)
    trials = []
    for block in sorted({b for b, *_ in DESIGN_41}):
        mine = [
            (condition, test)
            for b, condition, reps, tests in DESIGN_41
            if b == block
            for test in tests
            for _ in range(reps)
        ]
        trials += [(block, *mine[i]) for i in rng.permutation(len(mine))]
    sub = participant or f"sub-sim{seed}"
    path = out_dir / sub / "beh" / f"{sub}_task-{task}_beh.tsv"
    path.parent.mkdir(parents=True, exist_ok=True)
    onset = 0.0
    with open(path, "w", encoding="utf-8", newline="") as f:
        writer = csv.writer(f, delimiter="\t", lineterminator="\n")
        writer.writerow(BEH_COLUMNS)
        for number, (block, condition, test) in enumerate(trials, start=1):
            x = math.log10(test / STANDARD)
            chose = observer.chooses_test(x, condition)
            interval = int(rng.integers(1, 3))
            key = interval if chose else 3 - interval
            rt = float(rng.lognormal(math.log(0.6), 0.3))
            correct = int(chose == (test > STANDARD)) if condition == "training" else NA
            row = {
                "trial": number,
                "block": block,
                "condition": condition,
                "standard_intensity": STANDARD,
                "test_intensity": test,
                "log_relative_intensity": repr(x),
                "test_interval": interval,
                "response_key": key,
                "chose_test": int(chose),
                "correct": correct,
                "palette_choice": NA,
                "response_time": f"{rt:.3f}",
                "onset": f"{onset:.3f}",
                "flash_duration": FLASH,
                "black_duration": BLACK,
                "frames_late": NA,  # no page showed it
            }
            writer.writerow([row[c] for c in BEH_COLUMNS])
            onset += 2 * (FLASH + BLACK) + rt
    return path


def headless_41_run(seed: int, observer: EchoObserver, out_dir: Path) -> Path:
    """Sec. 4.1's preset through the experiment's own trial code (`runner.run_headless`: the
    page's trial state machine, stimuli rendered by the simulator at 96×54), no browser."""
    from gazehdr.experiment.runner import run_headless  # the simulator: the server extra

    return run_headless("4.1", observer, out_dir, seed=seed)


#: Trial code that `gazehdr experiment recovery --runner` can drive: the experiment's own
#: (`headless`), or the bare trial list (`synthetic`), which tests the fit alone.
RUNNERS: dict[str, RunOnce] = {"headless": headless_41_run, "synthetic": synthetic_41_run}


@dataclass(frozen=True)
class Coverage:
    condition: str
    true_pse: float
    runs: int
    covered: int  # runs whose interval holds the true PSE
    no_interval: int  # runs without an interval (unbounded, flat): counted as not covered
    mean_error: float  # mean (estimate − truth) over runs with a PSE
    mean_width: float  # mean interval width over runs with an interval

    @property
    def rate(self) -> float:
        return self.covered / self.runs if self.runs else 0.0


def recover(
    run_once: RunOnce,
    truth: EchoObserver,
    runs: int,
    settings: Settings,
    work_dir: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Coverage]:
    """`runs` experiments, each with its own seed from `settings.seed`, and their coverage.

    Training exclusion is off: the point is the fit, and a bad simulated run must count.
    `progress(done, runs)` is called after each run.
    """
    if runs < 1:
        raise InputError(f"runs must be at least 1, got {runs}")
    seeds = np.random.SeedSequence(settings.seed).generate_state(runs)
    hits: dict[str, list[tuple[float | None, tuple[float, float] | None]]] = {}
    with tempfile.TemporaryDirectory(prefix="gazehdr-recovery-") as tmp:
        base = work_dir or Path(tmp)
        for i, run_seed in enumerate(seeds):
            observer = replace(truth, seed=int(run_seed))
            out = base / f"run-{i:04d}"
            path = run_once(int(run_seed), observer, out)
            observers = load([path], training_criterion=0.0)
            for task in analyse(observers, replace(settings, seed=int(run_seed))):
                for o in task.included:
                    for condition, f in o.fits.items():
                        hits.setdefault(condition, []).append((f.fit.pse, f.ci))
            if progress:
                progress(i + 1, runs)
    out_list = []
    for condition, found in sorted(hits.items()):
        true = truth.pse.get(condition, 0.0)
        covered = sum(ci is not None and ci[0] <= true <= ci[1] for _, ci in found)
        errors = [p - true for p, _ in found if p is not None]
        widths = [ci[1] - ci[0] for _, ci in found if ci is not None]
        out_list.append(
            Coverage(
                condition,
                true,
                len(found),
                covered,
                sum(ci is None for _, ci in found),
                float(np.mean(errors)) if errors else 0.0,
                float(np.mean(widths)) if widths else 0.0,
            )
        )
    return out_list
