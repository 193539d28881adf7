"""Reading BIDS files: sidecars merged down from the dataset root (the inheritance principle),
header-less TSV.GZ rows, and one `_physio` recording's samples.

What import assumes:

- Sample time: the `timestamp` column in its sidecar `Units` (s, ms, us/µs, ns). Without a
  unit (eye2bids writes none) it is the one of s/ms/µs/ns whose median step matches
  `SamplingFrequency`. Without a `timestamp` column: `StartTime + (row − 1) / SamplingFrequency`.
"""

from __future__ import annotations

import csv
import gzip
import io
import itertools
import json
import math
import statistics
import zlib
from collections.abc import Iterator
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

from gazehdr.drivers.formats.bids.files import NA, _split_name, file_stem
from gazehdr.drivers.samples import EyeSample
from gazehdr.drivers.sessionlog import FormatError

UNITS_NS = {"s": 10**9, "ms": 10**6, "us": 10**3, "µs": 10**3, "μs": 10**3, "ns": 1}


def _load_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise FormatError(path, e.lineno, None, f"not valid JSON: {e.msg}") from None
    except UnicodeDecodeError as e:
        raise FormatError(
            path, None, None, f"not UTF-8 text: {e.reason} at byte {e.start}"
        ) from None
    except RecursionError:  # Python's parser recurses once per level of nesting
        raise FormatError(path, None, None, "not valid JSON: nested too deeply") from None
    if not isinstance(data, dict):
        raise FormatError(path, 1, None, "a sidecar is a JSON object")
    return data


class Sidecar(dict):  # type: ignore[type-arg]
    """A sidecar merged from several files, which knows the file each key came from, so that
    an error names the file to fix; a key no file has is the data file's own sidecar's."""

    def __init__(self, own: Path) -> None:
        super().__init__()
        self.own = own
        self.sources: dict[str, Path] = {}

    def where(self, key: str) -> Path:
        """The file that gave `key` (`timestamp.Units`: the one that gave `timestamp`)."""
        return self.sources.get(key.split(".", 1)[0], self.own)

    def error(self, key: str, reason: str) -> FormatError:
        return FormatError(self.where(key), None, key, reason)


def _sidecar(data_file: Path, suffix: str, entities: dict[str, str]) -> Sidecar:
    """The `suffix` sidecar that applies to `data_file`, merged down from the dataset root
    (BIDS "The Inheritance Principle": the file with more of the entities wins)."""
    own = {k: v for k, v in entities.items() if suffix != "events" or k != "recording"}
    dirs = []
    d = data_file.parent
    for _ in range(5):
        dirs.append(d)
        if (d / "dataset_description.json").exists() or d.parent == d:
            break
        d = d.parent
    merged = Sidecar(data_file.with_name(file_stem(own, suffix) + ".json"))
    for directory in reversed(dirs):
        found = []
        for candidate in directory.glob(f"*_{suffix}.json"):
            ents, sfx = _split_name(candidate.name)
            if sfx == suffix and all(entities.get(k) == v for k, v in ents.items()):
                found.append((len(ents), candidate))
        for _, candidate in sorted(found):
            data = _load_json(candidate)
            merged.update(data)
            merged.sources.update(dict.fromkeys(data, candidate))
    return merged


def _units(sidecar: dict[str, Any], column: str) -> str | None:
    spec = sidecar.get(column)
    return spec.get("Units") if isinstance(spec, dict) else None


def _rows(path: Path, columns: list[str]) -> Iterator[tuple[int, dict[str, str]]]:
    """(line, {column: text}) for each row of a header-less TSV.GZ file (a UTF-8 byte order
    mark, as some converters write, is skipped)."""
    try:
        with io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="") as f:
            reader = csv.reader(f, delimiter="\t")
            for row in reader:
                if not row or not any(v.strip() for v in row):
                    continue
                if len(row) != len(columns):
                    raise FormatError(
                        path,
                        reader.line_num,
                        None,
                        f"{len(row)} fields; the sidecar's Columns names {len(columns)} "
                        f"({', '.join(columns)})",
                    )
                yield reader.line_num, dict(zip(columns, (v.strip() for v in row), strict=True))
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as e:
        if isinstance(e, FileNotFoundError):
            raise
        raise FormatError(path, None, None, f"cannot read as gzip TSV: {e}") from None


def _float(path: Path, line: int, row: dict[str, str], column: str) -> float | None:
    text = row[column]
    if text == NA or text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise FormatError(path, line, column, f"expected a number or n/a, got {text!r}") from None
    return value if math.isfinite(value) else None


