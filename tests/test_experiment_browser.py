"""The experiment's page in real headless Chromium against a real server (the fixtures of
tests/browser.py): the echo observer answers a short run by key presses, and the
results, participants and session log hold what happened; the API refuses a caller without the
credential."""

from __future__ import annotations

import contextlib
import csv
import json
import struct
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gazehdr.drivers.sessionlog import read_session_log
from gazehdr.experiment.design import parse_design
from gazehdr.experiment.observer import EchoObserver
from gazehdr.experiment.schedule import schedule
from gazehdr.experiment.service import ExperimentConfig
from tests.browser import WAIT_MS, browser  # noqa: F401 -- the browser fixture
from tests.test_bids_dataset import validate
from tests.test_experiment_design import PALETTE, TINY
from tests.waiting import wait_until

SIZE = (48, 27)
SEED = 5
SMALLER = TINY.replace("control = 4", "control = 2")
DESIGN = parse_design(SMALLER.replace('name = "main"', 'name = "main"\nintro = "Go on."'), "t.toml")


def _config(tmp_path: Path) -> ExperimentConfig:
    return ExperimentConfig(DESIGN, tmp_path / "results", SIZE, "reference", SEED)


def _call(url: str, method: str = "GET", body: Any = None, auth: dict | None = None) -> int:
    data = None if body is None else json.dumps(body).encode()
    headers = {"Content-Type": "application/json", **(auth or {})}
    request = urllib.request.Request(url, data, headers, method=method)
    try:
        with urllib.request.urlopen(request, timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as e:
        return e.code


@contextlib.contextmanager
def experiment_page(chromium: Any, url: str, observer: str) -> Iterator[Any]:
    """The page past consent and instructions; no error on it, checked when it closes."""
    page = chromium.new_page(viewport={"width": 480, "height": 270})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(f"{url}/experiment")  # loopback: the page gives the browser its cookie
        page.wait_for_function("() => window.gazehdrExperiment.design", timeout=WAIT_MS)
        page.fill("#observer", observer)
        page.check("#agree")
        page.click("#begin")
        page.wait_for_function(
            "() => window.gazehdrExperiment.state === 'instructions'", timeout=WAIT_MS
        )
        page.keyboard.press("Space")
        yield page
    finally:
        page.close()
    assert not errors, errors


def test_the_experiment_api_needs_the_credential(live_server, tmp_path: Path) -> None:
    server = live_server(experiment=_config(tmp_path))
    api = f"{server.url}/api/experiment"
    start = {"observer": "a1", "consent": True}
    assert _call(api) == 401
    assert _call(f"{api}/runs", "POST", start) == 401
    assert _call(f"{api}/runs/x/trial") == 401
    answer = {"trial": 1, "key": "1", "response_time": 1.0}
    assert _call(f"{api}/runs/x/response", "POST", answer) == 401
    assert _call(api, auth={"Authorization": "Bearer wrong"}) == 401
    assert _call(api, auth=server.auth) == 200
    assert _call(f"{api}/runs", "POST", {**start, "consent": False}, server.auth) == 400
    assert _call(f"{api}/runs", "POST", {**start, "observer": "a-1"}, server.auth) == 422
    assert _call(f"{api}/runs/nope/trial", auth=server.auth) == 404
    assert _call(f"{server.url}/experiment") == 200  # the page itself is public
    assert not (tmp_path / "results" / "sub-a1").exists()
    with urllib.request.urlopen(f"{server.url}/openapi.json", timeout=30) as r:
        spec = json.load(r)
    ours = {p: ops for p, ops in spec["paths"].items() if p.startswith("/api/experiment")}
    assert len(ours) == 7
    for ops in ours.values():
        assert all(op["security"] == [{"bearer": []}, {"cookie": []}] for op in ops.values())


def test_the_echo_observer_answers_through_the_page(live_server, browser, tmp_path) -> None:  # noqa: F811
    server = live_server(experiment=_config(tmp_path))
    trials = schedule(DESIGN, SEED)
    observer = EchoObserver({"control": 0.05}, sigma=0.1, lapse=0.0, seed=3)
    with experiment_page(browser, server.url, "web1") as page:
        pressed = []
        for trial in trials:
            if trial.number == 5:  # the main block's first: its intro, until Space
                page.wait_for_function(
                    "() => window.gazehdrExperiment.state === 'intro'", timeout=WAIT_MS
                )
                assert page.text_content("#message-text").startswith("Go on.")
                page.keyboard.press("Space")
            page.wait_for_function(
                "(n) => window.gazehdrExperiment.state === 'prompt' "
                "&& window.gazehdrExperiment.trial === n",
                arg=trial.number,
                timeout=WAIT_MS,
            )
            chose = observer.chooses_test(trial.log_relative_intensity, trial.condition)
            key = DESIGN.keys[(trial.test_interval if chose else 3 - trial.test_interval) - 1]
            page.wait_for_timeout(30)  # a response time the page can measure
            page.keyboard.press(key)
            pressed.append(key)
        page.wait_for_function("() => window.gazehdrExperiment.state === 'done'", timeout=WAIT_MS)
        ex = page.evaluate("() => window.gazehdrExperiment")
        message = page.text_content("#message-text")
    assert message == DESIGN.texts.thanks
    assert ex["result"]["finished"] and not ex["result"]["excluded"]
    # every frame of both intervals (1 flash + 2 black) shown, or counted late
    assert ex["shown"] + sum(a["frames_late"] for a in ex["answers"]) >= len(trials) * 2 * 3
    assert ex["shown"] >= len(trials) * 2  # the flash frames at least
    results = tmp_path / "results"
    with (results / "sub-web1/beh/sub-web1_task-tiny_beh.tsv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    assert [r["response_key"] for r in rows] == pressed
    assert [int(r["test_interval"]) for r in rows] == [t.test_interval for t in trials]
    times = [float(r["response_time"]) for r in rows]
    assert all(0.02 < t < 30 for t in times)
    assert times == pytest.approx([a["response_time"] for a in ex["answers"]], abs=1e-9)
    late = [int(r["frames_late"]) for r in rows]
    assert late == [a["frames_late"] for a in ex["answers"]]
    for r in rows:
        assert float(r["flash_duration"]) == pytest.approx(0.05)
        assert float(r["black_duration"]) == pytest.approx(0.1)
    with (results / "participants.tsv").open(encoding="utf-8") as f:
        (participant,) = csv.DictReader(f, delimiter="\t")
    assert participant["participant_id"] == "sub-web1" and participant["tiny_excluded"] == "false"
    log = read_session_log(results / "sourcedata/sub-web1/sub-web1_task-tiny_sessionlog.jsonl")
    notes = [json.loads(n.text) for n in log.notes]
    answers = [n for n in notes if n["event"] == "response"]
    assert [a["key"] for a in answers] == pressed
    assert [a["response_time"] for a in answers] == pytest.approx(times)
    assert log.header.tracker["via"] == "browser" and len(log.samples) == len(trials)
    validate(results)


def test_an_observer_picks_afterimages_from_the_palette(live_server, browser, tmp_path) -> None:  # noqa: F811
    """Sec. 4.3 through the page: after each flash, the options' images load, clicks pick
    them, Enter answers; the results hold the labels picked."""
    design = parse_design(PALETTE, "pal.toml")
    config = ExperimentConfig(design, tmp_path / "results", SIZE, "reference", SEED)
    server = live_server(experiment=config)
    with experiment_page(browser, server.url, "pal1") as page:
        for number, labels in ((1, ["C1"]), (2, ["H1", "C1"])):
            page.wait_for_function(
                "(n) => window.gazehdrExperiment.state === 'prompt' "
                "&& window.gazehdrExperiment.trial === n "
                "&& [...document.querySelectorAll('#palette img')].every((i) => i.complete "
                "&& i.naturalWidth > 0)",
                arg=number,
                timeout=WAIT_MS,
            )
            page.keyboard.press("Enter")  # nothing picked yet: no answer
            for label in labels:
                page.click(f"#palette figure[data-label={label}]")
            page.keyboard.press("Enter")
        page.wait_for_function("() => window.gazehdrExperiment.state === 'done'", timeout=WAIT_MS)
        answers = page.evaluate("() => window.gazehdrExperiment.answers")
    assert [a["palette"] for a in answers] == [["C1"], ["H1", "C1"]]
    beh = tmp_path / "results/sub-pal1/beh/sub-pal1_task-pal_beh.tsv"
    with beh.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    assert [r["palette_choice"] for r in rows] == ["C1", "H1,C1"]
    assert all(float(r["response_time"]) > 0 for r in rows)
    validate(tmp_path / "results")


def _json(url: str, auth: dict, body: Any = None) -> Any:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data, {"Content-Type": "application/json", **auth})
    with urllib.request.urlopen(request, timeout=60) as r:
        return json.load(r) if "json" in r.headers["content-type"] else r.read()


def test_a_connected_trackers_gaze_is_recorded_not_followed(live_server, tmp_path) -> None:
    """With one tracker connected, its gaze at each trial and answer goes into the run's log;
    the frames still look at the fixation target (the paper's procedure)."""
    from websockets.sync.client import connect

    server = live_server(experiment=_config(tmp_path))
    api = f"{server.url}/api/experiment"
    with connect(server.ws_url + "/ws/gaze", additional_headers=server.auth) as daemon:
        daemon.send(json.dumps({"type": "hello", "protocol": 1, "tracker": "rig"}))
        assert json.loads(daemon.recv())["type"] == "welcome"
        daemon.send(json.dumps({"type": "samples", "samples": [{"t": 2, "x": 0.7, "y": 0.2}]}))
        feed = server.hub.trackers.feed("rig")
        wait_until(lambda: feed.samples > 0, what="the tracker's sample")
        run = _json(f"{api}/runs", server.auth, {"observer": "t1", "consent": True})["run"]
        trial = _json(f"{api}/runs/{run}/trial", server.auth)
        frames = _json(f"{api}/runs/{run}/trial/frames", server.auth)
        answer = {"trial": trial["trial"], "key": "1", "response_time": 0.5, "frames_late": 0}
        out = _json(f"{api}/runs/{run}/response", server.auth, answer)
    assert out["finished"] is False and trial["trial"] == 1
    header = struct.unpack_from("<4sHHIIdff", frames)
    assert header[0] == b"GZHF" and header[6:8] == pytest.approx(DESIGN.fixation)
    log = tmp_path / "results/sourcedata/sub-t1/sub-t1_task-tiny_sessionlog.jsonl"
    notes = [json.loads(line)["text"] for line in log.read_text().splitlines()[1:]
             if '"k":"note"' in line]  # fmt: skip
    tracked = [json.loads(n) for n in notes if "tracker_gaze" in n]
    assert tracked == [{"event": "tracker_gaze", "x": 0.7, "y": 0.2}] * 2
