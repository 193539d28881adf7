"""Recordings of other eye-tracking tools, into and out of the native session log.

Importers (each module's docstring says which documentation it follows, and what it assumes):

- `bids`: BIDS eye-tracking physio, `*_recording-<eye>_physio.tsv.gz` + JSON sidecars and
  `*_physioevents.tsv.gz`, from a dataset, a folder in one, or a file; also the exporter
  (`write_bids`), a run of a dataset that the official validator accepts.
- `eyelink`: SR Research EyeLink ASC files (EDF2ASC output).
- `pupil`: Pupil Player's `gaze_positions.csv`.
- `tobii`: the Tobii TSV written by PyGaze's `libtobii` and by `psychopy_tobii_controller`.
- `xdf`: LabRecorder's XDF (Lab Streaming Layer recordings): one gaze stream and its markers.

Each gives a `SessionLog` (samples in screen pixels, time in integer ns on the recording's clock,
events, notes, the screen geometry where the format records it). Malformed input raises
`FormatError` naming the file, the line and the field. `import_main` and `export_main` are the
`gazehdr import` / `gazehdr export` command lines.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gazehdr.drivers.cli_args import OneLineParser, positive_arg, screen_size_arg
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.layout import SELECTABLE
from gazehdr.drivers.formats.common import geometry_with
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import FormatError, GazeEvent, Note, SessionLog, SessionLogWriter

IMPORTERS: dict[str, tuple[str, str]] = {
    "bids": ("gazehdr.drivers.formats.bids", "read_bids"),
    "eyelink": ("gazehdr.drivers.formats.eyelink", "read_eyelink_asc"),
    "pupil": ("gazehdr.drivers.formats.pupil", "read_pupil_gaze_csv"),
    "tobii": ("gazehdr.drivers.formats.tobii", "read_tobii_tsv"),
    "xdf": ("gazehdr.drivers.formats.xdf", "read_xdf"),
}


# --- dispatch ---------------------------------------------------------------------------------


def detect_format(path: str | Path) -> str:
    """Which importer reads `path`, from its name and (for ambiguous suffixes) its first line."""
    p = Path(path)
    name = p.name.lower()
    if p.is_dir() or name.endswith(("_physio.tsv.gz", "_physio.tsv", "_physio.json")):
        return "bids"
    if name.endswith(".asc"):
        return "eyelink"
    if name.endswith(".edf"):
        raise InputError(
            f"{p}: an EyeLink EDF file is SR Research's binary format; convert it to ASC with "
            f"SR Research's edf2asc first (edf2asc {p.name}, EyeLink Developers Kit), then "
            "import the .asc"
        )
    if name.endswith(".csv"):
        return "pupil"
    if name.endswith((".xdf", ".xdfz", ".xdf.gz")):
        return "xdf"
    if name.endswith((".tsv", ".txt")):
        with p.open(encoding="utf-8", errors="replace") as f:
            if f.readline().startswith("Recording date:"):
                return "tobii"
    raise InputError(
        f"{p}: cannot tell its format from the name; pass --format "
        f"({', '.join(IMPORTERS)}). Expected a BIDS *_physio.tsv.gz, an EyeLink .asc, a Pupil "
        "Player gaze_positions.csv, a Tobii .tsv starting with 'Recording date:' or an .xdf"
    )


def import_recording(path: str | Path, fmt: str = "auto", **options: Any) -> SessionLog:
    """Read a recording in any supported format into a `SessionLog`.

    `options` go to the importer: `geometry` (a `ScreenGeometry` for what the file does not
    record) for all; `select` (bids: {"sub": .., "ses": .., "task": .., "acq": .., "run": ..},
    which run of a dataset) and `strict` (refuse an empty recording); `min_confidence` (pupil);
    `units` (tobii, psychopy_tobii_controller files); `missing`, `eye` and `strict` (eyelink:
    the `edf2asc -miss` string; the eye of a sample-only file; refuse a file at its first line
    not understood).
    """
    if fmt == "auto":
        fmt = detect_format(path)
    if fmt not in IMPORTERS:
        raise InputError(f"unknown format {fmt!r}; known: {', '.join(IMPORTERS)}")
    module, function = IMPORTERS[fmt]
    return getattr(importlib.import_module(module), function)(Path(path), **options)


# --- command lines ----------------------------------------------------------------------------


def import_main(argv: Sequence[str] | None = None) -> int:
    """`gazehdr import FILE --out LOG.jsonl`: a recording → a native session log.

    Returns 0; bad arguments exit with status 2 (one line on stderr); unreadable or malformed
    input raises (`FormatError`/`ValueError`/`OSError`), for the caller to report.
    """
    p = OneLineParser(
        prog="gazehdr import",
        description="Convert an eye-tracking recording into a gazehdr session log (JSON Lines).",
        epilog="examples:\n"
        "  gazehdr import s01.asc --out s01.jsonl\n"
        "  gazehdr import bids/ --sub 01 --run 2 --out s01.jsonl\n"
        "  gazehdr import bids/sub-01 --task x --out s01.jsonl\n"
        "  gazehdr import exports/000/gaze_positions.csv --screen 1280x720 --out s01.jsonl\n"
        "  gazehdr import test.tsv --units height --out s01.jsonl\n"
        "  gazehdr import sub-01_ses-S001_task-T1_run-001_eeg.xdf --stream Tobii --out s01.jsonl",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "file",
        help="the recording: a BIDS dataset, a folder in one (sub-*, ses-*) or a physio file; "
        ".asc, .csv, .tsv, .xdf",
    )
    p.add_argument("--out", required=True, help="the session log to write (.jsonl)")
    p.add_argument("--format", default="auto", choices=["auto", *IMPORTERS])
    p.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    p.add_argument(
        "--screen", type=screen_size_arg, help="screen size WxH in pixels, where the file has none"
    )
    p.add_argument("--diagonal", type=positive_arg, help="screen diagonal in metres (default 0.6)")
    p.add_argument("--distance", type=positive_arg, help="viewing distance in metres (default 1.0)")
    p.add_argument(
        "--units",
        choices=["pix", "norm", "height"],
        help="PsychoPy window units of a psychopy_tobii_controller file (the file does not say)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse an EyeLink file at its first line not understood (by default such a line "
        "becomes a note saying why, and the rest is read), and a BIDS run with an empty "
        "recording (by default a warning)",
    )
    p.add_argument(
        "--missing",
        metavar="VALUE",
        help="EyeLink: the string the file was converted with for missing values (edf2asc "
        "-miss VALUE); '.' is always missing, and a pupil of 0 is lost track whatever x, y say",
    )
    p.add_argument(
        "--eye",
        choices=["left", "right", "both"],
        help="EyeLink: what a sample-only file's samples hold (edf2asc -s names no eye)",
    )
    p.add_argument(
        "--min-confidence",
        type=float,
        default=0.6,
        help="Pupil (and XDF) gaze below this confidence is invalid (default 0.6, Pupil "
        "Player's own)",
    )
    p.add_argument(
        "--stream",
        metavar="NAME",
        help="XDF: the gaze stream to import (its name or source_id), when there are several",
    )
    runs = p.add_argument_group(
        "BIDS", "which run of a dataset, where it holds several (the error lists them)"
    )
    for key in SELECTABLE:
        runs.add_argument(f"--{key}", metavar="LABEL", help=f"the {key}-<label> entity")
    args = p.parse_args(argv)
    fmt = detect_format(args.file) if args.format == "auto" else args.format
    select = {k: getattr(args, k) for k in SELECTABLE if getattr(args, k) is not None}
    if select and fmt != "bids":
        p.error(f"--{next(iter(select))} picks a run of a BIDS dataset; {args.file} is {fmt}")
    geometry = None
    if args.screen or args.diagonal or args.distance:
        width, height = args.screen or (None, None)
        geometry = geometry_with(
            None,
            width_px=width,
            height_px=height,
            diagonal_m=args.diagonal,
            distance_m=args.distance,
        )
    options: dict[str, Any] = {"geometry": geometry}
    if fmt == "bids":
        options["select"] = select
    if fmt in ("pupil", "xdf"):
        options["min_confidence"] = args.min_confidence
    if fmt == "xdf":
        options["stream"] = args.stream
    elif args.stream is not None:
        p.error("--stream is for XDF files")
    if fmt == "tobii":
        options["units"] = args.units
    if fmt in ("eyelink", "bids"):
        options["strict"] = args.strict
    if fmt == "eyelink":
        options["missing"] = args.missing
        options["eye"] = args.eye
    else:
        for flag in ("missing", "eye"):
            if getattr(args, flag) is not None:
                p.error(f"--{flag} is for EyeLink ASC files; {args.file} is {fmt}")
    try:
        if fmt == "bids":  # streamed: memory does not grow with the samples
            from gazehdr.drivers.formats.bids.reader import BidsRun

            geometry_option = options.pop("geometry")
            run = BidsRun(Path(args.file), geometry=geometry_option, **options)
            header, records, warnings = run.header, run.records(), run.warnings
        else:
            log = import_recording(args.file, fmt, **options)
            header, records = log.header, log.records()
            warnings = []
    except ImportError as e:  # an optional reader's package (pyxdf) is not installed
        p.error(str(e))
    for warning in warnings:
        print(f"gazehdr import: warning: {warning}", file=sys.stderr)
    counts = {"samples": 0, "invalid": 0, "events": 0, "notes": 0}
    try:
        with SessionLogWriter(args.out, header, overwrite=args.overwrite) as writer:
            for record in records:
                if isinstance(record, GazeSample):
                    counts["samples"] += 1
                    counts["invalid"] += not record.valid
                elif isinstance(record, GazeEvent):
                    counts["events"] += 1
                elif isinstance(record, Note):
                    counts["notes"] += 1
                writer.write(record)
    except FileExistsError as e:  # name the option that allows it
        raise FileExistsError(
            e.errno,
            "session log already exists; choose another --out, or pass --overwrite",
            e.filename,
        ) from None
    except BaseException:  # a row refused while streaming: no half-written log is left
        Path(args.out).unlink(missing_ok=True)
        raise
    out = Path(args.out)
    screen = header.screen
    unread = header.tracker.get("unread_lines")
    print(
        f"{args.file} ({fmt}): {counts['samples']} samples ({counts['invalid']} invalid), "
        f"{counts['events']} events, {counts['notes']} notes"
        + (
            f" ({unread} line{'s' * (unread > 1)} not read: see the notes 'line N not read')"
            if unread
            else ""
        )
        + f", screen {screen.screen_width_px}x{screen.screen_height_px} -> {out}"
    )
    return 0


def _prefix_error(prefix: str) -> str:
    """What to use instead of the old `--prefix sub-01_task-hdr` (files in --out itself)."""
    entities = dict(p.split("-", 1) for p in prefix.split("_") if "-" in p)
    flags = " ".join(
        f"--{k} {v}" for k, v in entities.items() if k in ("sub", "ses", "task", "run")
    )
    return (
        "--prefix is replaced by entity flags, and --out now names the dataset's root (the "
        "files go to sub-<sub>/[ses-<ses>/]beh/ in it): use " + (flags or "--sub 01 --task NAME")
    )


def export_main(argv: Sequence[str] | None = None) -> int:
    """`gazehdr export LOG.jsonl --out DATASET --sub 01 --task hdr`: a native session log → a run
    of a BIDS dataset (made if new)."""
    p = OneLineParser(
        prog="gazehdr export",
        description="Write a gazehdr session log as a run of a BIDS eye-tracking dataset "
        "(made if --out is new or empty; other runs are left as they are): "
        "sub-<sub>/[ses-<ses>/]beh/ with the run's _events.tsv and, per eye, "
        "_recording-eye<N>_physio.tsv.gz and _physioevents.tsv.gz, with their sidecars.",
        epilog="examples:\n"
        "  gazehdr export s01.jsonl --out bids --sub 01 --task hdr\n"
        "  gazehdr export s02.jsonl --out bids --sub 01 --ses 2 --task hdr --run 1",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("log", help="a gazehdr session log (.jsonl)")
    p.add_argument("--out", required=True, help="the BIDS dataset's root folder")
    p.add_argument("--format", default="bids", choices=["bids"])
    p.add_argument("--sub", default="01", help="subject label (default 01)")
    p.add_argument("--ses", help="session label (default: none)")
    p.add_argument("--task", default="gazehdr", help="task label (default gazehdr)")
    p.add_argument("--run", help="run index (default: none); needed to add a second run")
    p.add_argument("--prefix", help=argparse.SUPPRESS)
    p.add_argument("--overwrite", action="store_true", help="replace this run if it exists")
    args = p.parse_args(argv)
    if args.prefix is not None:
        p.error(_prefix_error(args.prefix))
    from gazehdr.drivers.formats.bids import write_bids
    from gazehdr.drivers.sessionlog import read_session_log

    log = read_session_log(args.log)
    if log.truncated:
        print(f"{args.log}: cut short at line {log.truncated_line}; exporting what was whole")
    written = write_bids(
        log,
        args.out,
        sub=args.sub,
        ses=args.ses,
        task=args.task,
        run=args.run,
        overwrite=args.overwrite,
    )
    print(f"{args.log}: wrote {len(written)} files to the dataset {args.out}")
    for path in written:
        print(f"  {path.relative_to(args.out).as_posix()}")
    return 0


__all__ = [
    "IMPORTERS",
    "FormatError",
    "detect_format",
    "export_main",
    "import_main",
    "import_recording",
]
