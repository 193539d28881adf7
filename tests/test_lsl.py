"""Lab Streaming Layer both ways, with real liblsl on loopback (tests/lsl_loopback.py): a pylsl
outlet in the test feeds `gazehdr daemon --source lsl:...`, a real server follows its
fixations, and pylsl inlets in the test receive what gazehdr publishes; the source reconnects;
`serve --lsl-outlet` publishes what each session follows."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import websockets
from conftest import sole_tracker
from lsl_loopback import PUPIL_CAPTURE, TOBII, Recorder, pylsl, stream_info, until

from gazehdr.drivers.lsl.meta import StreamDescription, channel_layout
from gazehdr.drivers.registry import SourceUnavailableError, open_source
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import Note, read_session_log

SCREEN = ScreenGeometry(screen_width_px=1000, screen_height_px=500)
XY = [("x", "both", "ScreenX", "pixels"), ("y", "both", "ScreenY", "pixels")]
FAST = {"resolve_timeout_s": 0.8, "backoff_initial_s": 0.05, "backoff_max_s": 0.2}


def _scripted_tobii(rate_hz: float = 250.0) -> list[list[float]]:
    """Fixate A for 400 ms, a 40 ms saccade to B, fixate B for 500 ms: Tobii's normalised
    binocular values (left and right eye 0.01 apart, pupils 3 mm)."""
    a, b = (0.25, 0.25), (0.75, 0.7)
    rows = []
    for i in range(int(0.94 * rate_hz)):
        k = min(max((i / rate_hz - 0.4) / 0.04, 0.0), 1.0)
        x, y = a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1])
        rows.append([x - 0.005, y, 3.0, x + 0.005, y, 3.0])
    return rows


def test_the_daemon_follows_an_lsl_tracker_and_publishes_what_it_records(
    live_server, lsl_outlet, tmp_path: Path
) -> None:
    server = live_server(token="t")
    tracker = lsl_outlet(
        stream_info("LoopTobii", "Eyetracker", TOBII, rate=250, source_id="loop-tobii")
    )
    record = tmp_path / "rec.jsonl"
    gazehdr = Path(sys.executable).with_name("gazehdr")
    command = [str(gazehdr), "daemon", "--source", "lsl:LoopTobii", "--server", server.ws_url]
    command += ["--token", "t", "--record", str(record), "--lsl-outlet", "gz-daemon-test"]
    command += ["--screen", "1000x500"]
    with subprocess.Popen(command, stderr=subprocess.PIPE, text=True) as proc:
        try:
            gaze = Recorder("name='gz-daemon-test'")  # as LabRecorder records it
            events = Recorder("name='gz-daemon-test events'")
            until(lambda: server.hub.trackers.feeds(), what="the daemon's hello")
            rows = _scripted_tobii()
            t0 = pylsl.local_clock()
            stamps = [t0 + i / 250 for i in range(len(rows))]
            for row, stamp in zip(rows, stamps, strict=True):
                tracker.push_sample(row, stamp)
                time.sleep(max(0.0, stamp - pylsl.local_clock()))
            until(lambda: sole_tracker(server).samples == len(rows), what="every sample delivered")
            reading = sole_tracker(server).reading
            assert (reading.x, reading.y) == (pytest.approx(0.75, abs=0.01), pytest.approx(0.7))
            until(lambda: len(gaze.rows) == len(rows), what="every sample published")
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=15)
        except BaseException:
            proc.kill()
            raise
    assert proc.returncode == 0, err
    log = read_session_log(record)
    assert log.header.tracker["stream"] == "LoopTobii" and log.header.screen.screen_width_px == 1000
    assert [s.valid for s in log.samples] == [True] * len(rows)
    assert log.samples[0].left.pupil_mm == 3.0 and log.samples[0].x == pytest.approx(250.0)
    assert any(n.text.startswith("LSL stream 'LoopTobii'") for n in log.notes)
    assert list(open_source(f"replay:{record}@max")) == log.samples  # and it replays
    # the time stamps survive the trip: tracker stamp -> monotonic ns -> published LSL time
    # (give or take the clock correction: tens of µs on loopback, refreshed as it runs)
    published = gaze.stop().stamps
    assert published == pytest.approx(stamps, abs=1e-4)
    assert [s.t_ns - log.samples[0].t_ns for s in log.samples] == pytest.approx(
        [round((s - stamps[0]) * 1e9) for s in stamps], abs=100_000
    )
    # what was published is what was recorded: the samples, and the events as markers
    layout = channel_layout(StreamDescription.from_xml(gaze.header))
    assert [
        layout.sample(r, s.t_ns, SCREEN) for r, s in zip(gaze.rows, log.samples, strict=True)
    ] == [s for s in log.samples]
    markers = [json.loads(text) for (text,) in events.stop().rows]
    fixations = [m for m in markers if m["k"].startswith("fixation")]
    assert [(m["k"], m["id"]) for m in fixations] == [
        (e.kind, e.id) for e in log.events if e.kind.startswith("fixation")
    ]
    assert {m["id"] for m in fixations} == {1, 2}  # A and B, nothing along the saccade


def test_the_daemon_passes_min_confidence_to_the_lsl_source(
    live_server, lsl_outlet, tmp_path: Path
) -> None:
    """`gazehdr daemon --min-confidence 0.4`: Pupil Capture's relay layout, confidence 0.5 then
    0.2 by turns: the 0.5 samples valid (below the default 0.6 they would not be), the 0.2 not."""
    server = live_server(token="t")
    tracker = lsl_outlet(
        stream_info("LoopPupil", "Gaze", PUPIL_CAPTURE, rate=100, source_id="loop-pupil")
    )
    record = tmp_path / "rec.jsonl"
    gazehdr = Path(sys.executable).with_name("gazehdr")
    command = [str(gazehdr), "daemon", "--source", "lsl:LoopPupil", "--server", server.ws_url]
    command += ["--token", "t", "--record", str(record), "--min-confidence", "0.4"]
    confidences = [0.5, 0.2] * 10
    with subprocess.Popen(command, stderr=subprocess.PIPE, text=True) as proc:
        try:
            until(lambda: server.hub.trackers.feeds(), what="the daemon's hello")
            t0 = pylsl.local_clock()
            for i, c in enumerate(confidences):
                tracker.push_sample([c, 0.5, 0.5, 20.0, 20.0, 3.0, 3.0], t0 + i / 100)
            until(lambda: sole_tracker(server).samples == len(confidences), what="the samples")
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=15)
        except BaseException:
            proc.kill()
            raise
    assert proc.returncode == 0, err
    log = read_session_log(record)
    assert [s.valid for s in log.samples] == [c >= 0.4 for c in confidences]


def test_min_confidence_is_refused_for_a_source_without_one(capsys) -> None:
    from gazehdr.drivers.daemon_cli import daemon_main

    argv = ["--server", "ws://127.0.0.1:9", "--token", "t", "--min-confidence", "0.5"]
    assert daemon_main([*argv, "--source", "synthetic"]) == 2
    assert capsys.readouterr().err.startswith(
        "gazehdr daemon: error: a minimum confidence is for sources whose samples carry one "
        "(pupil, lsl); synthetic samples do not"
    )
    with pytest.raises(SystemExit):
        daemon_main([*argv[:-1], "1.5", "--source", "lsl"])
    assert "--min-confidence: expected a number from 0 to 1, got '1.5'" in capsys.readouterr().err


def test_a_stream_that_goes_and_comes_back_is_read_again_and_nothing_received_is_lost(
    lsl_outlet,
) -> None:
    def flaky() -> pylsl.StreamInfo:
        return stream_info("Flaky", "Gaze", XY, rate=100, source_id="flaky")

    first = pylsl.StreamOutlet(flaky())  # destroyed in the test, its consumer connected
    source = open_source("lsl:Flaky", **FAST)
    got: list[GazeSample | Note] = []
    reader = threading.Thread(target=lambda: got.extend(source.records()), daemon=True)
    reader.start()

    def samples() -> list[GazeSample]:
        return [r for r in list(got) if isinstance(r, GazeSample)]

    for i in range(50):
        first.push_sample([float(i), 1.0])
    until(lambda: len(samples()) == 50, what="the first 50 samples")
    del first  # the tracker's app quits
    until(lambda: any("lost" in r.text for r in list(got) if isinstance(r, Note)), what="loss")
    second = lsl_outlet(flaky())  # ... and starts again; its samples count from when it is read

    def connected() -> int:
        return sum("connected" in r.text for r in list(got) if isinstance(r, Note))

    until(lambda: connected() == 2, what="the source back on the stream")
    for i in range(100, 150):
        second.push_sample([float(i), 2.0])
    until(lambda: len(samples()) == 100, what="the next 50 samples")
    source.close()
    reader.join(5)
    assert [s.x for s in samples()] == [*map(float, range(50)), *map(float, range(100, 150))]
    times = [s.t_ns for s in samples()]
    assert times == sorted(times)
    notes = [r.text for r in got if isinstance(r, Note)]
    host = socket.gethostname()
    assert [n.split(";")[0] for n in notes if "connected" in n] == [
        f"LSL stream 'Flaky' (Gaze, 2 float32 channels on {host}) connected"
    ] * 2
    assert source.reconnects == 1


def test_a_daemon_started_before_its_stream_waits_for_it(lsl_outlet) -> None:
    opened: list = []
    waiter = threading.Thread(
        target=lambda: opened.append(open_source("lsl:Late", wait=True, **FAST))
    )
    waiter.start()
    time.sleep(1.0)
    assert waiter.is_alive() and not opened  # still waiting, with back-off
    late = lsl_outlet(stream_info("Late", "Gaze", XY, source_id="late"))
    waiter.join(10)
    (source,) = opened
    assert source.info.name == "lsl Late" and source.info.tracker["source_id"] == "late" and late


def test_what_cannot_be_followed_is_refused_clearly(
    lsl_outlet, monkeypatch: pytest.MonkeyPatch
) -> None:
    twins = [lsl_outlet(stream_info("Twin", "Gaze", XY, source_id=f"twin-{c}")) for c in "ab"]
    with pytest.raises(SourceUnavailableError, match="several LSL streams match name='Twin'") as e:
        open_source("lsl:Twin", **FAST)
    assert "'twin-a'" in str(e.value) and "'twin-b'" in str(e.value) and twins
    assert open_source("lsl:source_id=twin-b", **FAST).info.tracker["source_id"] == "twin-b"
    with pytest.raises(SourceUnavailableError, match="no LSL stream matches name='Nobody'"):
        open_source("lsl:Nobody", **FAST)
    bare = lsl_outlet(pylsl.StreamInfo("Bare", "Gaze", 2, 0, "float32", "bare"))
    with pytest.raises(SourceUnavailableError, match=r"'Bare' .* has no usable gaze channels"):
        open_source("lsl:Bare", **FAST)
    assert bare
    monkeypatch.setitem(sys.modules, "pylsl", None)
    with pytest.raises(
        SourceUnavailableError,
        match=r"LSL source unavailable: Lab Streaming Layer needs pylsl: install gazehdr\[lsl\]",
    ):
        open_source("lsl")


def test_serve_publishes_the_gaze_each_session_follows(live_server) -> None:
    server = live_server(lsl_outlet="gz-serve-test", record=True, gaze_source="synthetic")

    enough = threading.Event()  # the recorders have what the test checks: the session may end

    async def view() -> None:
        async with websockets.connect(
            server.ws_url + "/ws/view", additional_headers=server.auth
        ) as ws:
            deadline = time.monotonic() + 60  # a loaded machine resolves streams slowly
            while not enough.is_set() and time.monotonic() < deadline:
                await asyncio.wait_for(ws.recv(), 10)

    viewer = threading.Thread(target=lambda: asyncio.run(view()))
    viewer.start()
    try:
        gaze = Recorder("name='gz-serve-test'")
        events = Recorder("name='gz-serve-test events'")
        until(
            lambda: (
                len(gaze.rows) >= 2
                and any(json.loads(text)["k"] == "fixation_start" for (text,) in events.rows)
            ),
            timeout=30,
            what="two samples and a fixation published",
        )
    finally:
        enough.set()
        viewer.join()
    until(lambda: not server.hub.sessions, what="the session's end")
    until(lambda: gaze.lost and events.lost, what="the session's streams withdrawn")
    (recorded,) = (server.config.data_dir / "recordings").glob("*.jsonl")
    lines = [json.loads(line) for line in recorded.read_text().splitlines()[1:]]
    header = read_session_log(recorded).header
    # what was published since the recorders connected is the end of what was recorded
    layout = channel_layout(StreamDescription.from_xml(gaze.header))
    samples = [(s.x, s.y) for s in (layout.sample(r, 0, header.screen) for r in gaze.rows)]
    assert len(samples) >= 2  # the synthetic scan path fixates a few times a second
    assert samples == [(r["x"], r["y"]) for r in lines if r["k"] == "s"][-len(samples) :]
    markers = [json.loads(text) for (text,) in events.rows]
    assert markers[-1] == {"k": "note", "t": markers[-1]["t"], "text": "session ended"}
    assert markers == [r for r in lines if r["k"] != "s"][-len(markers) :]
    assert any(m["k"] == "fixation_start" for m in markers)
    assert StreamDescription.from_xml(gaze.header).acquisition()["application"] == "gazehdr serve"


def test_sessions_that_do_not_publish_keep_no_journal(live_server) -> None:
    server = live_server()

    async def check() -> None:
        async with websockets.connect(
            server.ws_url + "/ws/view", additional_headers=server.auth
        ) as ws:
            await asyncio.wait_for(ws.recv(), 5)
            (live,) = server.hub.sessions.values()
            assert not live.session.recording and live.outlet is None

    asyncio.run(check())


def test_the_outlet_flags_say_what_is_missing(tmp_path, monkeypatch, capsys) -> None:
    from gazehdr.drivers.daemon_cli import daemon_main
    from gazehdr.serve import build_config

    options = dict(
        host="127.0.0.1", port=0, scene="flash", scale=None, gaze="mouse", fps=30.0,
        size=(96, 54), fit_viewport=False, params_file=None, token="t", data_dir=tmp_path,
        allow_origins=(), encoding="rgb10a2", backend="reference", seed=0,
    )  # fmt: skip
    assert build_config(**options, lsl_outlet="gz").lsl_outlet == "gz"
    with pytest.raises(ValueError, match="--lsl-outlet needs a stream name"):
        build_config(**options, lsl_outlet=" ")
    monkeypatch.setitem(sys.modules, "pylsl", None)
    with pytest.raises(ValueError, match=r"LSL outlet unavailable: .*install gazehdr\[lsl\]"):
        build_config(**options, lsl_outlet="gz")
    argv = ["--source", "synthetic", "--server", "ws://127.0.0.1:9", "--token", "t"]
    assert daemon_main([*argv, "--lsl-outlet"]) == 2
    assert "LSL outlet unavailable: Lab Streaming Layer needs pylsl: install gazehdr[lsl]" in (
        capsys.readouterr().err
    )


def test_connecting_a_connected_or_closed_source_is_refused(lsl_outlet) -> None:
    """`connect` only when DISCONNECTED: again while an inlet is open would leak it, after close
    would open one nothing closes. Guards the state check."""
    from gazehdr.drivers.states import InvalidStateError, Link

    lsl_outlet(stream_info("Once", "Gaze", XY, source_id="once"))
    source = open_source("lsl:Once", **FAST)
    assert source.connection_state is Link.CONNECTED
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state CONNECTED"):
        source.connect()
    source.close()
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state CLOSED"):
        source.connect()


def test_a_stream_is_found_only_in_its_own_lsl_session(lsl_outlet, tmp_path: Path) -> None:
    """What keeps the suite's two workers apart (lsl_loopback): a resolver with another
    SessionID does not find this process's stream, one with the same finds it."""
    lsl_outlet(stream_info("Apart", "Gaze", XY, source_id="apart"))
    ours = Path(os.environ["LSLAPICFG"]).read_text()
    if worker := os.environ.get("PYTEST_XDIST_WORKER"):  # the suite's usual run
        assert re.search(rf"(?m)^SessionID = gazehdr-.*-{worker}$", ours), ours
    other = tmp_path / "other.cfg"
    alone = re.sub(r"(?m)^SessionID = .*\n", "", ours)  # under xdist: the worker's own
    other.write_text(alone.replace("[lab]\n", "[lab]\nSessionID = gazehdr-another-run\n", 1))
    assert other.read_text() != ours
    resolve = "import pylsl; print(len(pylsl.resolve_bypred(\"name='Apart'\", 1, 2.0)))"

    def found(config: str) -> str:
        env = {**os.environ, "LSLAPICFG": config}
        done = subprocess.run([sys.executable, "-c", resolve], env=env, capture_output=True,
                              text=True, timeout=30)  # fmt: skip
        return done.stdout.strip()

    assert found(str(other)) == "0"
    assert found(os.environ["LSLAPICFG"]) == "1"
