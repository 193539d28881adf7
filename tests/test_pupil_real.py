"""The Pupil Player importer on a real export (tests/data/formats/pupil_real, README there): every
row imported value by value, the file's own line ends (CR CR LF) read as a spreadsheet's LF
would be, the recording replayed through `gazehdr daemon` into a real server whose detector
finds the fixations, and exported to BIDS and back unchanged.

The expected values are read from the file by the rule Pupil's documentation gives (pupil-docs,
`src/core/terminology.md`: seconds of Pupil Time; normalised positions with the origin at the
bottom left), with `decimal` for the times (some have 17 digits, finer than a nanosecond: to the
nearest), so that a reader rounding a timestamp through a float, or cutting it, is noticed.
"""

from __future__ import annotations

import asyncio
import csv
import math
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path

import pytest
from test_bids_dataset import records, validate

from gazehdr.cli import main as gazehdr_main
from gazehdr.drivers.daemon import run_daemon
from gazehdr.drivers.fixations import detect
from gazehdr.drivers.formats import import_recording
from gazehdr.drivers.formats.pupil import MIN_CONFIDENCE
from gazehdr.drivers.replay import ReplaySource
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sessionlog import read_session_log

EXPORT = Path(__file__).parent / "data" / "formats" / "pupil_real" / "gaze2svg_gaze_positions.csv"
SCREEN = ScreenGeometry(0.6, 1920, 1080)  # the importer's default: the file has no screen


def expected_rows() -> list[tuple[int, float | None, float | None, bool]]:
    """(t_ns, x px, y px, valid) per row, straight from the file's text."""
    with EXPORT.open(newline=None, encoding="utf-8") as f:  # universal newlines: CR CR LF → 2 rows
        rows = [row for row in csv.reader(f) if row]
    header, body = rows[0], rows[1:]
    col = {name: header.index(name) for name in ("timestamp", "confidence", "norm_pos_x")}
    out = []
    for row in body:
        seconds = Decimal(row[col["timestamp"]])  # 17 digits: to the nearest ns
        t_ns = int((seconds * 10**9).to_integral_value(ROUND_HALF_EVEN))
        nx, ny = float(row[col["norm_pos_x"]]), float(row[col["norm_pos_x"] + 1])
        valid = float(row[col["confidence"]]) >= MIN_CONFIDENCE
        x = nx * SCREEN.screen_width_px if valid else None
        y = (1.0 - ny) * SCREEN.screen_height_px if valid else None
        out.append((t_ns, x, y, valid))
    return out


def imported_rows(path: Path) -> list[tuple[int, float | None, float | None, bool]]:
    log = import_recording(path)
    return [
        (s.t_ns, None if math.isnan(s.x) else s.x, None if math.isnan(s.y) else s.y, s.valid)
        for s in log.samples
    ]


def test_a_real_pupil_player_export_imports_row_by_row() -> None:
    """Every one of the 1,324 rows is one sample with its exact time, its position flipped to
    pixels from the top left, and valid exactly where its confidence reaches 0.6 (191 rows);
    no event or note is invented from the blank line a CR CR LF leaves after each row.
    Guards: the blank lines refused or read as rows, the old `timestamp` column not found,
    a time rounded through a float."""
    raw = EXPORT.read_bytes()
    assert raw.count(b"\r\r\n") == raw.count(b"\n") == 1325  # the fixture kept its line ends
    expected = expected_rows()
    assert len(expected) == 1324 and sum(valid for *_, valid in expected) == 191
    assert imported_rows(EXPORT) == expected
    log = import_recording(EXPORT)
    assert log.events == [] and log.notes == []
    assert log.header.screen == SCREEN


def test_its_line_ends_do_not_change_what_is_read(tmp_path: Path) -> None:
    """The same export saved with LF line ends imports to the same samples."""
    plain = tmp_path / "gaze_positions.csv"
    plain.write_bytes(EXPORT.read_bytes().replace(b"\r\r\n", b"\n"))
    assert imported_rows(plain) == imported_rows(EXPORT)


@pytest.mark.slow  # a server, a daemon and the BIDS validator
def test_a_real_pupil_export_replays_through_the_daemon_and_round_trips_through_bids(
    live_server, tmp_path: Path
) -> None:
    """`gazehdr daemon --source replay:gaze_positions.csv` into a real server: the file has no
    fixations of its own, so the daemon's detector finds them (three here) and every one is
    delivered; `gazehdr import` → `gazehdr export` (which the BIDS validator accepts) →
    `gazehdr import` gives the same records back."""
    server = live_server(token="t")
    source = ReplaySource(EXPORT, speed=math.inf)
    log = import_recording(EXPORT)
    detected = detect(log.samples, "ivt", log.header.screen)
    assert sum(e.kind == "fixation_end" for e in detected) == 3
    stats = asyncio.run(
        asyncio.wait_for(run_daemon(source, server.ws_url, "t", record=tmp_path / "sent.jsonl"), 60)
    )
    assert stats.events_delivered == len(detected) and stats.events_unsendable == 0
    assert read_session_log(tmp_path / "sent.jsonl").samples == log.samples

    first, again, root = tmp_path / "first.jsonl", tmp_path / "again.jsonl", tmp_path / "bids"
    assert gazehdr_main(["import", str(EXPORT), "--out", str(first)]) == 0
    assert gazehdr_main(["export", str(first), "--out", str(root), "--sub", "01"]) == 0
    assert gazehdr_main(["import", str(root), "--out", str(again)]) == 0
    assert records(read_session_log(again)) == records(read_session_log(first))
    validate(root)


@pytest.mark.parametrize("confidence", [0.0, 0.9])
def test_the_confidence_threshold_is_the_users(tmp_path: Path, confidence: float) -> None:
    """`--min-confidence` moves the line between valid and invalid rows of the real file."""
    out = tmp_path / "log.jsonl"
    argv = ["import", str(EXPORT), "--out", str(out), "--min-confidence", str(confidence)]
    assert gazehdr_main(argv) == 0
    with EXPORT.open(newline=None, encoding="utf-8") as f:
        rows = [row for row in csv.reader(f) if row][1:]
    valid = [s.valid for s in read_session_log(out).samples]
    assert valid == [float(row[2]) >= confidence for row in rows]
