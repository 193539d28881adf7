"""Gaze tracks: the openers of the track kinds in `gazehdr.drivers.registry`, and CSV tracks.

Each opener takes a `TrackRequest`; everything that renders only sees the `GazeTrack` protocol.
A native session log (`*.jsonl`) renders as its fixations (`SessionLog.fixation_track`), exactly
what a live session replaying it follows.

CSV gaze format (`*.csv`): one sample per row, `t,x,y[,eyes_open]`.

- `t`: seconds since the start, non-decreasing; `x`, `y`: normalised screen coordinates in
  [0, 1], origin top-left; `eyes_open`: 1/0, true/false or yes/no, default 1.
- An optional header row naming the columns (`t,x,y` or `t,x,y,eyes_open`); blank lines and
  lines starting with `#` are ignored.
- Each sample holds until the next (step interpolation: no invented positions between samples);
  before the first sample the track shows the first, after the last the last.
"""

from __future__ import annotations

import bisect
import csv
import itertools
import math
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazePoint, TrackRequest
from gazehdr.drivers.sessionlog import SessionTrack, read_session_track
from gazehdr.drivers.synthetic import FixationView, FixedGaze, SyntheticScanPath

_TRUE = {"1", "true", "yes"}
_FALSE = {"0", "false", "no"}
_HEADERS = (["t", "x", "y"], ["t", "x", "y", "eyes_open"])


class CsvGazeTrack:
    """Gaze samples read from a CSV file (see the module docstring), held step-wise."""

    def __init__(self, times: list[float], points: list[GazePoint]) -> None:
        if not times or len(times) != len(points):
            raise InputError("a gaze track needs at least one sample and one point per time")
        if any(b < a for a, b in itertools.pairwise(times)):
            raise InputError("gaze sample times must be non-decreasing")
        self.times = times
        self.points = points

    @classmethod
    def read(cls, path: str | Path) -> CsvGazeTrack:
        path = Path(path)
        times: list[float] = []
        points: list[GazePoint] = []
        with path.open(newline="", encoding="utf-8") as f:
            rows = csv.reader(f)
            try:
                for row in rows:
                    where = f"{path}:{rows.line_num}"
                    fields = [field.strip() for field in row]
                    if not any(fields) or fields[0].startswith("#"):
                        continue
                    if not times and [v.lower() for v in fields] in _HEADERS:
                        continue
                    t, point = _parse_row(fields, where)
                    if times and t < times[-1]:
                        raise InputError(f"{where}: time {t} goes back from {times[-1]}")
                    times.append(t)
                    points.append(point)
            except UnicodeDecodeError:
                raise InputError(f"{path}: not a UTF-8 text CSV file") from None
        if not times:
            raise InputError(f"{path}: no gaze samples (expected rows of t,x,y[,eyes_open])")
        return cls(times, points)

    def at(self, t: float) -> GazePoint:
        return self.points[max(bisect.bisect_right(self.times, t) - 1, 0)]


def _parse_row(fields: list[str], where: str) -> tuple[float, GazePoint]:
    if len(fields) not in (3, 4):
        raise InputError(f"{where}: expected t,x,y[,eyes_open], got {len(fields)} fields")
    try:
        t, x, y = (float(v) for v in fields[:3])
    except ValueError:
        raise InputError(f"{where}: t, x, y must be numbers, got {','.join(fields[:3])}") from None
    if not math.isfinite(t):
        raise InputError(f"{where}: time must be finite, got {fields[0]}")
    if not all(math.isfinite(v) and 0 <= v <= 1 for v in (x, y)):
        raise InputError(f"{where}: x, y must be normalised coordinates in [0, 1], got {x}, {y}")
    eyes = fields[3].lower() if len(fields) == 4 else "1"
    if eyes not in _TRUE | _FALSE:
        raise InputError(f"{where}: eyes_open must be 1/0, true/false or yes/no, got {fields[3]}")
    return t, GazePoint(x, y, eyes in _TRUE)


def synthetic_track(request: TrackRequest) -> FixationView:
    """`synthetic`: the seeded scan path, followed from fixation to fixation (SPEC §4) like a
    recorded session, so that a saccade does not sweep the retina."""
    return FixationView(SyntheticScanPath(seed=request.seed, duration=request.duration))


def fixed_track(request: TrackRequest) -> FixedGaze:
    """`fixed`: the centre of the screen."""
    return FixedGaze()


def point_track(request: TrackRequest) -> FixedGaze:
    """`X,Y`: a fixed point in normalised coordinates (the registry matched two numbers)."""
    x, y = request.spec.split(",")
    return FixedGaze(float(x), float(y))


def csv_track(request: TrackRequest) -> CsvGazeTrack:
    """`FILE.csv`: the samples of a CSV gaze file (see the module docstring)."""
    return CsvGazeTrack.read(request.path)


def session_log_track(request: TrackRequest) -> SessionTrack:
    """`LOG.jsonl`: a native session log's fixations (`gazehdr.drivers.sessionlog`)."""
    return read_session_track(request.path)
