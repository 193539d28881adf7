"""Reading BIDS files: sidecars merged down from the dataset root (the inheritance principle),
header-less TSV.GZ rows, and one `_physio` recording's samples.

What import assumes:

- Sample time: the `timestamp` column in its sidecar `Units` (s, ms, us/µs, ns). Without a
  unit (eye2bids writes none) it is the one of s/ms/µs/ns whose median step (over the first
  10000 rows) matches `SamplingFrequency`. Without a `timestamp` column: `StartTime + (row −
  1) / SamplingFrequency`.
- A recording is read twice, streaming: once for its times (kept as 8-byte integers, which
  row-indexed events need), once for its samples, which go straight to the session log; so
  memory does not grow with the samples.
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
from array import array
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

    def __init__(self, own: Path, data: Path | None = None) -> None:
        super().__init__()
        self.own = own
        self.data = data
        self.sources: dict[str, Path] = {}

    def where(self, key: str) -> Path:
        """The file that gave `key` (`timestamp.Units`: the one that gave `timestamp`)."""
        return self.sources.get(key.split(".", 1)[0], self.own)

    def error(self, key: str, reason: str) -> FormatError:
        """The error about `key`, naming the sidecar that gave it; a key no sidecar gives names
        the data file's own sidecar, where to add it (and says so when it does not exist)."""
        top = key.split(".", 1)[0]
        if top in self.sources:
            return FormatError(self.sources[top], None, key, reason)
        if self.own.exists():
            return FormatError(self.own, None, key, reason)
        return FormatError(
            self.own, None, key, f"{reason} (no sidecar gives it; this one, not there yet, may)"
        )


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
    merged = Sidecar(data_file.with_name(file_stem(own, suffix) + ".json"), data_file)
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


def _lines(path: Path, width: int, columns: list[str]) -> Iterator[tuple[int, list[str]]]:
    """(line, fields) of a header-less TSV.GZ file of numbers, fast: split on tabs (a physio
    file holds no quoted text); the fields of `_rows`, as a list."""
    try:
        with io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="") as f:
            for number, raw in enumerate(f, 1):
                row = raw.rstrip("\r\n").split("\t")
                if len(row) != width:
                    if not raw.strip():
                        continue
                    raise FormatError(
                        path,
                        number,
                        None,
                        f"{len(row)} fields; the sidecar's Columns names {width} "
                        f"({', '.join(columns)})",
                    )
                yield number, row
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as e:
        if isinstance(e, FileNotFoundError):
            raise
        raise FormatError(path, None, None, f"cannot read as gzip TSV: {e}") from None


def _number(path: Path, line: int, text: str, column: str) -> float | None:
    text = text.strip()
    if text == NA or text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise FormatError(path, line, column, f"expected a number or n/a, got {text!r}") from None
    return value if math.isfinite(value) else None


def _float(path: Path, line: int, row: dict[str, str], column: str) -> float | None:
    """`_number` of a named column of a row of `_rows`."""
    return _number(path, line, row[column], column)


