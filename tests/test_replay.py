"""Sources and replay: one interface, deterministic replays that emit what the live source did."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest

from gazehdr.drivers import registry, sources
from gazehdr.drivers.fixations import make_detector
from gazehdr.drivers.formats import import_recording
from gazehdr.drivers.registry import SourceUnavailableError, open_source
from gazehdr.drivers.replay import ReplaySource, is_session_log, parse_speed, replay
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    GazeEvent,
    Note,
    SessionHeader,
    SessionLogWriter,
    encode_record,
    read_session_log,
)
from gazehdr.drivers.sources import Pacer, Source, SyntheticSource

DATA = Path(__file__).parent / "data" / "formats"


class FakeClock:
    """A monotonic clock that only moves when someone sleeps."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self.now_ns = start_ns
        self.slept: list[float] = []

    def __call__(self) -> int:
        return self.now_ns

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now_ns += round(seconds * 1e9)


def _live_records(source, detector: str = "ivt") -> list:
    """What a live pipeline emits: each sample, then the events the detector gives for it."""
    det = make_detector(detector, source.info.geometry)
    out: list = []
    for sample in source:
        out.append(sample)
        out.extend(det.feed(sample))
    out.extend(det.flush())
    return out


def _record(path: Path, source, records: list) -> Path:
    header = SessionHeader(tracker=source.info.header_tracker(), screen=source.info.geometry)
    with SessionLogWriter(path, header) as writer:
        writer.write_all(records)
    return path


def _keys(records: list) -> list[dict]:
    return [encode_record(r) for r in records]


def test_synthetic_source_is_a_source_with_ground_truth() -> None:
    clock = FakeClock()
    src = SyntheticSource(3, 200.0, duration=2.0, realtime=False, clock=clock)
    assert isinstance(src, Source)
    assert src.info.rate_hz == 200.0 and src.info.live and not src.info.has_events
    samples = list(src)
    assert len(samples) == 401
    assert samples[0].t_ns == clock.now_ns  # stamped on the (monotonic) clock it was given
    assert all(b.t_ns - a.t_ns == 5_000_000 for a, b in itertools.pairwise(samples))
    assert clock.slept == []  # as fast as possible
    assert src.paths[0].fixations  # ground truth
    # the same seed gives the same samples, shifted to the start time
    again = list(SyntheticSource(3, 200.0, duration=2.0, realtime=False, start_ns=0))
    assert [(s.t_ns + samples[0].t_ns, s.x, s.valid) for s in again] == [
        (s.t_ns, s.x, s.valid) for s in samples
    ]


def test_synthetic_source_paces_in_real_time_with_an_injected_clock() -> None:
    clock = FakeClock()
    src = SyntheticSource(0, 100.0, duration=1.0, clock=clock, sleep=clock.sleep)
    start = clock.now_ns
    samples = list(src)
    assert len(samples) == 101
    assert sum(clock.slept) == pytest.approx(1.0, abs=1e-6)
    assert clock.now_ns - start == samples[-1].t_ns - samples[0].t_ns


def test_endless_synthetic_source_chains_seeded_chunks(monkeypatch) -> None:
    monkeypatch.setattr(sources, "SYNTHETIC_CHUNK_S", 1.0)
    src = SyntheticSource(5, 100.0, realtime=False, start_ns=0)
    it = iter(src)
    samples = [next(it) for _ in range(350)]
    assert [s.t_ns for s in samples] == [i * 10_000_000 for i in range(350)]
    assert [p.seed for p in src.paths] == [5, 6, 7, 8]


def test_pacer_maps_record_time_to_wall_time_at_a_speed() -> None:
    clock = FakeClock()
    pacer = Pacer(2.0, clock=clock, sleep=clock.sleep)
    for t in (10_000_000_000, 11_000_000_000, 10_500_000_000, 13_000_000_000):
        pacer.wait(t)
    assert clock.slept == pytest.approx([0.5, 1.0])  # a time that goes back never waits
    with pytest.raises(ValueError):
        Pacer(0.0)


def test_replay_of_a_recorded_synthetic_run_emits_exactly_what_was_live(tmp_path: Path) -> None:
    src = SyntheticSource(1, 250.0, duration=6.0, realtime=False, start_ns=123)
    live = _live_records(src)
    assert any(isinstance(r, GazeSample) for r in live)
    kinds = {r.kind for r in live if not isinstance(r, GazeSample)}
    assert {"fixation_start", "fixation_end", "blink_start", "blink_end"} <= kinds
    path = _record(tmp_path / "run.jsonl", src, live)
    assert is_session_log(path)

    rep = ReplaySource(path, speed=math.inf)
    assert rep.info.has_events and not rep.info.live
    assert rep.info.geometry == src.info.geometry
    first, second = list(rep.records()), list(rep.records())
    assert _keys(first) == _keys(second)  # deterministic
    assert _keys(first) == _keys(live)  # same samples, same events, same order
    assert list(rep) == [r for r in live if isinstance(r, GazeSample)]  # samples equal exactly
    assert all(isinstance(r, GazeEvent) for r in first if not isinstance(r, GazeSample))


