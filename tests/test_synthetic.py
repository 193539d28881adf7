"""Scripted gaze: the synthetic scan path's kinematics and ground truth, fixed and CSV tracks."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from gazehdr.drivers.registry import open_track
from gazehdr.drivers.samples import GazePoint, GazeSample, GazeTrack, ScreenGeometry
from gazehdr.drivers.synthetic import FixationView, FixedGaze, SyntheticScanPath, peak_velocity
from gazehdr.drivers.tracks import CsvGazeTrack

RATE_HZ = 2000.0  # dense enough that finite differences resolve a 25 ms saccade's peak


def _positions_deg(path: SyntheticScanPath, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (s) and gaze in degrees from the path's own tracker-style samples."""
    samples = list(path.samples(rate_hz))
    t = np.array([s.t_ns for s in samples]) * 1e-9
    xy = np.array([(s.x, s.y) for s in samples]) / path.geometry.pixels_per_degree
    return t, xy


def test_geometry_defaults_match_the_server_geometry() -> None:
    from gazehdr.sim import Geometry

    assert ScreenGeometry().pixels_per_degree == pytest.approx(Geometry().pixels_per_degree())
    assert ScreenGeometry().pixels_per_degree == pytest.approx(64.08, abs=0.01)
    g = ScreenGeometry()
    assert g.norm_to_deg(*g.deg_to_norm(3.0, -2.0)) == pytest.approx((3.0, -2.0))


def test_same_seed_same_path_other_seed_other_path() -> None:
    a, b, c = (
        SyntheticScanPath(seed=7, duration=20),
        SyntheticScanPath(7, 20),
        SyntheticScanPath(8, 20),
    )
    times = np.linspace(0, 20, 997)
    assert a.fixations == b.fixations and a.blinks == b.blinks
    assert [a.at(t) for t in times] == [b.at(t) for t in times]
    assert a.fixations != c.fixations
    assert list(a.samples(100)) == list(b.samples(100))
    noisy = [SyntheticScanPath(7, 20, noise_deg=0.1) for _ in range(2)]
    assert list(noisy[0].samples(100)) == list(noisy[1].samples(100))
    assert list(noisy[0].samples(100)) != list(a.samples(100))
    assert noisy[0].fixations == a.fixations and noisy[0].blinks == a.blinks  # noise: no replan


def _targets(path: SyntheticScanPath) -> list[tuple[float, float]]:
    """The fixation targets in order, the two pieces of a blink-split fixation counted once."""
    return [xy for xy, _ in itertools.groupby((f.x, f.y) for f in path.fixations)]


def test_blinks_split_fixations_without_changing_the_targets() -> None:
    with_blinks = SyntheticScanPath(seed=3, duration=30)
    without = SyntheticScanPath(seed=3, duration=30, blinks=False)
    assert with_blinks.blinks and not without.blinks
    assert len(with_blinks.fixations) == len(_targets(with_blinks)) + len(with_blinks.blinks)
    n = len(_targets(with_blinks))
    assert _targets(with_blinks) == _targets(without)[:n]


def test_fixations_cover_the_duration_inside_the_screen() -> None:
    path = SyntheticScanPath(seed=1, duration=30, margin=0.1)
    fixations = path.fixations
    assert fixations[0].start == 0 and fixations[-1].end >= 30
    for f in fixations:
        assert 0.1 <= f.x <= 0.9 and 0.1 <= f.y <= 0.9
        assert 0.2 - 1e-9 <= f.end - f.start <= 0.6 + 1e-9
    for prev, nxt in itertools.pairwise(fixations):
        assert nxt.start > prev.end  # a saccade between them
    durations = np.array([f.end - f.start for f in fixations])
    assert 0.25 < np.median(durations) < 0.45  # log-normal around ~350 ms, not piled at a bound
    points = [path.at(t) for t in np.linspace(0, 30, 3001)]
    assert all(0 <= p.x <= 1 and 0 <= p.y <= 1 for p in points)


def test_fixational_drift_is_small_and_slow() -> None:
    path = SyntheticScanPath(seed=2, duration=20, blinks=False, jitter_deg=0)
    t, xy = _positions_deg(path, RATE_HZ)
    speed = np.hypot(*np.gradient(xy, t, axis=0).T)
    for f in path.fixations:
        inside = (t > f.start + 1e-3) & (t < f.end - 1e-3)
        cx, cy = np.array(path.geometry.norm_to_deg(f.x, f.y))
        offset = np.hypot(xy[inside, 0] - cx, xy[inside, 1] - cy)
        assert offset.max() <= 2 * 0.07 + 1e-9  # at most drift_deg per axis
        assert speed[inside].max() < 5.0  # far below any saccade detector threshold (30 °/s)
    assert max(np.ptp(xy[(t > f.start) & (t < f.end)], axis=0).max() for f in path.fixations) > 0.02


