"""The model observer (server/experiment/observer.py, brightness.py): it answers from the frames
shown, is given no PSE, its colour term (Nayatani's Helmholtz-Kohlrausch estimate) and temporal
summation do what the docs say, it is seeded, and a headless 4.1 and 4.2 run prints its
prediction beside the paper's numbers. Each test names the mutation it guards. Frames are tiny
(synthetic, or 48×27 on the NumPy reference backend): CI has two cores."""

from __future__ import annotations

import inspect
import math
import re
from pathlib import Path

import numpy as np
import pytest

from gazehdr.cli import main as cli_main
from gazehdr.experiment import prediction
from gazehdr.experiment.brightness import (
    Interval,
    hk_gamma,
    k_br,
    log10_brightness,
    q_nayatani,
    windowed_peak,
)
from gazehdr.experiment.design import load_design
from gazehdr.experiment.observer import ModelObserver
from gazehdr.experiment.runner import Presented, percepts, run_headless
from gazehdr.experiment.schedule import Trial
from gazehdr.experiment.stimulus import clip
from gazehdr.sim.display import PAPER_DISPLAY
from gazehdr.sim.layout import RGB_TO_XYZ
from tests.test_experiment_run import rows

SIZE = (48, 27)
BACKEND = "reference"
DT = 1 / 60


def interval(cd_m2: np.ndarray, times: np.ndarray | None = None) -> Interval:
    """Frames (N×H×W×3 cd/m² per channel) as the page gets them: float16 v for the monitor."""
    cd_m2 = np.asarray(cd_m2, dtype=float)
    t = np.arange(len(cd_m2)) * DT if times is None else times
    v = PAPER_DISPLAY.values(cd_m2).astype(np.float16)
    return Interval(v, t, float(t[-1] + DT), PAPER_DISPLAY)


def flash(peak: float, after: float = 0.0, n_after: int = 12) -> np.ndarray:
    """A 3-frame grey flash on a 6×6 patch of an 8×8 frame, then `after` cd/m² on it."""
    frames = np.zeros((3 + n_after, 8, 8, 3))
    frames[:3, 1:7, 1:7] = peak
    frames[3:, 1:7, 1:7] = after
    return frames


def trial(test_interval: int, condition: str = "control", test: float = 27.0) -> Trial:
    return Trial(1, 2, "main", condition, 27.0, test, test_interval, False)


def choose_rate(observer: ModelObserver, test: Interval, standard: Interval, n: int) -> float:
    """How often `observer` picks the test, over `n` trials with the test first in half."""
    chose = 0
    for i in range(n):
        first = 1 + i % 2
        shown = (test, standard) if first == 1 else (standard, test)
        chose += observer.answer(trial(first), lambda s=shown: [observer.perceive(x) for x in s])
    return chose / n


def test_a_brighter_test_is_chosen_more_often_and_the_same_frames_half_the_time() -> None:
    """The answers come from the frames: a test flash 8 % brighter (in the frames only: the
    trial says the same intensities), about a Weber fraction, is chosen in about 76 % of the
    trials (d' = 1), as the Weber noise predicts, the same frames in half of them, a dimmer test in
    about 24 %.
    Guards: an observer that answers from the trial's intensities or condition instead of the
    frames (all three rates would be equal), and one that compares the wrong interval (the
    rates swap)."""
    observer = ModelObserver(seed=5)
    standard = interval(flash(27.0))
    brighter, dimmer = interval(flash(27.0 * 1.08)), interval(flash(27.0 / 1.08))
    expected = observer.p_choose_test(observer.perceive(brighter), observer.perceive(standard))
    z = math.log10(1.08) / (2 * observer.sigma)  # Φ(Δ / √2σ)
    assert expected == pytest.approx(0.5 * (1 + math.erf(z)), abs=3e-3)
    up = choose_rate(observer, brighter, standard, 600)
    same = choose_rate(observer, interval(flash(27.0)), standard, 600)
    down = choose_rate(observer, dimmer, standard, 600)
    assert up == pytest.approx(expected, abs=0.06) and up > 0.68
    assert same == pytest.approx(0.5, abs=0.07)
    assert down == pytest.approx(1 - expected, abs=0.06) and down < 0.32


def test_the_model_observer_is_given_no_pse_and_ignores_what_the_trial_says() -> None:
    """Its constructor takes no PSE (nor a condition or intensity); answering the same frames,
    a trial labelled manipulated with other intensities gets the same answers as one labelled
    control. Guards: a PSE (or condition bias) handed to the model observer, and answers that
    read the trial's log relative intensity."""
    params = inspect.signature(ModelObserver).parameters
    assert set(params) == {"weber", "window", "hk", "lapse", "seed"}
    with pytest.raises(TypeError):
        ModelObserver(pse={"manipulated": 0.13})  # type: ignore[call-arg]
    a, b = interval(flash(27.0)), interval(flash(30.0))
    answers = []
    for label in (("control", 27.0), ("manipulated", 49.0)):
        o = ModelObserver(seed=2)
        answers.append([
            o.answer(trial(1 + i % 2, *label), lambda o=o: [o.perceive(a), o.perceive(b)])
            for i in range(200)
        ])  # fmt: skip
    assert answers[0] == answers[1]


