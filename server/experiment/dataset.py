"""Reading experiment results for the analysis: `_beh.tsv` runs (columns.BEH_COLUMNS) found in
BIDS datasets, subject folders or given as files, and what participants.tsv says of each
participant (docs/experiment-analysis.md, "What is read").
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import NA
from gazehdr.experiment.schedule import log_ratio

#: The columns the analysis needs; the others of BEH_COLUMNS are carried but not required.
REQUIRED = ("condition", "chose_test")
_TRUE = {"1", "true", "yes", "y", "t", "excluded", "exclude"}
_FALSE = {"0", "false", "no", "n", "f", "included", "include", "", NA}
_EXCLUDED_NAMES = ("excluded", "exclude", "is_excluded", "exclusion")


class ResultsError(InputError):
    """Results that cannot be read; the message names the file."""


@dataclass(frozen=True)
class Trial:
    condition: str
    x: float | None  # log10 relative intensity
    chose_test: float | None  # 1, 0, or None (n/a: no response)
    test_intensity: float | None
    correct: float | None
    palette_choice: tuple[str, ...]


@dataclass
class Observer:
    """One participant's trials in one task, from one or more runs."""

    participant: str
    task: str
    trials: list[Trial] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    excluded: bool = False
    exclusion: str = ""  # why (and on whose word)
    training_score: float | None = None  # participants.tsv's, as written

    @property
    def training(self) -> tuple[int, int]:
        """Training trials answered correctly, and answered at all."""
        scored = [
            t.correct for t in self.trials if t.condition == "training" and t.correct is not None
        ]
        return int(sum(scored)), len(scored)


