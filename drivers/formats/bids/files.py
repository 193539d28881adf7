"""The BIDS files, as both the importer and the exporter see them: names, missing values, and
which sample an event's timestamp names.

What the files are:

- `<matches>_recording-<label>_physio.tsv.gz`: gzip, tab-separated, **no header line**; the
  column names are the sidecar's `Columns`. With `"PhysioType": "eyetrack"` the columns start
  `timestamp, x_coordinate, y_coordinate`, then optional `pupil_size`; `n/a` marks a missing
  value. One recording per eye: `recording-eye1`, `eye2` (and `eye3` for a cyclopean signal),
  the eye in the sidecar's `RecordedEye` (`left`, `right`, `cyclopean`).
- `<matches>_recording-<label>_physio.json`: `SamplingFrequency`, `StartTime` (s), `Columns`,
  `PhysioType`, `RecordedEye`, `SampleCoordinateUnits`, `SampleCoordinateSystem`,
  `EnvironmentCoordinates`, and per column a `Units`. Sidecars are inherited: a
  `task-x_physio.json` at the dataset root applies to every file whose entities include its
  own, the more specific file winning (BIDS inheritance principle).
- `<matches>_recording-<label>_physioevents.tsv.gz` + `.json`: columns `onset` (first, the
  schema requires it), `duration`, `trial_type`, `message`, ... With `ForeignIndexColumn` (or
  `OnsetSource`, as in the example dataset) naming the physio file's `timestamp` column, the
  events' column of that name (the specification's "Explicit indexing": each value MUST be one
  of the physio file's timestamps), or `onset` (eye2bids), is in that column's units. Without
  it, a `foreign_index` column is the zero-based row of the physio file, negative before its
  first row (the specification's "Implicit indexing"); lacking one, `onset` is taken as the
  one-based row.
- The screen: `StimulusPresentation` (`ScreenResolution` px, `ScreenSize`, `ScreenDistance`)
  in the sidecars or in the task's `_events.json`.
"""

from __future__ import annotations

import bisect

NA = "n/a"


def _split_name(name: str) -> tuple[dict[str, str], str]:
    """`sub-01_task-x_recording-eye1_physio.tsv.gz` → ({sub, task, recording}, "physio")."""
    stem = name.split(".", 1)[0]
    parts = stem.split("_")
    entities = dict(p.split("-", 1) for p in parts[:-1] if "-" in p)
    return entities, parts[-1]


def _sample_at(times: list[int], t: int) -> int:
    """The time of the sample at or before `t` (the first sample's for an earlier `t`)."""
    return times[max(bisect.bisect_right(times, t) - 1, 0)]
