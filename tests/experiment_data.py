"""Small generated experiment datasets for the analysis tests: BIDS layout, participants.tsv,
one `_beh.tsv` per observer with Sec. 4.1's trial counts (recovery.synthetic_41_run)."""

from __future__ import annotations

import json
from pathlib import Path

from gazehdr.experiment.observer import EchoObserver
from gazehdr.experiment.recovery import synthetic_41_run


def write_dataset(
    root: Path,
    observers: dict[str, EchoObserver],
    excluded: frozenset[str] = frozenset(),
    task: str = "afterimage",
) -> Path:
    """A BIDS dataset at `root`: `observers` maps a participant id (sub-…) to its observer."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "dataset_description.json").write_text(
        json.dumps({"Name": "test", "BIDSVersion": "1.11.1", "DatasetType": "raw"})
    )
    rows = ["participant_id\ttraining_score\texcluded"]
    for i, (participant, observer) in enumerate(observers.items()):
        synthetic_41_run(i, observer, root, task=task, participant=participant)
        rows.append(f"{participant}\t0.9\t{'true' if participant in excluded else 'false'}")
    (root / "participants.tsv").write_text("\n".join(rows) + "\n")
    return root