def test_replay_paces_at_recorded_speed_times_k(tmp_path: Path) -> None:
    src = SyntheticSource(2, 50.0, duration=2.0, realtime=False, start_ns=0)
    path = _record(tmp_path / "r.jsonl", src, list(src))
    for speed, expected in ((1.0, 2.0), (4.0, 0.5)):
        clock = FakeClock()
        out = list(ReplaySource(path, speed=speed, clock=clock, sleep=clock.sleep))
        assert len(out) == 101
        assert sum(clock.slept) == pytest.approx(expected, abs=1e-6)
    clock = FakeClock()
    assert len(replay(path, math.inf, clock=clock, sleep=clock.sleep)) == 101
    assert clock.slept == []


def test_replay_of_a_cut_log_stops_at_the_last_whole_line(tmp_path: Path) -> None:
    src = SyntheticSource(2, 100.0, duration=1.0, realtime=False, start_ns=0)
    path = _record(tmp_path / "cut.jsonl", src, list(src))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 7])
    rep = ReplaySource(path, speed=math.inf)
    out = list(rep)
    assert len(out) == 100 and rep.truncated


def test_replay_of_an_imported_recording_equals_its_import(tmp_path: Path) -> None:
    fixture = DATA / "eyelink_mono.asc"
    imported = import_recording(fixture)
    rep = ReplaySource(fixture, speed=math.inf)
    assert rep.info.geometry == imported.header.screen
    out = list(rep.records())
    expected = [r for r in imported.records() if isinstance(r, (GazeSample, GazeEvent))]
    assert _keys(out) == _keys(expected)
    assert _keys(list(rep.records())) == _keys(out)
    # and replaying the imported log written natively gives the same stream
    from gazehdr.drivers.sessionlog import write_session_log

    native = write_session_log(tmp_path / "imported.jsonl", imported)
    assert _keys(replay(native)) == _keys(out)


def test_open_source_specs(tmp_path: Path) -> None:
    src = open_source("synthetic:7", rate_hz=60.0, realtime=False)
    assert isinstance(src, SyntheticSource) and src.seed == 7 and src.rate_hz == 60.0
    assert open_source("synthetic").seed == 0
    s = SyntheticSource(0, 50.0, duration=1.0, realtime=False, start_ns=0)
    path = _record(tmp_path / "a@b.jsonl", s, list(s))
    assert open_source(f"replay:{path}").speed == 1.0  # an @ in the name stays in it
    assert open_source(f"replay:{path}@max").speed == math.inf
    assert open_source(f"replay:{path}@2.5").speed == 2.5
    assert open_source(f"replay:{path}@x3").speed == 3.0
    assert parse_speed("0.5") == 0.5
    with pytest.raises(ValueError, match="speed"):
        parse_speed("-1")
    with pytest.raises(ValueError, match="integer seed"):
        open_source("synthetic:abc")
    with pytest.raises(ValueError, match="known: synthetic"):
        open_source("mouse")
    with pytest.raises(FileNotFoundError):
        open_source(f"replay:{tmp_path / 'missing.jsonl'}")
    with pytest.raises(ValueError, match="replay needs a file"):
        open_source("replay:")


def test_a_replay_knows_where_each_fixation_is(tmp_path: Path) -> None:
    """EyeLink's SFIX has no position: the replay places each fixation where its EFIX says it
    was, from its start, as `SessionLog.fixation_track` does; the same for the log `gazehdr
    import` writes, read from its fixation lines alone, and up to where a cut log ends."""
    from gazehdr.drivers.sessionlog import FixationPlace, write_session_log

    fixture = DATA / "eyelink_mono.asc"
    ms = 1_000_000
    expected = {
        (1, "left"): FixationPlace(2_154_556 * ms, 640.6, 512.1),
        (2, "left"): FixationPlace(2_154_566 * ms, 830.5, 395.8),
        (3, "left"): FixationPlace(2_154_576 * ms, 831.4, 396.4),
    }
    assert ReplaySource(fixture).fixation_places() == expected
    native = write_session_log(tmp_path / "s01.jsonl", import_recording(fixture))
    assert ReplaySource(native).fixation_places() == expected
    lines = native.read_bytes().splitlines(keepends=True)
    last_end = max(i for i, line in enumerate(lines) if b'"fixation_end"' in line)
    cut = tmp_path / "cut.jsonl"
    cut.write_bytes(b"".join(lines[:last_end]) + lines[last_end][:20])  # the last EFIX cut
    assert ReplaySource(cut).fixation_places() == {
        k: v for k, v in expected.items() if k != (3, "left")
    }
    no_events = _record(tmp_path / "plain.jsonl", SyntheticSource(1, 50.0, duration=1.0), [])
    assert ReplaySource(no_events).fixation_places() == {}
    assert sources.fixation_places_of(SyntheticSource(1)) is None  # a live source: it cannot