def test_tremor_is_band_limited_jitter_of_the_stated_size() -> None:
    """The same seed with and without tremor: the difference is the tremor alone."""
    still = SyntheticScanPath(seed=6, duration=20, jitter_deg=0)
    _, xy0 = _positions_deg(still, RATE_HZ)
    seen = np.isfinite(xy0[:, 0])
    for rms in (0.05, 0.008):
        _, xy = _positions_deg(SyntheticScanPath(seed=6, duration=20, jitter_deg=rms), RATE_HZ)
        tremor = (xy - xy0)[seen]
        assert np.sqrt(np.mean(tremor**2, axis=0)) == pytest.approx([rms, rms], rel=0.05)
        assert np.abs(tremor.mean(axis=0)).max() < 0.05 * rms
    tremor = (xy - xy0)[: np.argmin(seen)]  # up to the first blink: evenly sampled
    power = np.abs(np.fft.rfft(tremor, axis=0)) ** 2
    hz = np.fft.rfftfreq(len(tremor), 1 / RATE_HZ)
    band = (hz >= 39) & (hz <= 101)
    assert power[band].sum() > 0.98 * power.sum()  # 40-100 Hz, as physiological tremor
    window = round(0.020 * RATE_HZ)  # I-VT's 20 ms velocity window sees a few °/s at most
    assert np.hypot(*(tremor[window:] - tremor[:-window]).T).max() / 0.020 < 5.0


def test_tracker_noise_is_white_and_of_the_stated_size() -> None:
    clean = list(SyntheticScanPath(seed=8, duration=20).samples(500))
    noisy = list(SyntheticScanPath(seed=8, duration=20, noise_deg=0.1).samples(500))
    assert [s.valid for s in noisy] == [s.valid for s in clean]
    assert [s.t_ns for s in noisy] == [s.t_ns for s in clean]
    ppd = ScreenGeometry().pixels_per_degree
    error = (
        np.array([(n.x - c.x, n.y - c.y) for n, c in zip(noisy, clean, strict=True) if c.valid])
        / ppd
    )
    assert np.std(error, axis=0) == pytest.approx([0.1, 0.1], rel=0.05)
    assert np.abs(error.mean(axis=0)).max() < 0.005
    lag1 = [np.corrcoef(error[1:, k], error[:-1, k])[0, 1] for k in (0, 1)]
    assert np.abs(lag1).max() < 0.05  # independent from sample to sample


def test_saccades_follow_the_main_sequence() -> None:
    path = SyntheticScanPath(seed=4, duration=20, jitter_deg=0)
    t, xy = _positions_deg(path, RATE_HZ)
    speed = np.hypot(*np.gradient(xy, t, axis=0).T)
    geometry = path.geometry
    checked = 0
    for s in path.saccades:
        prev = next(f for f in path.fixations if f.end == s.start)
        nxt = next(f for f in path.fixations if f.start == s.end)
        assert (s.x0, s.y0) == path.at(prev.end)[:2] and (s.x1, s.y1) == (nxt.x, nxt.y)
        during = (t >= s.start) & (t <= s.end)
        start = np.array(geometry.norm_to_deg(s.x0, s.y0))
        end = np.array(geometry.norm_to_deg(s.x1, s.y1))
        amplitude = float(np.hypot(*(end - start)))
        assert amplitude == pytest.approx(s.amplitude_deg)
        measured = speed[during].max()
        # Sampling at 0.5 ms misses the true peak of a >= 25 ms minimum-jerk profile by < 0.5 %.
        assert measured == pytest.approx(600 * (1 - math.exp(-amplitude / 7.25)), rel=0.01)
        assert measured == pytest.approx(path.peak_velocity(amplitude), rel=0.01)
        if amplitude <= 20:
            assert s.end - s.start == pytest.approx(0.0022 * amplitude + 0.021, rel=0.04)
        checked += 1
    assert checked > 30 and path.blinks  # blinks never stand in for a saccade
    assert peak_velocity(10.0, 500.0, 15.0) == pytest.approx(500 * (1 - math.exp(-10 / 15)))


