"""Where runs live in a BIDS dataset: finding the one eye-tracking run to import, and making or
extending a dataset to export one into.

Follows BIDS 1.11.1 `src/common-principles.md` ("Filesystem structure", "Filenames": the
`sub-<label>/[ses-<label>/]<datatype>/` folders; "Entity-linked file collections": one run's
files share all entities but `recording`) and `src/modality-agnostic-files/` (the dataset's
`dataset_description.json`, `README`, `participants.tsv`).

Import (`find_run`) takes a dataset root, any folder inside one (a `sub-*` or `ses-*` folder,
a datatype folder) or one file. In a folder it looks at every `*_physio.tsv.gz` below it, but
not in `derivatives/`, `sourcedata/` or hidden folders, and keeps the eye-tracking recordings
(`PhysioType` "eyetrack", or no `PhysioType` and gaze columns, as drafts wrote): a run is the
recordings that share a folder and all entities but `recording`. Entities given (`--sub`,
`--ses`, `--task`, `--acq`, `--run`) narrow the runs; when more than one is left, the error
lists them and the flags that tell them apart.

Export (`prepare_dataset`) writes `dataset_description.json` and `README.md` into a new dataset,
adds the subject to `participants.tsv` (made if missing), and never touches another run.
"""

from __future__ import annotations

import errno
import json
from collections.abc import Mapping
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import _split_name, file_stem, same_label
from gazehdr.drivers.formats.bids.physio import _load_json, _sidecar
from gazehdr.drivers.sessionlog import FormatError

BIDS_VERSION = "1.11.1"
#: Entities a run can be picked by on the command line (`gazehdr import --run 2`).
SELECTABLE = ("sub", "ses", "task", "acq", "run")
_NOT_RAW = {"derivatives", "sourcedata", "code"}
_RUN_SUFFIXES = ("physio", "physioevents", "events")


def _run_key(name: str) -> dict[str, str]:
    return {k: v for k, v in _split_name(name)[0].items() if k != "recording"}


def _is_eyetrack(path: Path) -> bool:
    side = _sidecar(path, "physio", _split_name(path.name)[0])
    kind = side.get("PhysioType")
    columns = side.get("Columns")
    gaze = isinstance(columns, list) and {"x_coordinate", "y_coordinate"} <= set(columns)
    return kind == "eyetrack" or (kind is None and gaze)


def _selected(entities: Mapping[str, str], select: Mapping[str, str]) -> bool:
    return all(k in entities and same_label(k, entities[k], v) for k, v in select.items())


def _same_run(a: Mapping[str, str], b: Mapping[str, str]) -> bool:
    return a.keys() == b.keys() and all(same_label(k, a[k], b[k]) for k in a)


def _describe(entities: Mapping[str, str]) -> str:
    return " ".join(f"{k}-{v}" for k, v in entities.items())


def find_run(path: Path, select: Mapping[str, str] | None = None) -> list[Path]:
    """The eye-tracking physio files of the one run that `path` (and `select`) names."""
    select = {k: v for k, v in (select or {}).items() if v is not None}
    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(path))
    if path.is_dir():
        return _run_in_folder(path, select)
    name = path.name
    if name.endswith("_physio.json"):
        path = path.with_name(name[: -len(".json")] + ".tsv.gz")
    elif name.endswith("_physio.tsv"):
        raise FormatError(path, None, None, "BIDS physio files are gzipped: *_physio.tsv.gz")
    if _split_name(path.name)[1] != "physio" or not path.name.endswith(".tsv.gz"):
        raise FormatError(path, None, None, "not a BIDS *_physio.tsv.gz file")
    if not path.exists():  # a sidecar named, its data file missing
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(path))
    key = _run_key(path.name)
    if not _selected(key, select):
        wanted = _describe(select)
        raise InputError(f"{path}: this run ({_describe(key)}) is not the one asked for ({wanted})")
    # the named file is read whatever its PhysioType (its errors say what is wrong); the run's
    # other recordings only if they are eye-tracking (a run may hold cardiac ones too)
    return [
        f
        for f in sorted(path.parent.glob("*_physio.tsv.gz"))
        if _run_key(f.name) == key and (f == path or _is_eyetrack(f))
    ]


def _run_in_folder(folder: Path, select: Mapping[str, str]) -> list[Path]:
    runs: dict[tuple[Path, tuple[tuple[str, str], ...]], list[Path]] = {}
    seen = 0
    for f in sorted(folder.rglob("*_physio.tsv.gz")):
        parts = f.relative_to(folder).parts[:-1]
        if any(p in _NOT_RAW or p.startswith(".") for p in parts):
            continue
        seen += 1
        if _is_eyetrack(f):
            runs.setdefault((f.parent, tuple(_run_key(f.name).items())), []).append(f)
    if not runs:
        found = f"{seen} physio file{'s' * (seen > 1)}, none eye-tracking"
        found = found if seen else "no *_physio.tsv.gz file"
        raise FormatError(folder, None, None, f"{found} (searched every folder below it)")
    chosen = {k: v for k, v in runs.items() if _selected(dict(k[1]), select)}
    if len(chosen) == 1:
        return next(iter(chosen.values()))

    def listing(items: dict) -> str:
        lines = []
        for (parent, key), files in items.items():
            where = parent.relative_to(folder).as_posix()
            n = len(files)
            lines.append(f"  {_describe(dict(key))}  ({where}/, {n} recording{'s' * (n > 1)})")
        return "\n".join(lines)

    if not chosen:
        raise InputError(
            f"{folder}: no eye-tracking run has {_describe(select)}; it holds:\n{listing(runs)}"
        )
    keys = [dict(k[1]) for k in chosen]
    differ = [k for k in SELECTABLE if len({d.get(k) for d in keys}) > 1]
    how = " ".join(f"--{k}" for k in differ) if differ else "naming one of its files"
    raise InputError(
        f"{folder}: {len(chosen)} eye-tracking runs; pick one with {how}:\n{listing(chosen)}"
    )


