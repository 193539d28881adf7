"""The registry of gaze sources: one table, opened as streams or as tracks, and what it lists."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gazehdr.drivers import registry
from gazehdr.drivers.registry import (
    KINDS,
    STREAM,
    TRACK,
    Opening,
    SourceKind,
    SourceUnavailableError,
    choices,
    describe,
    kinds,
    open_source,
    open_track,
)
from gazehdr.drivers.samples import (
    GazePoint,
    GazeSample,
    ScreenGeometry,
    StreamRequest,
    TrackRequest,
)
from gazehdr.drivers.sources import IterableSource, SourceInfo, SyntheticSource
from gazehdr.drivers.synthetic import FixedGaze


def test_every_kind_is_named_once_and_its_code_loads() -> None:
    assert len({k.name for k in KINDS}) == len(KINDS)
    for kind in KINDS:
        openings = [o for o in (kind.stream, kind.track) if o is not None]
        assert openings, f"{kind.name} opens neither as a stream nor as a track"
        for opening in openings:
            assert callable(opening.load()), opening.code
        if kind.stream is not None:
            assert kind.stream.syntax.startswith(kind.name)  # NAME[:ARG]


def test_what_opens_how() -> None:
    assert [k.name for k in kinds(STREAM)] == ["synthetic", "replay", "hid", "pupil", "lsl"]
    assert [k.name for k in kinds(TRACK)] == ["synthetic", "fixed", "point", "csv", "replay"]
    assert kinds() == KINDS


def test_choices_and_help_come_from_the_table() -> None:
    assert choices(STREAM) == (
        "synthetic[:SEED], replay:FILE[@SPEED], hid[:PATH], pupil[:HOST[:PORT][/SURFACE]], "
        "lsl[:QUERY]"
    )
    assert choices(TRACK) == "synthetic, fixed, X,Y or a file ending in .csv, .jsonl"
    assert describe(TRACK).startswith("synthetic (seeded scan path, fixation to fixation), fixed")
    assert describe(TRACK).endswith(" or LOG.jsonl (a session log's fixations)")
    with pytest.raises(ValueError, match=r"known: synthetic\[:SEED\], replay:FILE\[@SPEED\], hid"):
        open_source("fixed")  # a kind, but not one that streams
    with pytest.raises(ValueError, match="expected synthetic, fixed, X,Y or a file ending in"):
        open_track("hid")  # a kind, but not one that is a track


def test_track_specs_by_name_pattern_then_suffix(tmp_path: Path) -> None:
    assert open_track("fixed") == FixedGaze()
    assert open_track("1e-1,+.5") == FixedGaze(0.1, 0.5)
    with pytest.raises(ValueError, match=r"gaze file .* not found"):
        open_track(str(tmp_path / "gaze.CSV"))  # suffixes in any case
    (tmp_path / "gaze.txt").write_text("t,x,y\n0,0.1,0.2\n")
    with pytest.raises(ValueError, match="expected synthetic"):
        open_track(str(tmp_path / "gaze.txt"))  # a file, but of no kind
    folder = tmp_path / "folder.csv"
    folder.mkdir()
    with pytest.raises(ValueError, match="not found"):
        open_track(str(folder))  # not a file


def test_stream_request_screen_fields() -> None:
    geometry = ScreenGeometry(0.5, 1280, 1024, 0.7)
    assert StreamRequest().screen_geometry() is None
    assert StreamRequest(geometry=geometry).screen_geometry() == geometry
    request = StreamRequest(geometry=geometry, screen={"viewing_distance_m": 0.6})
    assert request.screen_geometry() == ScreenGeometry(0.5, 1280, 1024, 0.6)
    assert StreamRequest(screen={"screen_width_px": 800}).screen_geometry() == ScreenGeometry(
        screen_width_px=800
    )


# A kind added the way `lsl` and `pupil` will be: an entry, and openers in its module (here).


def open_constant_stream(request: StreamRequest) -> IterableSource:
    x, _, y = request.arg.partition(",")
    samples = [GazeSample(i, float(x), float(y)) for i in range(int(request.options["n"]))]
    return IterableSource(samples, SourceInfo(name="constant", geometry=request.screen_geometry()))


def open_constant_track(request: TrackRequest) -> FixedGaze:
    return FixedGaze(0.25, 0.75)


def open_missing_driver(request: StreamRequest) -> IterableSource:
    import gazehdr_no_such_driver  # type: ignore[import-not-found]  # noqa: F401

    raise AssertionError("unreachable")


def test_a_new_kind_is_one_entry(monkeypatch: pytest.MonkeyPatch) -> None:
    here = __name__
    kinds_now = (
        *KINDS,
        SourceKind(
            "constant",
            stream=Opening("constant:X,Y", "a fixed point", f"{here}:open_constant_stream"),
            track=Opening("constant", "a fixed point", f"{here}:open_constant_track"),
        ),
        SourceKind(
            "lab",
            stream=Opening("lab", "a driver not installed", f"{here}:open_missing_driver"),
            title="Lab",
        ),
    )
    monkeypatch.setattr(registry, "KINDS", kinds_now)
    source = open_source("constant:3,4", n=2, screen={"screen_width_px": 640})
    assert [(s.x, s.y) for s in source] == [(3.0, 4.0), (3.0, 4.0)]
    assert source.info.geometry.screen_width_px == 640
    assert open_track("constant").at(1.0) == GazePoint(0.25, 0.75, True)
    assert choices(STREAM).endswith("pupil[:HOST[:PORT][/SURFACE]], lsl[:QUERY], constant:X,Y, lab")
    assert "constant (a fixed point)" in describe(TRACK)
    with pytest.raises(SourceUnavailableError, match="Lab source unavailable: No module named"):
        open_source("lab")


def test_the_table_is_light() -> None:
    """`gazehdr --help` lists the sources from the table: importing it loads no source's module
    (nor numpy, which the synthetic scan path brings)."""
    code = (
        "import sys, gazehdr.drivers.registry; "
        "loaded = [m for m in sys.modules if m.split('.')[0] == 'numpy' or "
        "m.startswith('gazehdr.drivers.') and m not in ("
        "'gazehdr.drivers.registry', 'gazehdr.drivers.samples', 'gazehdr.drivers.errors')]; "
        "print(loaded); sys.exit(1 if loaded else 0)"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_open_source_passes_what_applies() -> None:
    src = open_source("synthetic:2", rate_hz=50.0, realtime=False, duration=1.0, wait=True)
    assert isinstance(src, SyntheticSource)
    assert (src.seed, src.rate_hz, src.realtime, src.duration) == (2, 50.0, False, 1.0)