def test_blinks_split_a_fixation_and_invalidate_samples() -> None:
    path = SyntheticScanPath(seed=5, duration=40)
    assert len(path.blinks) >= 4
    previous_end = 0.0
    # Due 4-8 s after the last blink, it waits for the end of the fixation piece in progress
    # (at most 0.6 s) and the saccade before it (under 0.1 s on this screen).
    for b in path.blinks:
        assert 4.0 <= b.start - previous_end <= 8.0 + 0.6 + 0.1
        assert 0.1 <= b.end - b.start <= 0.3 and b.end < path.duration
        before = next(f for f in path.fixations if f.end == b.start)
        after = next(f for f in path.fixations if f.start == b.end)
        assert (before.x, before.y) == (after.x, after.y)  # one fixation, split by the blink
        assert 0.2 - 1e-9 <= after.end - after.start <= 0.6 + 1e-9
        assert path.at(b.start).eyes_open is False
        assert path.at((b.start + b.end) / 2).eyes_open is False
        assert path.at(b.start - 1e-3).eyes_open is True
        assert path.at(b.end).eyes_open is True
        previous_end = b.end
    rate = 500.0
    samples = list(path.samples(rate))
    invalid = [s for s in samples if not s.valid]
    assert all(math.isnan(s.x) and math.isnan(s.y) for s in invalid)
    closed = sum(b.end - b.start for b in path.blinks)
    assert len(invalid) == pytest.approx(closed * rate, abs=len(path.blinks))
    assert samples[-1].t_ns == 40 * 10**9


def test_tracks_satisfy_the_protocol() -> None:
    assert isinstance(SyntheticScanPath(duration=1), GazeTrack)
    assert isinstance(FixedGaze(), GazeTrack)
    assert isinstance(CsvGazeTrack([0.0], [GazePoint(0.5, 0.5, True)]), GazeTrack)
    assert FixedGaze(0.2, 0.7).at(123.0) == GazePoint(0.2, 0.7, True)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": -1}, "seed"),
        ({"duration": 0}, "duration"),
        ({"duration": math.inf}, "duration"),
        ({"margin": 0.5}, "margin"),
        ({"fixation_s": (0.6, 0.2)}, "fixation_s"),
        ({"min_amplitude_deg": 30.0}, "min_amplitude_deg"),
        ({"c_deg": 0.0}, "c_deg"),
        ({"jitter_deg": -0.01}, "jitter_deg"),
        ({"noise_deg": math.nan}, "noise_deg"),
    ],
)
def test_scan_path_rejects_bad_settings(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SyntheticScanPath(**kwargs)


def test_bad_points_are_rejected() -> None:
    with pytest.raises(ValueError, match="normalised"):
        FixedGaze(1.2, 0.5)
    with pytest.raises(ValueError, match="finite"):
        GazeSample(0, math.nan, 1.0)
    assert not GazeSample(0, math.nan, math.nan, valid=False).valid
    with pytest.raises(ValueError, match="finite"):
        SyntheticScanPath(duration=1).at(math.nan)


def test_csv_track_holds_each_sample(tmp_path: Path) -> None:
    csv = tmp_path / "gaze.csv"
    csv.write_text(
        "# recorded by hand\nt,x,y,eyes_open\n0.0,0.1,0.2,1\n\n0.5,0.3,0.4,false\n1.0,0.9,0.8\n"
    )
    track = CsvGazeTrack.read(csv)
    assert track.at(-1.0) == GazePoint(0.1, 0.2, True)
    assert track.at(0.49) == GazePoint(0.1, 0.2, True)
    assert track.at(0.5) == GazePoint(0.3, 0.4, False)
    assert track.at(99.0) == GazePoint(0.9, 0.8, True)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no gaze samples"),
        ("0,0.5\n", ":1: expected t,x,y"),
        ("0,0.5,0.5\n1,a,0.5\n", ":2: t, x, y must be numbers"),
        ("0,0.5,0.5\n1,1.5,0.5\n", ":2: x, y must be normalised"),
        ("0,0.5,0.5\n1,nan,0.5\n", ":2: x, y must be normalised"),
        ("1,0.5,0.5\n0,0.5,0.5\n", ":2: time 0.0 goes back"),
        ("0,0.5,0.5,maybe\n", ":1: eyes_open"),
    ],
)
def test_csv_errors_name_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        CsvGazeTrack.read(csv)
    assert str(csv) in str(error.value)


def test_open_track_specs(tmp_path: Path) -> None:
    synthetic = open_track("synthetic", seed=3, duration=5)
    assert isinstance(synthetic, FixationView)  # render and viewer follow fixations alike
    assert synthetic.path.fixations == SyntheticScanPath(3, 5).fixations
    assert open_track("fixed") == FixedGaze(0.5, 0.5)
    assert open_track(" 0.25, .75 ") == FixedGaze(0.25, 0.75)
    csv = tmp_path / "g.CSV"
    csv.write_text("0,0.1,0.9\n")
    assert open_track(str(csv)).at(0.0) == GazePoint(0.1, 0.9, True)
    with pytest.raises(ValueError, match="normalised"):
        open_track("2,0.5")
    with pytest.raises(ValueError, match="not found"):
        open_track(str(tmp_path / "missing.csv"))
    with pytest.raises(ValueError, match="expected synthetic, fixed, X,Y"):
        open_track("session.edf")