def test_hid_source_without_a_tracker_is_a_clear_error() -> None:
    class NoDevices:  # the hidapi module interface, with nothing plugged in
        def enumerate(self, *args):
            return []

    with pytest.raises(SourceUnavailableError, match="HID source unavailable"):
        open_source("hid", backend=NoDevices())


def test_hid_source_is_opened_lazily_with_a_clear_error(monkeypatch) -> None:
    import sys

    hid = next(k for k in registry.KINDS if k.name == "hid")
    assert hid.stream is not None
    monkeypatch.setitem(sys.modules, hid.stream.module, None)  # as if it could not be imported
    with pytest.raises(SourceUnavailableError, match="HID source unavailable"):
        open_source("hid")


def test_imported_geometry_passes_through(tmp_path: Path) -> None:
    geometry = ScreenGeometry(0.5, 1280, 1024, 0.7)
    rep = open_source(f"replay:{DATA / 'gaze_positions.csv'}", geometry=geometry)
    assert rep.info.geometry.screen_width_px == 1280
    log = read_session_log(_record(tmp_path / "g.jsonl", rep, list(rep.records())))
    assert log.header.screen.screen_width_px == 1280


# --- recordings gazehdr imported: BIDS runs, fixations without a place, a long tail ------------


def _two_runs(tmp_path: Path) -> Path:
    """A dataset of two runs of one subject, exported from the fixture's imported log and a copy
    of it one hour later."""
    from gazehdr.drivers.formats.bids import read_bids, write_bids

    log = read_bids(DATA / "bids")
    root = tmp_path / "ds"
    write_bids(log, root, sub="01", task="free", run="1")
    hour = 3600 * 10**9
    log.samples = [
        GazeSample(s.t_ns + hour, s.x, s.y, s.valid, s.left, s.right) for s in log.samples
    ]
    log.events, log.notes = [], []
    write_bids(log, root, sub="01", task="free", run="2")
    return root


def test_a_bids_dataset_replays_with_its_run_picked(tmp_path: Path) -> None:
    """`replay:DATASET#run-2` streams run 2 of a dataset (`#sub-01_run-2`, as the files name
    it); without the run, the error lists them; a folder of the dataset works as a file does.
    Guards: a BIDS folder refused as "no such recording"; no way to pick the run."""
    root = _two_runs(tmp_path)
    with pytest.raises(ValueError, match="2 eye-tracking runs; pick one with --run"):
        open_source(f"replay:{root}@max")
    run2 = [r for r in open_source(f"replay:{root}#run-2@max").records()]
    run1 = [r for r in open_source(f"replay:{root / 'sub-01'}#sub-01_run-1@max").records()]
    assert [s.t_ns for s in run2 if isinstance(s, GazeSample)] == [
        s.t_ns + 3600 * 10**9 for s in run1 if isinstance(s, GazeSample)
    ]
    with pytest.raises(ValueError, match="expected entities such as"):
        open_source(f"replay:{root}#take-2@max")


def test_fixations_without_a_place_are_placed_at_their_samples_mean(tmp_path: Path) -> None:
    """The fixture's physioevents fixations have no position (eye2bids writes none, nor does
    EEGEyeNet's 10 Hz dataset), and its samples are too few for I-VT: a replay places each at
    the mean of its eye's valid samples inside it, so the daemon sends the recording's fixations
    instead of none (where I-VT finds fixations the daemon's detector runs, as before:
    tests/test_daemon.py). A render (`fixation_track`) follows the same places. Guards: a
    replay whose fixations have no position sending no fixation at all; a render following
    the raw samples where the replay sends fixations."""
    source = ReplaySource(DATA / "bids", speed=math.inf)
    places = source.fixation_places()
    log = import_recording(DATA / "bids")
    starts = [e for e in log.events if e.kind == "fixation_start"]
    assert {(e.id, e.eye) for e in starts} == set(places)
    first = places[(1, "left")]
    ends = {(e.id, e.eye): e.t_ns for e in log.events if e.kind == "fixation_end"}
    inside = [
        s.left
        for s in log.samples
        if first.start_ns <= s.t_ns <= ends[(1, "left")] and math.isfinite(s.left.x)
    ]
    assert (first.x, first.y) == pytest.approx(
        (sum(e.x for e in inside) / len(inside), sum(e.y for e in inside) / len(inside))
    )
    assert source.unplaced == 0
    detector = make_detector("ivt", source.info.geometry)
    sent = [r for r in sources.records_of(source) if getattr(r, "kind", "").startswith("fix")]
    assert sent and detector is not None
    # A render (`fixation_track`) holds the same places as the replay sends: the first eye's.
    track = log.fixation_track()
    w, h = log.header.screen.screen_width_px, log.header.screen.screen_height_px
    left = sorted(p for (_, eye), p in places.items() if eye == "left")
    assert len(left) > 1
    for place in left:
        point = track.at((place.start_ns - track.t0_ns) / 1e9)
        assert (point.x, point.y) == pytest.approx((place.x / w, place.y / h))


