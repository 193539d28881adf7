"""BIDS eye-tracking (BEP020, merged in BIDS 1.11) ↔ the native session log.

Written from BIDS 1.11.1 (bids-standard/bids-specification, tag v1.11.1, the version whose
schema the official validator `bids-validator-deno` 3.0.2 bundles):
`src/modality-specific-files/physiological-recordings.md`, sections "Continuous physiological
recordings", "Physiology events" and "Eye-tracking"; `src/common-principles.md`; the schema
`src/schema/rules/` (`files/raw/task.yaml`, `sidecars/continuous.yaml`,
`tabular_data/physio.yaml`, `checks/eyetrack.yaml`). What real files hold: the example datasets
`eyetracking_binocular` and `eyetracking_eeg_ds007338` (bids-standard/bids-examples) and the
converter eye2bids (bids-standard/eye2bids); how the validator reads a TSV:
bids-standard/bids-validator `src/files/tsv.ts`.

The modules:

- `files`: what the files are (names, entities, sidecars, indexing), and the conventions the
  importer and the exporter share (text escapes).
- `layout`: where runs are in a dataset: the run to import, the dataset to export into.
- `reader`: `read_bids`, one run's recordings into one log, and what import assumes; with
  `physio` (sidecar inheritance, TSV rows, one recording's samples and their times) and
  `physioevents` (fixations, blinks and messages, and their times).
- `writer`: `write_bids`, and what export writes.
"""

from gazehdr.drivers.formats.bids.reader import read_bids
from gazehdr.drivers.formats.bids.writer import write_bids

__all__ = ["read_bids", "write_bids"]
