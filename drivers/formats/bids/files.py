"""The BIDS files, as both the importer and the exporter see them: names, entities, missing
values and how text is kept in a TSV value.

Written from BIDS 1.11.1 (bids-standard/bids-specification, tag v1.11.1), whose schema the
official validator `bids-validator-deno` 3.0.2 carries: `src/modality-specific-files/
physiological-recordings.md` ("Continuous physiological recordings", "Physiology events",
"Eye-tracking"), `src/common-principles.md` ("Tabular files", "The Inheritance Principle"),
and the schema's `rules/` (`files/raw/task.yaml`, `sidecars/continuous.yaml`,
`tabular_data/physio.yaml`, `checks/eyetrack.yaml`). What the files are:

- `sub-<label>[_ses-<label>]_task-<label>[_acq-<label>][_run-<index>]_recording-<label>_physio
  .tsv.gz`: gzip, tab-separated, **no header line**; the column names are the sidecar's
  `Columns`. With `"PhysioType": "eyetrack"` the columns start `timestamp, x_coordinate,
  y_coordinate`, then optional `pupil_size`; `n/a` marks a missing value. One recording per
  eye (REQUIRED): `recording-eye1`, `eye2` (and `eye3` for a cyclopean signal), the eye in the
  sidecar's `RecordedEye` (`left`, `right`, `cyclopean`).
- `..._physio.json`: `SamplingFrequency`, `StartTime` (s), `Columns`, `PhysioType`,
  `RecordedEye`, `SampleCoordinateSystem`, and per column a `Units` (REQUIRED for the
  coordinates). Sidecars are inherited: a `task-x_physio.json` at the dataset root applies to
  every file whose entities include its own, the more specific file winning.
- `..._physioevents.tsv.gz` + `.json`: columns `onset` (first), `duration` (seconds, the
  schema's `columns.duration`), `trial_type`, `message`, ...; the REQUIRED `OnsetSource` names
  the physio column whose values `onset` shares (`"timestamp"`), or is `"n/a"`: `onset` is
  then the zero-based physio row, negative before the first.
- `..._events.tsv` + `.json` (REQUIRED with gaze-on-screen eye-tracking): the events sidecar
  carries `StimulusPresentation` with `ScreenDistance`, `ScreenOrigin`, `ScreenResolution`
  and `ScreenSize` (m).

Text values: the validator splits rows on every tab (`src/files/tsv.ts`: no quoting), so a
value must hold no tab or line break. gazehdr writes them, and backslashes, as `\\t`, `\\n`,
`\\r`, `\\\\` and says so with `"GazehdrEscapedText": true` in the sidecar.
"""

from __future__ import annotations

import re

NA = "n/a"

#: The entities gazehdr names files with, in the specification's order (`rules/entities.yaml`).
ENTITY_ORDER = ("sub", "ses", "task", "acq", "run", "recording")
#: A label: alphanumeric (`objects/formats.yaml`, `label`); a run is an `index` (digits).
LABEL = re.compile(r"[a-zA-Z0-9]+")
INDEX = re.compile(r"[0-9]+")
ESCAPED_TEXT = "GazehdrEscapedText"

_ESCAPES = {"\\": "\\\\", "\t": "\\t", "\n": "\\n", "\r": "\\r"}
_UNESCAPES = {v[1]: k for k, v in _ESCAPES.items()}


def _split_name(name: str) -> tuple[dict[str, str], str]:
    """`sub-01_task-x_recording-eye1_physio.tsv.gz` → ({sub, task, recording}, "physio")."""
    stem = name.split(".", 1)[0]
    parts = stem.split("_")
    entities = dict(p.split("-", 1) for p in parts[:-1] if "-" in p)
    return entities, parts[-1]


def file_stem(entities: dict[str, str], suffix: str) -> str:
    """({sub: 01, task: x}, "events") → `sub-01_task-x_events`, entities in the BIDS order."""
    parts = [f"{k}-{entities[k]}" for k in ENTITY_ORDER if entities.get(k) is not None]
    return "_".join([*parts, suffix])


def same_label(key: str, a: str, b: str) -> bool:
    """Entity values equal as BIDS compares them: a run is an index, so `1` is `01`."""
    if key == "run" and INDEX.fullmatch(a) and INDEX.fullmatch(b):
        return int(a) == int(b)
    return a == b


def escape_text(text: str) -> str:
    """A string as one TSV value: tab, line breaks and backslash as `\\t`, `\\n`, `\\r`, `\\\\`."""
    return "".join(_ESCAPES.get(c, c) for c in text)


def unescape_text(text: str) -> str:
    """The inverse of `escape_text`; a backslash before anything else stays as it is."""
    return re.sub(r"\\([\\tnr])", lambda m: _UNESCAPES[m.group(1)], text)
