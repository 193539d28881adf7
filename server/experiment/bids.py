"""An experiment's results as a BIDS dataset of behavioural data: dataset_description.json,
participants.tsv (+ .json) with each observer's training score and exclusion, and per run
`sub-<id>/beh/sub-<id>_task-<name>[_run-<n>]_beh.tsv` with its sidecar made from `BEH_COLUMNS`.
The runs' session logs live in `sourcedata/`, which the validator leaves alone."""

from __future__ import annotations

import errno
import json
import math
from importlib.metadata import version
from pathlib import Path
from typing import Any

from gazehdr.atomic import write_text
from gazehdr.drivers.formats.bids.files import NA
from gazehdr.drivers.formats.bids.layout import open_dataset, write_json
from gazehdr.experiment.columns import BEH_COLUMNS
from gazehdr.experiment.design import Design


def participant_columns(task: str) -> dict[str, dict[str, Any]]:
    """participants.tsv's columns for a task's runs: one observer may run several tasks (4.1 and
    4.2 in the paper), each with its own training and exclusion, so each task has its own."""
    return {
        f"{task}_training_score": {
            "Description": f"task {task}: fraction of the scored training trials answered "
            "correctly (Sec. 4.1.1)"
        },
        f"{task}_excluded": {
            "Description": f"task {task}: whether the observer was excluded by the training rule",
            "Levels": {"true": "scored below the design's min_correct", "false": "kept"},
        },
    }


def start_dataset(root: Path, design: Design) -> None:
    """Make `root` a dataset for `design`'s results, or check that it is one already; a folder
    that is neither new, empty, nor a dataset is refused (it is the root, not a folder in it)."""
    open_dataset(root, design.title, {"Name": "gazehdr", "Version": version("gazehdr")}, (
        f"Results of `gazehdr experiment` (design `{design.source}`): one `_beh.tsv` per run, "
        "two-alternative forced-choice brightness judgements; the runs' session logs (every "
        "trial's events, the gaze, the responses) are in `sourcedata/`.\n"
    ))  # fmt: skip


def beh_path(root: Path, observer_id: str, stem: str) -> Path:
    return root / f"sub-{observer_id}" / "beh" / f"{stem}.tsv"


def refuse_existing(root: Path, observer_id: str, stem: str) -> None:
    path = beh_path(root, observer_id, stem)
    if path.exists():
        raise FileExistsError(
            errno.EEXIST, "this observer has this run already: give another run number", str(path)
        )


def cell(value: Any) -> str:
    """A TSV cell: n/a for nothing (or a non-finite number), numbers as Python writes them."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return NA
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        return repr(round(value, 9))
    return str(value)


def sidecar(design: Design) -> dict[str, Any]:
    """The `_beh.json`: every column of `BEH_COLUMNS`, described."""
    out: dict[str, Any] = {
        "TaskName": design.title,
        "TaskDescription": "two-alternative forced choice, method of constant stimuli: which of "
        "two intervals (standard, test) was brighter",
        "Instructions": design.texts.instructions,
    }
    for name, col in BEH_COLUMNS.items():
        entry: dict[str, Any] = {"Description": col.description}
        if col.units:
            entry["Units"] = col.units
        if col.levels:
            entry["Levels"] = dict(col.levels)
        out[name] = entry
    return out


def write_results(
    root: Path,
    design: Design,
    observer_id: str,
    stem: str,
    rows: list[dict[str, Any]],
    *,
    score: float | None,
    excluded: bool,
) -> Path:
    """Write one run's `_beh.tsv` and sidecar and the observer's participants.tsv row; the
    path of the `_beh.tsv`."""
    path = beh_path(root, observer_id, stem)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["\t".join(BEH_COLUMNS)]
    lines += ["\t".join(cell(row.get(c)) for c in BEH_COLUMNS) for row in rows]
    write_text(path, "\n".join(lines) + "\n")
    write_json(path.with_suffix(".json"), sidecar(design))
    score_cell = NA if score is None else cell(float(score))
    descriptions = participant_columns(design.name)
    score_col, excluded_col = descriptions
    values = {score_col: score_cell, excluded_col: "true" if excluded else "false"}
    set_participant(root, observer_id, values, descriptions)
    return path


def set_participant(
    root: Path,
    observer_id: str,
    values: dict[str, str],
    descriptions: dict[str, dict[str, Any]] | None = None,
) -> None:
    """Add or update the observer's row of participants.tsv (other columns kept, n/a where a
    row has none); participants.json describes the columns."""
    path = root / "participants.tsv"
    header, rows = ["participant_id"], []
    if path.exists():
        lines = path.read_text(encoding="utf-8").lstrip("\ufeff").splitlines()
        header = lines[0].split("\t")
        rows = [dict(zip(header, line.split("\t"), strict=False)) for line in lines[1:] if line]
    header += [c for c in values if c not in header]
    participant = f"sub-{observer_id}"
    row = next((r for r in rows if r.get("participant_id") == participant), None)
    if row is None:
        row = {"participant_id": participant}
        rows.append(row)
    row.update(values)
    text = ["\t".join(header)] + ["\t".join(r.get(c, NA) for c in header) for r in rows]
    write_text(path, "\n".join(text) + "\n")  # every observer's row: never half-written
    described = root / "participants.json"
    data = json.loads(described.read_text(encoding="utf-8")) if described.exists() else {}
    data.setdefault("participant_id", {"Description": "the observer id given at the start"})
    for column in values:
        data.setdefault(column, (descriptions or {}).get(column, {"Description": column}))
    write_json(described, data)
