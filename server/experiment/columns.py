"""The columns of an experiment's `_beh.tsv`: the one contract between the runner that writes
results and the analysis that reads them. The BIDS sidecar (`_beh.json`) is made from this table,
so a column cannot be written without being described.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Column:
    description: str
    units: str | None = None
    levels: dict[str, str] | None = None


#: Conditions of a trial; the analysis fits one psychometric function per (observer, condition).
CONDITIONS = {
    "training": "large brightness differences, unmanipulated; scored, not analysed (Sec. 4.1.1)",
    "control": "test and standard rendered alike (weak afterimage in 4.1, no mesopic cues in 4.2)",
    "manipulated": "the test carries the manipulation (strong afterimage in 4.1, mesopic cues in "
    "4.2)",
    "palette": "one flash, then the observer picks the afterimage colours seen (Sec. 4.3)",
}

BEH_COLUMNS: dict[str, Column] = {
    "trial": Column("trial number within the run, from 1, in presentation order"),
    "block": Column("block number within the run, from 1 (Sec. 4.1.1: training, control, final)"),
    "condition": Column("what this trial measures", levels=CONDITIONS),
    "standard_intensity": Column("the standard's intensity (n/a in palette trials)", "cd/m^2"),
    "test_intensity": Column("the test's intensity (the flash's, in palette trials)", "cd/m^2"),
    "log_relative_intensity": Column("log10(test_intensity / standard_intensity)", "log10"),
    "test_interval": Column("which interval showed the test: 1 or 2 (n/a in palette trials)"),
    "response_key": Column("the key the observer pressed (n/a: no response)"),
    "chose_test": Column(
        "1 if the observer judged the test brighter, 0 if the standard (n/a in palette trials)"
    ),
    "correct": Column("training trials: 1 if the brighter image was chosen, else 0; n/a otherwise"),
    "palette_choice": Column(
        "palette trials: the option(s) picked, comma-separated labels "
        "(Fig. 15's columns and rows, e.g. H1); n/a otherwise"
    ),
    "response_time": Column("from the response prompt to the key press", "s"),
    "onset": Column("trial start, from the start of the run, on the simulation clock", "s"),
    "flash_duration": Column(
        "how long the stimulus was on, measured from the frames' "
        "simulation times (first frame of the next phase minus first "
        "frame of the stimulus)",
        "s",
    ),
    "black_duration": Column(
        "how long the black screen after the stimulus lasted, measured the same way", "s"
    ),
    "frames_late": Column(
        "frames of the trial the browser did not show at their time: not yet received, or "
        "passed over when its display loop came late (the frame before stayed longer); 0 is a "
        "trial shown as rendered; n/a without a browser"
    ),
}