def _number(text: str, path: Path, line: int, column: str) -> float | None:
    if text.strip() in ("", NA):
        return None
    try:
        value = float(text)
    except ValueError:
        raise ResultsError(
            f"{path}:{line}: {column}: expected a number or n/a, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise ResultsError(f"{path}:{line}: {column}: expected a finite number, got {text!r}")
    return value


def _log_relative(row: dict[str, str], path: Path, line: int) -> float | None:
    x = _number(row.get("log_relative_intensity", NA), path, line, "log_relative_intensity")
    if x is not None:
        return x
    test = _number(row.get("test_intensity", NA), path, line, "test_intensity")
    standard = _number(row.get("standard_intensity", NA), path, line, "standard_intensity")
    if test and standard and test > 0 and standard > 0:
        return log_ratio(test, standard)
    return None


def read_beh(path: Path) -> list[Trial]:
    """The trials of one `_beh.tsv`, in file order."""
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.DictReader(f, delimiter="\t")
        missing = [c for c in REQUIRED if c not in (reader.fieldnames or [])]
        if missing:
            raise ResultsError(f"{path}: no {', '.join(missing)} column (a _beh.tsv of gazehdr?)")
        trials = []
        for line, row in enumerate(reader, start=2):
            chose = _number(row["chose_test"], path, line, "chose_test")
            if chose not in (None, 0.0, 1.0):
                raise ResultsError(f"{path}:{line}: chose_test: expected 1, 0 or n/a")
            choice = row.get("palette_choice") or NA
            trials.append(
                Trial(
                    condition=(row["condition"] or NA).strip(),
                    x=_log_relative(row, path, line),
                    chose_test=chose,
                    test_intensity=_number(
                        row.get("test_intensity", NA), path, line, "test_intensity"
                    ),
                    correct=_number(row.get("correct", NA), path, line, "correct"),
                    palette_choice=()
                    if choice.strip() == NA
                    else tuple(c.strip() for c in choice.split(",") if c.strip()),
                )
            )
    return trials


def find_beh_files(paths: Sequence[Path]) -> list[Path]:
    """Every `_beh.tsv` in the given datasets, subject folders (sessions too) or files."""
    found: list[Path] = []
    for path in paths:
        if path.is_file():
            if not path.name.endswith("_beh.tsv"):
                raise ResultsError(f"{path}: not a *_beh.tsv file")
            found.append(path)
        elif path.is_dir():
            inside = sorted(path.glob("**/*_beh.tsv"))
            if not inside:
                raise ResultsError(f"{path}: no *_beh.tsv below this folder")
            found.extend(inside)
        else:
            raise ResultsError(f"{path}: no such file or folder")
    unique = list(dict.fromkeys(p.resolve() for p in found))
    return unique


def _entity(name: str, key: str) -> str | None:
    match = re.search(rf"(?:^|_){key}-([A-Za-z0-9]+)", name)
    return match[1] if match else None


def participant_of(path: Path) -> str:
    """`sub-<label>` from the file name, else from a `sub-*` folder above it, else the name."""
    label = _entity(path.name, "sub")
    if label:
        return f"sub-{label}"
    for parent in path.parents:
        if parent.name.startswith("sub-"):
            return parent.name
    return path.name.removesuffix("_beh.tsv")


def dataset_root(path: Path) -> Path | None:
    """The nearest folder above `path` with a dataset_description.json."""
    for parent in path.parents:
        if (parent / "dataset_description.json").is_file():
            return parent
    return None


@dataclass(frozen=True)
class ParticipantInfo:
    excluded: bool | None  # None: the column is missing or n/a
    training_score: float | None
    columns: tuple[str, str | None]  # which columns were read: (excluded's, training's)


def _truth(text: str, path: Path, line: int, column: str) -> bool | None:
    value = text.strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return None if value in ("", NA) else False
    raise ResultsError(
        f"{path}:{line}: {column}: expected 1/0, true/false, yes/no or n/a, got {text!r}"
    )


def read_participants(path: Path, task: str) -> dict[str, ParticipantInfo]:
    """participants.tsv for `task`'s observers: the task's own columns where present
    (`TASK_excluded`, `TASK_training_score`: what `gazehdr experiment run` writes, since one
    observer may run several tasks), else an `excluded`-like column (excluded, exclude,
    is_excluded, exclusion) read as a boolean and the first column naming `training` as the
    training score."""
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.DictReader(f, delimiter="\t")
        header = reader.fieldnames or []
        if "participant_id" not in header:
            raise ResultsError(f"{path}: no participant_id column")
        lower = {h.lower(): h for h in header}
        own = [f"{task}_{n}".lower() for n in _EXCLUDED_NAMES]
        excluded_col = next((lower[n] for n in (*own, *_EXCLUDED_NAMES) if n in lower), None)
        training_col = lower.get(f"{task}_training_score".lower()) or next(
            (h for h in header if "training" in h.lower() and not _other_task(h, task)), None
        )
        info = {}
        for line, row in enumerate(reader, start=2):
            excluded = None
            if excluded_col:
                excluded = _truth(row.get(excluded_col) or NA, path, line, excluded_col)
            score = None
            if training_col:
                score = _number(row.get(training_col) or NA, path, line, training_col)
            info[row["participant_id"].strip()] = ParticipantInfo(
                excluded, score, (excluded_col or "", training_col)
            )
    return info


def _other_task(column: str, task: str) -> bool:
    """Whether `column` is another task's own (`OTHER_training_score`)."""
    prefix, sep, _ = column.partition("_training")
    return bool(sep and prefix) and prefix.lower() != task.lower()


def load(
    paths: Sequence[Path], exclude: Iterable[str] = (), training_criterion: float = 0.7
) -> list[Observer]:
    """The observers of every task found, each marked excluded or not (and why).

    Exclusion, first that applies: named in `exclude`; participants.tsv's excluded column;
    else the paper's training rule, fewer than `training_criterion` of the training trials
    correct (Sec. 4.1.1: 70 %; 0 turns it off).
    """
    observers: dict[tuple[str, str], Observer] = {}
    tables: dict[tuple[Path, str], dict[str, ParticipantInfo]] = {}
    infos: dict[tuple[str, str], ParticipantInfo] = {}
    for path in find_beh_files(paths):
        participant = participant_of(path)
        task = _entity(path.name, "task") or "unknown"
        obs = observers.setdefault((task, participant), Observer(participant, task))
        obs.trials.extend(read_beh(path))
        obs.files.append(str(path))
        root = dataset_root(path)
        if root is not None and (root / "participants.tsv").is_file():
            if (root, task) not in tables:
                tables[root, task] = read_participants(root / "participants.tsv", task)
            if participant in tables[root, task]:
                infos[task, participant] = tables[root, task][participant]
    named = {e if e.startswith("sub-") else f"sub-{e}" for e in exclude}
    for obs in observers.values():
        info = infos.get((obs.task, obs.participant))
        obs.training_score = info.training_score if info else None
        correct, scored = obs.training
        if obs.participant in named:
            obs.excluded, obs.exclusion = True, "excluded on the command line"
        elif info is not None and info.excluded is not None:
            obs.excluded = info.excluded
            obs.exclusion = (
                f"participants.tsv: {info.columns[0]} = {'yes' if info.excluded else 'no'}"
            )
        elif scored and correct < training_criterion * scored:
            obs.excluded = True
            obs.exclusion = (
                f"training: {correct}/{scored} correct, below {training_criterion:.0%} (Sec. 4.1.1)"
            )
    return sorted(observers.values(), key=lambda o: (o.task, o.participant))