class _Recording:
    """One `_physio.tsv.gz` with its merged sidecar."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.entities, _ = _split_name(path.name)
        self.times: list[int] = []  # the rows' times, once read
        self.sidecar = _sidecar(path, "physio", self.entities)
        side = self.sidecar
        columns = side.get("Columns")
        if not isinstance(columns, list) or not all(isinstance(c, str) for c in columns):
            raise side.error("Columns", "required: the list of the TSV's column names")
        for needed in ("x_coordinate", "y_coordinate"):
            if needed not in columns:
                raise side.error("Columns", f"no '{needed}' column: not eye-tracking data")
        self.columns = columns
        physio_type = side.get("PhysioType", "eyetrack")
        if physio_type != "eyetrack":
            raise side.error("PhysioType", f"{physio_type!r}; expected 'eyetrack'")
        eye = side.get("RecordedEye", "cyclopean")
        if not isinstance(eye, str) or eye.lower() not in ("left", "right", "cyclopean"):
            raise side.error("RecordedEye", f"expected left, right or cyclopean, got {eye!r}")
        self.eye = eye.lower()
        system = side.get("SampleCoordinateSystem", "gaze-on-screen")
        if system != "gaze-on-screen":
            raise side.error("SampleCoordinateSystem", f"{system!r}; expected gaze-on-screen")
        units = side.get("SampleCoordinateUnits") or _units(side, "x_coordinate")
        if str(units).lower() not in ("pixel", "pixels", "px"):
            raise side.error(
                "SampleCoordinateUnits",
                f"{units!r}; gazehdr imports screen pixels ('pixel')",
            )
        self.fs = side.get("SamplingFrequency")
        if self.fs is not None and self.fs != NA:
            if not isinstance(self.fs, (int, float)) or not self.fs > 0:
                raise side.error(
                    "SamplingFrequency",
                    f"expected a positive number, got {self.fs!r}",
                )
        else:
            self.fs = None

    def read(self, flip_height: int | None) -> list[tuple[int, EyeSample]]:
        """(t_ns, position) per row; a lost position is NaN. Keeps the row times in `times`."""
        rows = list(_rows(self.path, self.columns))
        times = self._times(rows)
        has_pupil = "pupil_size" in self.columns and str(
            _units(self.sidecar, "pupil_size")
        ).lower() in ("mm", "millimeter", "millimetre")
        self.times = times
        out = []
        for t, (line, row) in zip(times, rows, strict=True):
            x = _float(self.path, line, row, "x_coordinate")
            y = _float(self.path, line, row, "y_coordinate")
            pupil = _float(self.path, line, row, "pupil_size") if has_pupil else None
            if x is None or y is None:
                out.append((t, EyeSample(math.nan, math.nan, pupil)))
                continue
            if flip_height is not None:
                y = flip_height - y
            out.append((t, EyeSample(x, y, pupil)))
        return out

    def _times(self, rows: list[tuple[int, dict[str, str]]]) -> list[int]:
        if "timestamp" not in self.columns:
            if self.fs is None:
                raise self.sidecar.error(
                    "SamplingFrequency",
                    "needed to time the rows of a file without a timestamp column",
                )
            start = self.sidecar.get("StartTime", 0)
            if not isinstance(start, (int, float)):
                raise self.sidecar.error("StartTime", f"expected seconds, got {start!r}")
            return [round((start + i / self.fs) * 1e9) for i in range(len(rows))]
        raw: list[Decimal] = []
        for line, row in rows:
            text = row["timestamp"]
            try:
                value = Decimal(text)
            except InvalidOperation:
                value = Decimal("nan")
            if not value.is_finite():
                raise FormatError(self.path, line, "timestamp", f"expected a number, got {text!r}")
            raw.append(value)
        self.timestamp_unit_ns = self._timestamp_unit(raw)
        times = [int((v * self.timestamp_unit_ns).to_integral_value()) for v in raw]
        for (line, _), a, b in zip(rows[1:], times, times[1:], strict=False):
            if b < a:
                raise FormatError(self.path, line, "timestamp", "goes back in time")
        return times

    def _timestamp_unit(self, raw: list[Decimal]) -> int:
        """ns per unit of the timestamp column: its sidecar Units, else inferred."""
        units = _units(self.sidecar, "timestamp")
        if units is not None:
            if units not in UNITS_NS:
                raise self.sidecar.error(
                    "timestamp.Units",
                    f"{units!r}; supported: {', '.join(UNITS_NS)}",
                )
            return UNITS_NS[units]
        steps = [float(b - a) for a, b in itertools.pairwise(raw) if b > a]
        if self.fs and steps:
            period_ns = 1e9 / self.fs
            for scale in (10**9, 10**6, 10**3, 1):
                if abs(statistics.median(steps) * scale - period_ns) <= 0.25 * period_ns:
                    return scale
        raise self.sidecar.error(
            "timestamp.Units",
            "missing, and the sample spacing fits none of s, ms, us, ns at SamplingFrequency",
        )
