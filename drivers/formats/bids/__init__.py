"""BIDS eye-tracking physio (BEP020, merged in BIDS 1.11) ↔ the native session log.

Written from the BIDS specification (bids-standard/bids-specification,
`src/modality-specific-files/physiological-and-other-continuous-recordings.md`, sections
"Continuous physiological recordings", "Physiology events" and "Eye-tracking"; the schema
`src/schema/rules/tabular_data/physio.yaml` and `src/schema/rules/sidecars/continuous.yaml`)
its example dataset `eyetracking_binocular` (bids-standard/bids-examples), which also shows the
inheritance of sidecars from the dataset root, and the reference converter eye2bids
(bids-standard/eye2bids, `eye2bids/edf2bids.py`, `eye2bids/_base.py`) for what real files hold.

The modules:

- `files`: what the files are (names, sidecars, indexing), and the conventions the importer
  and the exporter share.
- `reader`: `read_bids`, a set of recordings into one log, and what import assumes; with
  `physio` (sidecar inheritance, TSV rows, one recording's samples and their times) and
  `physioevents` (fixations, blinks and messages, and their times).
- `writer`: `write_bids`, and what export writes.
"""

from gazehdr.drivers.formats.bids.reader import read_bids
from gazehdr.drivers.formats.bids.writer import write_bids

__all__ = ["read_bids", "write_bids"]