def test_an_imported_recording_ends_at_its_last_sample(tmp_path: Path) -> None:
    """Records more than a second after an imported recording's last valid sample (an END or
    messages 52 minutes later) are not replayed: an invalid sample just after the last one ends
    the gaze. Guards: a replay holding the last gaze through the gap."""
    log = import_recording(DATA / "eyelink_mono.asc")
    late = log.samples[-1].t_ns + 52 * 60 * 10**9
    log.samples.append(GazeSample(late, math.nan, math.nan, False))
    log.notes.append(Note(late, "the end, 52 minutes on"))
    out = replay(log, include_all=True)
    last_valid = max(s.t_ns for s in log.samples if s.valid)
    assert max(r.t_ns for r in out) <= last_valid + 10**9
    assert isinstance(out[-1], GazeSample) and not out[-1].valid


def test_serve_gaze_replay_takes_a_bids_dataset_and_drives_the_gaze(tmp_path: Path) -> None:
    """`gazehdr serve --gaze replay:PATH#RUN`: the run is imported into the server's recordings
    and new sessions follow it (`replay:NAME`); the track it gives is the recording's gaze.
    Importing the same run again makes no copy; another recording of the same name is kept
    beside, never over, the first. Guards: `serve --gaze replay:PATH` refused, a recording of
    the server's overwritten by a namesake."""
    from gazehdr.recordings import RecordingLibrary
    from gazehdr.serve import build_config

    root = _two_runs(tmp_path)
    options = dict(
        host="127.0.0.1", port=0, scene="flash", scale=None, fps=30.0, size=(96, 54),
        fit_viewport=False, params_file=None, token="t", data_dir=tmp_path / "data",
        allow_origins=(), encoding="rgb10a2", backend="reference", seed=0,
    )  # fmt: skip
    config = build_config(**options, gaze=f"replay:{root}#run-1")
    assert config.session.gaze_source == "replay:run-1"
    track, _ = RecordingLibrary(tmp_path / "data").replay("run-1")
    log = import_recording(root, select={"run": "1"})
    w, h = log.header.screen.screen_width_px, log.header.screen.screen_height_px
    expected = log.fixation_track().at(0.0)
    assert (track.at(0.0).x, track.at(0.0).y) == pytest.approx((expected.x, expected.y))
    assert 0 < track.at(0.0).x * w < w and 0 < track.at(0.0).y * h < h
    again = build_config(**options, gaze="replay:run-1")  # the server's recording by its name
    assert again.session.gaze_source == "replay:run-1"
    kept = (tmp_path / "data" / "recordings" / "run-1.jsonl").read_bytes()
    restarted = build_config(**options, gaze=f"replay:{root}#run-1")  # the same run: no copy
    assert restarted.session.gaze_source == "replay:run-1"
    other = build_config(**options, gaze=f"replay:{root}#run-2")
    assert other.session.gaze_source == "replay:run-2"
    # Another recording named run-1 (a second dataset's) takes run-1-2; the first is kept.
    second = tmp_path / "second"
    second.mkdir()
    (tmp_path / "data" / "recordings" / "run-2.jsonl").rename(second / "run-1.jsonl")
    moved = build_config(**options, gaze=f"replay:{second / 'run-1.jsonl'}")
    assert moved.session.gaze_source == "replay:run-1-2"
    assert (tmp_path / "data" / "recordings" / "run-1.jsonl").read_bytes() == kept
    assert sorted(p.name for p in (tmp_path / "data" / "recordings").iterdir()) == [
        "run-1-2.jsonl",
        "run-1.jsonl",
    ]
    with pytest.raises(ValueError, match="no such recording"):
        build_config(**options, gaze=f"replay:{tmp_path / 'nothing'}")
