"""Trials through the simulator, headless: the durations measured from the frames' simulation
times, what the clips show, a whole preset answered by the echo observer, the training rule
ending a run, the session log, the BIDS output under the official validator, and the CLI.
Frames are tiny (48×27) on the NumPy reference backend: CI has two cores."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from gazehdr.cli import main as cli_main
from gazehdr.drivers.sessionlog import read_session_log
from gazehdr.experiment.columns import BEH_COLUMNS
from gazehdr.experiment.dataset import read_beh
from gazehdr.experiment.design import load_design, parse_design
from gazehdr.experiment.observer import EchoObserver
from gazehdr.experiment.runner import ExperimentRun, Presented, RunError, run_headless
from gazehdr.experiment.schedule import Trial, log_ratio
from gazehdr.experiment.stimulus import PHASES, Clip, clip, palette_images
from tests.test_bids_dataset import validate
from tests.test_experiment_design import PALETTE, TINY

SIZE = (48, 27)
BACKEND = "reference"


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f, delimiter="\t"))


def luminance(v: np.ndarray) -> np.ndarray:
    """Linear luminance of display values (v = J^0.455)."""
    return np.power(v.astype(float), 1 / 0.455) @ np.array([0.2126, 0.7152, 0.0722])


def test_the_flash_and_black_are_measured_from_the_frames_times() -> None:
    """4.1's 50 ms flash and 2.5 s black, from the first frame of each phase to the first of the
    next (or the clip's end), to within one step; the flash frames show the flash, the black
    ones the afterimage, stronger with the manipulated test's j1 = 0.001 than with 0.0003."""
    d = load_design("4.1")
    weak = clip(d, d.conditions["control"].test, SIZE, BACKEND)
    strong = clip(d, d.conditions["manipulated"].test, SIZE, BACKEND)
    for c in (weak, strong):
        m = c.measured()
        assert abs(m["on"] - 0.05) <= d.dt / 2 and abs(m["off"] - 2.5) <= d.dt / 2
        assert c.phases.count("on") == 3 and c.phases.count("off") == 150
        assert np.allclose(np.diff(c.times), d.dt)
    shown = luminance(weak.shown(27.0, d))
    assert shown[0].max() == pytest.approx(27.0 / d.display.white_cd_m2, rel=0.02)  # scale "peak"
    assert luminance(weak.shown(49.0, d))[0].max() > shown[0].max()
    after = [float(luminance(c.shown(27.0, d))[3:].max()) for c in (weak, strong)]
    assert 0 < after[0] < after[1]
    assert shown[3:].max() < shown[0].max() / 10  # black, but for the afterimage


def test_a_duration_off_the_step_is_rounded_and_the_measure_says_so() -> None:
    """0.07 s at 20 Hz is 1.4 steps: one step is simulated and shown, and measured as 0.05."""
    d = parse_design(TINY.replace("on = 0.05", "on = 0.07").replace("off = 0.1", "off = 0.13"))
    m = clip(d, d.conditions["training"].test, SIZE, BACKEND).measured()
    assert m["on"] == pytest.approx(0.05) and m["off"] == pytest.approx(0.15)


def test_mesopic_tests_match_the_control_mean_and_lose_colour() -> None:
    """4.2: the standard's (photopic) rendering has its white tile, its brightest part, at the
    intensity; the manipulated test (mesopic colour and acuity, no Purkinje) is shown at the mean
    pixel value of that rendering at the same intensity, and its colours are closer together
    (the patches fade towards one dull purple)."""
    d = load_design("4.2")
    control = clip(d, d.conditions["control"].test, SIZE, BACKEND)
    mesopic = clip(d, d.conditions["manipulated"].test, SIZE, BACKEND)
    assert control.measured() == pytest.approx({"on": 1.25, "off": 0.75}, abs=d.dt / 2)
    a, b = control.shown(0.055, d)[0], mesopic.shown(0.055, d, like=control)[0]
    assert luminance(a).max() == pytest.approx(
        0.055 / d.display.white_cd_m2, rel=0.01
    )  # white tile
    assert luminance(b).mean() == pytest.approx(luminance(a).mean(), rel=0.005)
    brighter = luminance(control.shown(0.075, d)[0]).mean()
    assert brighter == pytest.approx(luminance(a).mean() * 0.075 / 0.055, rel=0.01)
    # and a trial as the page gets it: the manipulated test matched to its own standard
    trial = Trial(1, 3, "final", "manipulated", 0.055, 0.055, 2, False)
    frames = list(Presented(trial, (control, mesopic), 0.0).frames(d))
    first = [next(v for _, k, phase, v in frames if k == i and phase == "on") for i in (1, 2)]
    assert luminance(first[1]).mean() == pytest.approx(luminance(first[0]).mean(), rel=0.005)
    assert luminance(first[1]).max() < luminance(first[0]).max()  # no tile at the intensity

    def spread(v: np.ndarray) -> float:
        J = np.power(v.astype(float), 1 / 0.455)
        chromaticity = J / np.maximum(J.sum(-1, keepdims=True), 1e-12)
        return float(chromaticity.reshape(-1, 3).std(axis=0).sum())

    assert spread(b) < 0.8 * spread(a)


def test_the_echo_observer_runs_the_whole_afterimage_preset(tmp_path: Path) -> None:
    observer = EchoObserver({"manipulated": 0.1}, sigma=0.05, lapse=0.0, seed=2)
    path = run_headless("4.1", observer, tmp_path, seed=7, size=SIZE, backend=BACKEND)
    assert path == tmp_path / "sub-sim/beh/sub-sim_task-afterimage_beh.tsv"
    got = rows(path)
    assert list(got[0]) == list(BEH_COLUMNS)
    assert len(got) == 320 and [r["trial"] for r in got] == [str(i) for i in range(1, 321)]
    count = {(r["block"], r["condition"]) for r in got}
    assert count == {("1", "training"), ("2", "control"), ("3", "control"), ("3", "manipulated")}
    for r in got:
        assert abs(float(r["flash_duration"]) - 0.05) <= 1 / 120
        assert abs(float(r["black_duration"]) - 2.5) <= 1 / 120
        assert r["response_time"] == "n/a" and r["palette_choice"] == "n/a"
        assert (r["correct"] == "n/a") == (r["condition"] != "training")
        chose_first = r["response_key"] == "1"
        assert r["chose_test"] == str(int(chose_first == (r["test_interval"] == "1")))
    # the run clock: each trial starts when the one before ended (two clips of 2.55 s)
    onsets = [float(r["onset"]) for r in got]
    assert np.allclose(np.diff(onsets), 2 * 2.55)
    # the observer's bias shows: at equal intensity it picks the manipulated test far less often
    equal = [r for r in got if r["test_intensity"] == "27.0"]
    rate = {
        c: np.mean([r["chose_test"] == "1" for r in equal if r["condition"] == c])
        for c in ("control", "manipulated")
    }
    assert rate["manipulated"] < 0.2 < 0.3 < rate["control"]
    participants = rows(tmp_path / "participants.tsv")
    assert participants == [  # columns of the task's own: an observer may run several tasks
        {"participant_id": "sub-sim", "afterimage_training_score": "1.0",
         "afterimage_excluded": "false"}
    ]  # fmt: skip
    sidecar = json.loads(path.with_suffix(".json").read_text())
    assert set(BEH_COLUMNS) <= set(sidecar) and sidecar["response_time"]["Units"] == "s"
    validate(tmp_path)


def test_an_observer_who_guesses_is_excluded_after_training(tmp_path: Path) -> None:
    guesser = EchoObserver(sigma=50.0, lapse=0.0, seed=1)
    path = run_headless(TINY_LONG_TRAINING, guesser, tmp_path, seed=1, size=SIZE,
                        backend=BACKEND, observer_id="g1")  # fmt: skip
    got = rows(path)
    assert len(got) == 20 and {r["block"] for r in got} == {"1"}  # stopped after training
    score = sum(r["correct"] == "1" for r in got) / 20
    assert score < 0.7
    (p,) = rows(tmp_path / "participants.tsv")
    task = TINY_LONG_TRAINING.name
    assert p == {"participant_id": "sub-g1", f"{task}_training_score": repr(score),
                 f"{task}_excluded": "true"}  # fmt: skip
    validate(tmp_path)


TINY_LONG_TRAINING = parse_design(TINY.replace("training = 2", "training = 10"))


def test_the_session_log_holds_every_trial_response_and_the_fixation_gaze(tmp_path: Path) -> None:
    d = parse_design(TINY)
    run = ExperimentRun(d, "s1", tmp_path, seed=4, size=SIZE, backend=BACKEND)
    with pytest.raises(RunError, match="present one first"):
        run.respond("1")
    shown = run.present()
    with pytest.raises(ValueError, match="key 'x' is not an answer"):
        run.respond("x")
    with pytest.raises(RunError, match="trial 5 is not the one waiting"):
        run.respond("1", 0.5, trial_number=5)
    run.respond("2", 0.25, trial_number=1, tracker_gaze=(0.4, 0.6), frames_late=2)
    while run.current is not None:
        run.present()
        run.respond("1", 0.5)
    with pytest.raises(RunError, match="finished"):
        run.present()
    log = read_session_log(next((tmp_path / "sourcedata/sub-s1").glob("*_sessionlog.jsonl")))
    notes = [json.loads(n.text) for n in log.notes]
    events = [n["event"] for n in notes]
    assert events.count("trial") == events.count("response") == events.count("prompt") == 12
    assert events.count("interval 1 on") == events.count("interval 2 off") == 12
    assert events[0] == "run" and events[-1] == "end" and "training" in events
    first = next(n for n in notes if n["event"] == "response")
    assert first == {"event": "response", "trial": 1, "key": "2", "response_time": 0.25,
                     "chose_test": shown.trial.test_interval == 2,
                     "correct": shown.trial.correct(2), "frames_late": 2}  # fmt: skip
    assert {"event": "tracker_gaze", "x": 0.4, "y": 0.6} in notes
    assert len(log.samples) == 12 and {(s.x, s.y) for s in log.samples} == {(960.0, 540.0)}
    # the responses' times move the run clock on: trial 2 starts after trial 1's answer
    got = rows(run.result)
    assert float(got[1]["onset"]) == pytest.approx(2 * 0.15 + 0.25)
    assert got[0]["response_time"] == "0.25" and got[0]["frames_late"] == "2"
    assert got[1]["frames_late"] == "n/a"


def test_a_run_refuses_a_folder_that_is_not_a_dataset_and_an_existing_run(tmp_path: Path) -> None:
    d = parse_design(TINY)
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not empty and not a BIDS dataset"):
        ExperimentRun(d, "s1", tmp_path, seed=0, size=SIZE, backend=BACKEND)
    out = tmp_path / "ds"
    run_headless(d, EchoObserver(), out, size=SIZE, backend=BACKEND, observer_id="s1")
    with pytest.raises(FileExistsError, match="another run number"):
        ExperimentRun(d, "s1", out, seed=0, size=SIZE, backend=BACKEND)
    with pytest.raises(ValueError, match="letters and digits"):
        ExperimentRun(d, "s-1", out, seed=0, size=SIZE, backend=BACKEND)
    second = run_headless(d, EchoObserver(), out, size=SIZE, backend=BACKEND,
                          observer_id="s1", run=2)  # fmt: skip
    assert second.name == "sub-s1_task-tiny_run-2_beh.tsv"
    validate(out)


def test_the_command_line_runs_headless_and_names_bad_input(tmp_path: Path, capsys) -> None:
    """`--headless` with the echo observer (its PSEs given, labelled as no prediction) and the
    model observer (the default, refusing a PSE), and the errors of bad input. Guards: the
    model observer accepting a PSE, the echo observer running without one, and the paper's
    numbers printed beside a design that is not the paper's."""
    design = tmp_path / "tiny.toml"
    design.write_text(TINY)
    argv = ["experiment", "run", str(design), "--out", str(tmp_path / "ds"), "--headless",
            "--size", "48x27", "--backend", BACKEND, "--seed", "3"]  # fmt: skip
    echo = [*argv, "--simulated-observer", "echo"]
    assert cli_main([*echo, "--pse", "control=0.05"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].endswith("sub-sim_task-tiny_beh.tsv") and len(rows(Path(printed[0]))) == 12
    assert "echo (PSEs given)" in "\n".join(printed) and "no prediction" in "\n".join(printed)
    assert cli_main([*echo, "--run", "2"]) == 2
    assert "echo needs --pse" in capsys.readouterr().err
    assert cli_main([*echo, "--run", "2", "--pse", "control"]) == 2
    assert "'control': give CONDITION=PSE" in capsys.readouterr().err
    assert cli_main([*argv, "--run", "2", "--pse", "control=0.1"]) == 2
    assert "the model observer takes no PSE" in capsys.readouterr().err
    assert cli_main([*argv, "--run", "3", "--observers", "2"]) == 0  # the model observer
    printed = capsys.readouterr().out
    assert "sub-sim01_task-tiny_run-3_beh.tsv" in printed and "model prediction" in printed
    assert "paper (" not in printed  # not one of the paper's designs
    palette = ["experiment", "run", "4.3", "--out", str(tmp_path / "p"), "--headless"]
    assert cli_main(palette) == 2
    assert "palette trials, which a simulated observer cannot answer" in capsys.readouterr().err


def test_palette_trials_record_the_options_picked(tmp_path: Path) -> None:
    """Sec. 4.3: a flash, its black, then the options picked; the 2AFC columns are n/a. The
    options' images are the first black frame after their flash: ours coloured, at the paper's
    j1 = 0.03 of display white (Fig. 15's caption: brightened for print), Ritschel's grey (the
    paper's point: no colour contrast) and bright after a 1e7 cd/m^2 flash."""
    d = parse_design(PALETTE)
    picks = {1: ["H1"], 2: ["H1", "C1"]}
    path = run_headless(d, EchoObserver(), tmp_path, size=SIZE, backend=BACKEND,
                        palette_chooser=lambda trial, labels: picks[trial.number])  # fmt: skip
    got = rows(path)
    assert [r["palette_choice"] for r in got] == ["H1", "H1,C1"]
    assert [r["test_intensity"] for r in got] == ["10000000.0", "100000.0"]
    for r in got:
        assert r["condition"] == "palette" and r["flash_duration"] == "0.05"
        for column in ("standard_intensity", "log_relative_intensity", "test_interval",
                       "response_key", "chose_test", "correct"):  # fmt: skip
            assert r[column] == "n/a", column
    validate(tmp_path)
    ours, ritschel = palette_images(d, SIZE, BACKEND)
    J = [np.power(v.astype(float), 1 / 0.455) for v in (ours, ritschel)]
    spread = [float((j.max(-1) - j.min(-1)).max()) for j in J]
    assert J[0].max() > 0.02 and spread[0] > 0.5 * J[0].max()
    assert J[1].max() > 0.1 and spread[1] < 0.01
    with pytest.raises(ValueError, match="palette_chooser"):
        run_headless(d, EchoObserver(), tmp_path / "x", size=SIZE, backend=BACKEND)


def test_a_palette_trial_takes_only_known_options(tmp_path: Path) -> None:
    run = ExperimentRun(parse_design(PALETTE), "p1", tmp_path, seed=0, size=SIZE, backend=BACKEND)
    run.present()
    for bad in ([], ["H1", "H1"], ["X9"], None):
        with pytest.raises(ValueError, match="one or more of H1, C1"):
            run.respond(palette=bad)
    with pytest.raises(ValueError, match="one or more of H1, C1"):
        run.respond("1")  # a key is no answer to a palette trial
    run.respond(palette=["C1"], response_time=1.5)
    run.present()
    assert run.respond(palette=["H1"]).finished


def test_a_black_stimulus_frame_is_refused_not_scaled_to_nan() -> None:
    design = parse_design(TINY)
    black = Clip(
        np.zeros((2, 4, 4, 3), np.float16), np.array([0.0, 0.1]), PHASES, 0.2, 2.2,
        (0.2126, 0.7152, 0.0722),
    )  # fmt: skip
    with pytest.raises(ValueError, match="stimulus frame 0 is black"):
        black.shown(100.0, design)


def test_relative_intensities_stay_finite_where_their_quotient_would_not(tmp_path: Path) -> None:
    assert log_ratio(1e300, 1e-10) == pytest.approx(310.0)
    assert log_ratio(1e-300, 1e100) == pytest.approx(-400.0)
    path = tmp_path / "sub-a_task-x_beh.tsv"
    rows = [dict.fromkeys(BEH_COLUMNS, "n/a") for _ in range(1)]
    rows[0] |= {"test_intensity": "1e-300", "standard_intensity": "1e100"}
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.DictWriter(f, list(BEH_COLUMNS), delimiter="\t", lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    trials = read_beh(path)
    assert trials[0].x == pytest.approx(-400.0)