def test_nayatani_terms_match_published_values_and_a_grey_is_its_luminance() -> None:
    """Nayatani's (1997) q(θ), K_Br and Γ against the values colour-science's tests give for
    the same formulas (u'v' (0.4035, 0.5393) around D65 at 63.66 cd/m²: Γ_obj 1.2618 VAC,
    1.3442 VCC; luminous VAC 1.7280); a grey keeps its luminance. Guards: a wrong
    coefficient, a dropped K_Br term, the object-colour formula used for luminous colours,
    and the normalisation lost (every pixel 7e-5 off)."""
    assert q_nayatani(0.0) == pytest.approx(-0.1212, abs=1e-7)
    assert q_nayatani(np.pi / 2) == pytest.approx(0.19168, abs=1e-6)
    assert k_br(10.0) == pytest.approx(0.713448177657588, rel=1e-9)
    assert k_br(63.66) == pytest.approx(1.000128455584031, rel=1e-9)
    u, v = 0.40351010, 0.53933673  # a red; XYZ with Y = 1 from its u'v'
    x, y = 9 * u / (6 * u - 16 * v + 12), 4 * v / (6 * u - 16 * v + 12)
    xyz = np.array([x / y, 1.0, (1 - x - y) / y])
    grey = 0.4462 * 1.3086**3
    for method, obj, lum in (("VAC", 1.261777232837009, 1.727991241148628),
                             ("VCC", 1.344152435497761, None)):  # fmt: skip
        g = float(hk_gamma(xyz, 63.66, method)) * grey
        assert g == pytest.approx(0.4462 * (obj + 0.3086) ** 3, rel=1e-6)
        if lum is not None:
            assert g == pytest.approx(lum, rel=1e-6)
    white = np.array([0.95047, 1.0, 1.08883])
    assert float(hk_gamma(white, 0.01, "VAC")) == pytest.approx(1.0, abs=1e-6)
    assert float(hk_gamma(np.zeros(3), 0.01, "VCC")) == pytest.approx(1.0, abs=1e-12)


def test_a_desaturated_image_of_equal_luminance_looks_darker() -> None:
    """The Helmholtz-Kohlrausch effect: a ColorChecker-like image of saturated colours and the
    same image desaturated to grey, pixel for pixel at the same luminance (4.2's mesopic
    luminances): the colourful one is brighter to the model observer with either of Nayatani's
    estimates (VCC more), equal without the colour term, and is chosen over the grey one.
    Guards: the colour term's sign flipped or dropped (`hk` ignored), and luminance computed
    with other weights than the display's (the grey would not match)."""
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0.0, 1.0, (6, 4, 3)) ** 2
    rgb[rgb.sum(-1) < 0.3] += 0.2
    Y = rgb @ RGB_TO_XYZ[1]
    scale = 0.02 / Y.mean()  # mean 0.02 cd/m^2, mesopic
    colour = np.repeat(np.kron(rgb * scale, np.ones((2, 2, 1)))[None], 75, axis=0)
    grey = np.repeat((colour @ RGB_TO_XYZ[1])[..., None], 3, axis=-1)
    a, b = interval(colour), interval(grey)
    assert log10_brightness(a, hk="none") == pytest.approx(log10_brightness(b, hk="none"), abs=2e-3)
    for hk in ("VAC", "VCC"):
        assert log10_brightness(a, hk=hk) > log10_brightness(b, hk=hk) + 0.005, hk
    vac, vcc = (log10_brightness(a, hk=h) - log10_brightness(b, hk=h) for h in ("VAC", "VCC"))
    assert vcc > vac
    assert choose_rate(ModelObserver(seed=1, weber=0.01), a, b, 200) > 0.8


def test_bloch_summation_lets_an_afterimage_add_within_its_window() -> None:
    """Bloch's law: within the window light is summed, so a 50 ms flash followed by an
    afterimage is brighter than the flash alone by the afterimage's share of the window, and a
    whole-interval window gives the afterimage its whole duration. An all-black interval is
    finite. Guards: a peak over single frames instead of a window (the afterimage would add
    nothing), a window not in seconds, and log10(0) for black."""
    times = np.arange(15) * DT
    plain, after = flash(27.0), flash(27.0, after=0.5)
    for window, share in ((0.1, 0.05), (math.inf, 12 * DT)):
        b0 = 10 ** log10_brightness(interval(plain), window=window, hk="none")
        b1 = 10 ** log10_brightness(interval(after), window=window, hk="none")
        span = min(window, 15 * DT)
        patch = 36 / 64  # the flash's share of the frame
        assert b1 - b0 == pytest.approx(0.5 * patch * share / span, rel=0.02), window
    assert windowed_peak(np.array([0, 1, 0, 0.0]), np.arange(4.0), 4.0, 2.0) == 0.5
    black = log10_brightness(interval(np.zeros((4, 2, 2, 3)), times[:4]))
    assert math.isfinite(black) and black == -30.0
    with pytest.raises(ValueError, match="NaN"):
        Interval(np.full((2, 2, 2, 3), np.nan, np.float16), times[:2], 1.0, PAPER_DISPLAY)