class _Recording:
    """One `_physio.tsv.gz` with its merged sidecar. `scan()` reads its times, `samples()` its
    samples, each streaming."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.entities, _ = _split_name(path.name)
        self.times: array[int] = array("q")  # the rows' times, once scanned
        self.timestamp_unit_ns: int | None = None
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
        key = "SampleCoordinateUnits" if "SampleCoordinateUnits" in side else "x_coordinate.Units"
        units = side.get("SampleCoordinateUnits") or _units(side, "x_coordinate")
        if str(units).lower() not in ("pixel", "pixels", "px"):
            raise side.error(key, f"{units!r}; gazehdr imports screen pixels ('pixel')")
        self.fs = side.get("SamplingFrequency")
        if self.fs is not None and self.fs != NA:
            if not isinstance(self.fs, (int, float)) or not self.fs > 0:
                raise side.error(
                    "SamplingFrequency",
                    f"expected a positive number, got {self.fs!r}",
                )
        else:
            self.fs = None
        #: The pupil column's unit: "mm", or "a.u." for any other (the tracker's own units,
        #: as EyeLink's area or diameter: eye2bids writes "a.u."); None without the column.
        self.pupil_unit = (
            None
            if "pupil_size" not in columns
            else "mm"
            if str(_units(side, "pupil_size")).lower() in ("mm", "millimeter", "millimetre")
            else "a.u."
        )

    def scan(self) -> None:
        """Read the rows' times into `times` (and so check every row's shape and time)."""
        width = len(self.columns)
        if "timestamp" not in self.columns:
            rows = sum(1 for _ in _lines(self.path, width, self.columns))
            if self.fs is None:
                if rows == 0:
                    return
                raise self.sidecar.error(
                    "SamplingFrequency",
                    "needed to time the rows of a file without a timestamp column",
                )
            start = self.sidecar.get("StartTime", 0)
            if not isinstance(start, (int, float)):
                raise self.sidecar.error("StartTime", f"expected seconds, got {start!r}")
            self.times = array("q", (round((start + i / self.fs) * 1e9) for i in range(rows)))
            return
        column = self.columns.index("timestamp")
        texts: list[tuple[int, Decimal]] = []  # the first rows, for the unit
        unit: int | None = None
        last = None
        for line, row in _lines(self.path, width, self.columns):
            text = row[column].strip()
            if unit is None:
                texts.append((line, self._decimal(line, text)))
                if len(texts) < 10_000:
                    continue
                unit = self._unit_of(texts)
                for n, value in texts:
                    last = self._push(n, int((value * unit).to_integral_value()), last)
                continue
            t = int(text) * unit if text.isdigit() else None
            if t is None:
                t = int((self._decimal(line, text) * unit).to_integral_value())
            last = self._push(line, t, last)
        if unit is None and texts:
            unit = self._unit_of(texts)
            for n, value in texts:
                last = self._push(n, int((value * unit).to_integral_value()), last)
        self.timestamp_unit_ns = unit if unit is not None else self._declared_unit()

    def _push(self, line: int, t: int, last: int | None) -> int:
        if last is not None and t < last:
            raise FormatError(self.path, line, "timestamp", "goes back in time")
        self.times.append(t)
        return t

    def _decimal(self, line: int, text: str) -> Decimal:
        try:
            value = Decimal(text)
        except InvalidOperation:
            value = Decimal("nan")
        if not value.is_finite():
            raise FormatError(self.path, line, "timestamp", f"expected a number, got {text!r}")
        return value

    def _declared_unit(self) -> int | None:
        units = _units(self.sidecar, "timestamp")
        if units is None:
            return None
        if units not in UNITS_NS:
            raise self.sidecar.error(
                "timestamp.Units",
                f"{units!r}; supported: {', '.join(UNITS_NS)}",
            )
        return UNITS_NS[units]

    def _unit_of(self, texts: list[tuple[int, Decimal]]) -> int:
        """ns per unit of the timestamp column: its sidecar Units, else inferred."""
        declared = self._declared_unit()
        if declared is not None:
            return declared
        raw = [v for _, v in texts]
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

    def samples(self, flip_height: int | None) -> Iterator[tuple[int, EyeSample]]:
        """(t_ns, position) per row, streaming; a lost position is NaN. `scan()` first."""
        columns = self.columns
        ix, iy = columns.index("x_coordinate"), columns.index("y_coordinate")
        ip = columns.index("pupil_size") if self.pupil_unit else None
        in_mm = self.pupil_unit == "mm"
        times = self.times
        nan = math.nan
        path = self.path
        for i, (line, row) in enumerate(_lines(path, len(columns), columns)):
            t = times[i]
            try:
                x, y = float(row[ix]), float(row[iy])
            except ValueError:
                x = _number(path, line, row[ix], "x_coordinate")
                y = _number(path, line, row[iy], "y_coordinate")
                x = nan if x is None else x
                y = nan if y is None else y
            pupil = _number(path, line, row[ip], "pupil_size") if ip is not None else None
            mm, au = (pupil, None) if in_mm else (None, pupil)
            if not (math.isfinite(x) and math.isfinite(y)):
                yield t, EyeSample(nan, nan, mm, au)
                continue
            if flip_height is not None:
                y = flip_height - y
            yield t, EyeSample(x, y, mm, au)