# --- export -----------------------------------------------------------------------------------


def open_dataset(root: Path, name: str, generated_by: dict[str, str], about: str) -> list[Path]:
    """Make `root` a raw BIDS dataset called `name` (its description, and a README of `about`
    under that title), or check that it is one; returns the files written. A folder that is not
    empty and has no `dataset_description.json` is refused: it is a dataset's root that is
    asked for, not a folder inside one."""
    description = root / "dataset_description.json"
    if description.exists():
        data = _load_json(description)
        if "BIDSVersion" not in data:
            raise FormatError(description, None, "BIDSVersion", "required: not a BIDS dataset")
        return []
    if root.exists() and any(root.iterdir()):
        inside = next((p for p in root.parents if (p / description.name).exists()), None)
        hint = f"; its dataset root is {inside}" if inside else ""
        raise InputError(
            f"{root}: not empty and not a BIDS dataset (no dataset_description.json): "
            f"give a new or empty folder, or an existing dataset's root{hint}"
        )
    root.mkdir(parents=True, exist_ok=True)
    write_json(description, {
        "Name": name, "BIDSVersion": BIDS_VERSION, "DatasetType": "raw",
        "GeneratedBy": [generated_by],
    })  # fmt: skip
    readme = root / "README.md"
    readme.write_text(f"# {name}\n\n{about}", encoding="utf-8")
    return [description, readme]


def prepare_dataset(root: Path, subject: str, generated_by: dict[str, str]) -> list[Path]:
    """Make `root` a BIDS dataset (or check that it is one, `open_dataset`) with `subject` in
    participants.tsv. Returns the files written."""
    written = open_dataset(root, "gazehdr sessions", generated_by, (
        "Gaze recorded with gazehdr, a gaze-adaptive HDR display, and exported as BIDS "
        "eye-tracking physio (`gazehdr export`).\nEach run holds one recording per eye "
        "(`recording-eye<N>`), its fixations and blinks (`_physioevents`) and the session's "
        "scene and setting changes (`_events.tsv`).\n"
    ))  # fmt: skip
    participants = root / "participants.tsv"
    if _add_participant(participants, f"sub-{subject}"):
        written.append(participants)
    return written


def _add_participant(path: Path, participant: str) -> bool:
    """Add a row for `participant` (n/a in its other columns); False when it has one."""
    if not path.exists():
        path.write_text(f"participant_id\n{participant}\n", encoding="utf-8")
        return True
    text = path.read_text(encoding="utf-8")
    lines = text.lstrip("\ufeff").splitlines()
    header = lines[0].split("\t") if lines else []
    if "participant_id" not in header:
        raise FormatError(path, 1, "participant_id", "the header has no participant_id column")
    column = header.index("participant_id")
    if any(line.split("\t")[column : column + 1] == [participant] for line in lines[1:]):
        return False
    row = ["n/a"] * len(header)
    row[column] = participant
    ending = "" if text.endswith("\n") else "\n"
    path.write_text(text + ending + "\t".join(row) + "\n", encoding="utf-8")
    return True


def run_files(folder: Path, entities: Mapping[str, str]) -> list[Path]:
    """The files of the run `entities` names in `folder`: its events, physio, physioevents."""
    if not folder.is_dir():
        return []
    return sorted(
        f
        for f in folder.iterdir()
        if _split_name(f.name)[1] in _RUN_SUFFIXES and _same_run(_run_key(f.name), entities)
    )


def refuse_existing_run(folder: Path, entities: Mapping[str, str]) -> None:
    """FileExistsError when `folder` holds the run already, naming the next free run index."""
    existing = run_files(folder, entities)
    if not existing:
        return
    task = {k: v for k, v in entities.items() if k != "run"}
    taken = [1]
    for f in folder.iterdir():
        key = _run_key(f.name)
        run = key.pop("run", "1")  # a run without an index is the first
        if key == task and run.isdigit():
            taken.append(int(run))
    raise FileExistsError(
        errno.EEXIST,
        f"the dataset has this run already ({file_stem(dict(entities), '*')}, "
        f"{len(existing)} files): pass --overwrite to replace it, or --run {max(taken) + 1} "
        "to add another",
        str(existing[0]),
    )


def write_json(path: Path, data: dict) -> None:
    """A sidecar: indented, UTF-8 as it is (BIDS: JSON files MUST be UTF-8)."""
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