def test_a_seed_fixes_every_answer_and_the_runner_shows_the_observer_the_page_frames(
    tmp_path: Path,
) -> None:
    """The same seed gives the same answers (another seed others), through a whole headless
    run too; and what the runner hands the observer is its percept of the frames the page gets
    for the trial (`Presented.intervals`). Guards: an unseeded generator, and the runner
    passing the observer other frames (the clip unscaled, or the intervals swapped)."""
    a, b = interval(flash(27.0)), interval(flash(28.0))
    answers = [
        [o.answer(trial(1), lambda o=o: [o.perceive(a), o.perceive(b)]) for _ in range(100)]
        for o in (ModelObserver(seed=4), ModelObserver(seed=4), ModelObserver(seed=5))
    ]
    assert answers[0] == answers[1] != answers[2]
    d = load_design("4.1")
    runs = [run_headless(d, ModelObserver(seed=3), tmp_path / f"r{i}", seed=3, size=SIZE,
                         backend=BACKEND) for i in range(2)]  # fmt: skip
    chose = [[r["chose_test"] for r in rows(p)] for p in runs]
    assert chose[0] == chose[1] and len(chose[0]) == 320
    training = [r for r in rows(runs[0]) if r["condition"] == "training"]
    assert sum(r["correct"] == "1" for r in training) >= 18  # 14 or 49 against 27: easy
    control, strong = (
        clip(d, d.conditions[c].test, SIZE, BACKEND) for c in ("control", "manipulated")
    )
    shown = Presented(
        Trial(1, 3, "final", "manipulated", 27.0, 35.0, 2, False), (control, strong), 0
    )
    observer = ModelObserver()
    got = percepts(shown, d, observer)
    assert got == tuple(observer.perceive(i) for i in shown.intervals(d))
    assert got[1] > got[0]  # the test, 35 cd/m^2, second


def _summary_numbers(out: str) -> dict[str, str]:
    got = {}
    for line in out.splitlines():
        if m := re.match(r"\s+(median PSE, \w+|rank-sum p)\b.*?\s{2,}(\S+)", line):
            got[m.group(1)] = m.group(2)
    return got


@pytest.mark.parametrize(
    ("preset", "task", "paper"),
    [("4.1", "afterimage", ("paper (11 human observers)", "-0.020", "0.449")),
     ("4.2", "mesopic", ("paper (10 human observers)", "+0.130", "2.84e-06"))],
)  # fmt: skip
def test_a_headless_run_prints_the_models_prediction_beside_the_papers(
    tmp_path: Path, capsys, preset: str, task: str, paper: tuple[str, ...]
) -> None:
    """`gazehdr experiment run 4.x --headless` runs the model observer (the default), then
    prints the group's PSE medians and rank-sum labelled as the model's prediction, and the
    paper's numbers beside, labelled as the paper's; the printed prediction is the analysis
    of the results it wrote, not the paper's numbers. Guards: the echo observer as the default,
    the paper's numbers printed as the prediction, a summary that is not the written results'."""
    out = tmp_path / "ds"
    argv = ["experiment", "run", preset, "--out", str(out), "--headless", "--size", "48x27",
            "--backend", BACKEND, "--observers", "3", "--seed", "1"]  # fmt: skip
    assert cli_main(argv) == 0
    printed = capsys.readouterr().out
    assert "model prediction (3 simulated)" in printed and "model observer (Weber" in printed
    for text in paper:
        assert text in printed
    paths = sorted(out.glob("sub-*/beh/*_beh.tsv"))
    assert len(paths) == 3 and [str(p) for p in paths] == printed.splitlines()[:3]
    group = prediction.analyse_group(paths, task)
    numbers = _summary_numbers(printed)
    assert numbers["median PSE, control"] == f"{group.median_control:+.3f}"
    assert numbers["median PSE, manipulated"] == f"{group.median_manipulated:+.3f}"
    assert numbers["rank-sum p"] == f"{group.p:.3g}"
    assert "PSE without noise" in printed


def test_the_colour_term_moves_the_mesopic_prediction_as_the_model_says() -> None:
    """4.2's real stimuli: without the colour term the manipulated test (at the control's mean
    pixel value) has the control's brightness, PSE 0; Nayatani's H-K term moves it. The
    manipulated rendering is less saturated but shifted to purple, where the effect is
    strongest (q(θ) < 0), and the shift wins: the model observer sees it slightly brighter,
    PSE below 0, not above it as the paper's observers did. Guards: the colour term dropped
    (both PSEs 0) and its hue term's sign flipped (the PSE moves up)."""
    d = load_design("4.2")
    pse = {hk: prediction.noiseless_pse(d, ModelObserver(hk=hk), SIZE, BACKEND)
           for hk in ("none", "VAC", "VCC")}  # fmt: skip
    for hk in pse:
        assert abs(pse[hk]["control"]) < 3e-4, hk
    assert abs(pse["none"]["manipulated"]) < 5e-4
    assert pse["VCC"]["manipulated"] < pse["VAC"]["manipulated"] < -1e-3
