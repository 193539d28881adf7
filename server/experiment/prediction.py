"""`gazehdr experiment run ... --headless`: a group of simulated observers, each with its own seed,
through the experiment's own trial code, then the paper's analysis (a PSE per observer and
condition, the rank-sum test), printed beside the paper's results (Sec. 4.1.2, 4.2.2, Fig. 14)
where the design is one of the paper's. With the model observer that is the model's
prediction; with the echo observer, a pipeline check. The observers are never given the
paper's numbers: they are only printed beside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.experiment.design import Design
from gazehdr.experiment.observer import ModelObserver, Observer
from gazehdr.experiment.schedule import log_ratio


@dataclass(frozen=True)
class PaperResult:
    """What Jacobs et al. 2015 report for one experiment (Fig. 14 and its text)."""

    section: str
    observers: int  # PSEs analysed per condition, as the text says
    median_manipulated: float  # log10 units
    p: float  # rank-sum, control against manipulated PSEs


#: By the task label of the paper's presets. 4.1: 13 recruited, 2 excluded by the training
#: rule; 4.2: the same people, one more excluded on debriefing (its p, 2.84e-6, is the exact p
#: of 11 against 11 PSEs without overlap; with 10 against 10 the smallest is 1.08e-5).
PAPER = {
    "afterimage": PaperResult("4.1", 11, -0.02, 0.449),
    "mesopic": PaperResult("4.2", 10, 0.13, 2.84e-6),
}


@dataclass(frozen=True)
class GroupResult:
    task: str
    observers: int  # simulated
    included: int
    median_control: float | None
    median_manipulated: float | None
    n_control: int
    n_manipulated: int
    p: float | None
    method: str | None
    W: float | None
    z: float | None


def participants(design: Design) -> int:
    """How many observers a headless run simulates by default: the paper's count, else one."""
    paper = PAPER.get(design.name)
    return paper.observers if paper else 1


def observer_ids(prefix: str, n: int) -> list[str]:
    """`prefix` for one observer, `prefix01`, `prefix02`, ... for more (BIDS labels)."""
    if n == 1:
        return [prefix]
    return [f"{prefix}{i:0{max(2, len(str(n)))}d}" for i in range(1, n + 1)]


def run_group(
    design: Design,
    make_observer: Callable[[int], Observer],
    out_dir: Path,
    *,
    observers: int,
    seed: int,
    size: tuple[int, int],
    backend: str,
    prefix: str = "sim",
    run: int | None = None,
) -> list[Path]:
    """`observers` headless runs into one dataset: observer i (from 0) has seed `seed + i`,
    for its trial order and its answers (`make_observer(seed)`)."""
    from gazehdr.experiment.runner import run_headless

    if observers < 1:
        raise InputError(f"observers must be at least 1, got {observers}")
    paths = []
    for i, sub in enumerate(observer_ids(prefix, observers)):
        observer = make_observer(seed + i)
        paths.append(
            run_headless(design, observer, out_dir, seed=seed + i, size=size, observer_id=sub,
                         backend=backend, run=run)
        )  # fmt: skip
    return paths


def analyse_group(paths: list[Path], task: str) -> GroupResult:
    """The paper's analysis of the runs (no bootstrap: PSEs and the rank-sum need none)."""
    from gazehdr.experiment.analysis import Settings, analyse
    from gazehdr.experiment.dataset import load

    (result,) = [t for t in analyse(load(paths), Settings(bootstrap=0)) if t.task == task]
    g = result.group
    rs = g.ranksum
    return GroupResult(
        task, len(result.observers), len(result.included), g.median_control,
        g.median_manipulated, g.n_control, g.n_manipulated, rs.p if rs else None,
        rs.method if rs else None, rs.W if rs else None, rs.z if rs else None,
    )  # fmt: skip


def noiseless_pse(
    design: Design, observer: ModelObserver, size: tuple[int, int], backend: str
) -> dict[str, float | None]:
    """The model observer's PSE per condition without its noise: the log relative intensity at
    which the test's log10 brightness equals the standard's, from a straight line through
    (x, log B_test(x) - log B_standard) at the design's tests (None if it does not rise)."""
    from gazehdr.experiment.runner import percept
    from gazehdr.experiment.stimulus import clip

    out: dict[str, float | None] = {}
    for name in ("control", "manipulated"):
        condition = design.conditions.get(name)
        if condition is None:
            continue
        standard = clip(design, condition.standard, size, backend)
        test = clip(design, condition.test, size, backend)
        b0 = percept(observer, design, standard, design.standard, standard)
        x = np.array([log_ratio(t, design.standard) for t in design.tests])
        d = np.array([percept(observer, design, test, t, standard) - b0 for t in design.tests])
        slope, offset = np.polyfit(x, d, 1) if len(set(x)) > 1 else (0.0, 0.0)
        out[name] = float(-offset / slope) if slope > 0 else None
    return out


def _pse(x: float | None, digits: int = 3) -> str:
    return "n/a" if x is None else f"{x:+.{digits}f}"


def _p(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def summary(
    design: Design,
    group: GroupResult,
    observer_text: str,
    model: bool,
    noiseless: dict[str, float | None] | None = None,
) -> str:
    """The lines printed after a headless run: the simulated group's medians and rank-sum,
    labelled a model prediction (or an echo pipeline check), the paper's beside; `noiseless`,
    the model observer's PSEs without its noise."""
    paper = PAPER.get(design.name)
    where = f" (Jacobs et al. 2015, Sec. {paper.section})" if paper else ""
    label = "model prediction" if model else "echo (PSEs given)"
    ours = f"{label} ({group.included} simulated)"
    theirs = f"paper ({paper.observers} human observers)" if paper else ""
    test = "n/a"
    if group.p is not None:
        test = f"{_p(group.p)} ({group.method}, W = {group.W:g}, z = {group.z:.2f})"
    rows = [
        ("", ours, theirs),
        ("median PSE, control (log10)", _pse(group.median_control),
         "near 0 (not given)" if paper else ""),
        ("median PSE, manipulated (log10)", _pse(group.median_manipulated),
         _pse(paper.median_manipulated) if paper else ""),
        ("rank-sum p, control vs manipulated", test, _p(paper.p) if paper else ""),
        ("PSEs per condition", f"{group.n_control} control, {group.n_manipulated} manipulated",
         f"{paper.observers}" if paper else ""),
    ]  # fmt: skip
    if noiseless is not None:
        rows.insert(3, ("PSE without noise, control / manipulated",
                        " / ".join(_pse(noiseless.get(c), 4) for c in ("control", "manipulated")),
                        ""))  # fmt: skip
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    lines = [
        f"{design.name}{where}: {group.observers} simulated observers, {group.included} "
        f"analysed ({group.observers - group.included} excluded by the training rule)",
        f"  observer: {observer_text}",
    ]
    lines += [f"  {a:<{w0}}  {b:<{w1}}  {c}".rstrip() for a, b, c in rows]
    if not model:
        lines.append("  (the echo observer answers from the PSEs given: this is no prediction)")
    return "\n".join(lines)
