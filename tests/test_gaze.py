"""One gaze path into a session (server/gaze.py): pointer, trackers and tracks behind
`GazeInput.at(t)`, and trackers that each drive only the sessions bound to them — directly,
then through a real server with two daemons."""

from __future__ import annotations

import asyncio
import dataclasses
import json

import pytest
import websockets
from conftest import sole_tracker
from sessions import new_session, tick

from gazehdr.drivers.samples import GazePoint
from gazehdr.gaze import PointerGaze, TrackerFigures, Trackers, TrackGaze
from gazehdr.protocol import Choose, Eyes, Gaze, ParamChange, Reset, decode_frame
from gazehdr.session import SessionSettings
from gazehdr.sim import Params
from gazehdr.sim.layout import blind_spot_strength
from tests.test_server import Client, run

SETTINGS = SessionSettings(width=32, height=18, scene="lamp", backend="reference")
#: `gazehdr serve --token gaze-test` (the servers these tests start): writes, /ws/view, recordings
AUTH = {"Authorization": "Bearer gaze-test"}


# --- the inputs ----------------------------------------------------------------------------


def test_pointer_takes_gaze_and_eyes_and_nothing_else() -> None:
    pointer = PointerGaze()
    assert pointer.take(Gaze(0.2, 0.7, 4), now=10.0)
    r = pointer.at(123.0)
    assert (r.x, r.y, r.eyes_open, r.seq, r.received_at) == (0.2, 0.7, True, 4, 10.0)
    assert pointer.take(Eyes(False), now=11.0)
    closed = pointer.at(0.0)
    # closing the eyes is no new gaze: the latency metrics keep timing the last pointer move
    assert (closed.x, closed.eyes_open, closed.received_at) == (0.2, False, 10.0)
    assert not pointer.take(Reset(), now=12.0)
    assert pointer.at(0.0) is closed


def test_a_track_replays_from_where_it_was_chosen_and_loops() -> None:
    class Ramp:  # x = t
        def at(self, t: float) -> GazePoint:
            return GazePoint(t, 0.5, True)

    gaze = TrackGaze(Ramp(), start=2.0, length=3.0)
    assert [gaze.at(t).x for t in (2.0, 3.5, 5.0, 6.0)] == [0.0, 1.5, 0.0, 1.0]


def test_trackers_with_the_same_name_are_told_apart_and_get_their_feed_back() -> None:
    trackers = Trackers()
    first, second = trackers.connect("Tobii Pro"), trackers.connect("Tobii Pro")
    assert (first.name, second.name) == ("Tobii Pro", "Tobii Pro #2")
    assert trackers.sole_connected() is None  # two stations: nobody guesses
    trackers.disconnect(first)
    assert trackers.sole_connected() is second
    assert trackers.connect("Tobii Pro") is first  # the first station reconnects as itself
    assert trackers.connect(None).name == "unnamed tracker"
    assert [t["name"] for t in trackers.describe()] == [
        "Tobii Pro", "Tobii Pro #2", "unnamed tracker",
    ]  # fmt: skip


# --- a session follows one input -----------------------------------------------------------


def test_a_session_follows_only_the_tracker_it_chose() -> None:
    trackers = Trackers()
    a, b = trackers.connect("station A"), trackers.connect("station B")
    session = new_session(SETTINGS, trackers=trackers)
    _, notes = tick(session, 0.0, [(Choose("gaze_source", "remote:station B"), 0.0)])
    assert notes[-1]["gaze_source"] == "remote:station B"
    assert {"remote:station A", "remote:station B"} <= set(notes[-1]["gaze_sources"])
    a.fixate(0.1, 0.1, True, now=1.0)
    b.fixate(0.8, 0.3, True, now=2.0)
    frame, _ = tick(session, 0.1, [(Gaze(0.5, 0.5, 1), 3.0)])  # the pointer is not followed
    h = frame.header
    assert (h.gaze_x, h.gaze_y, h.tracker) == (pytest.approx(0.8), pytest.approx(0.3), True)
    assert frame.gaze_received_at == 2.0
    a.fixate(0.2, 0.9, False, now=4.0)  # station A blinks and moves: nothing here
    frame, _ = tick(session, 0.1, [])
    assert (frame.header.gaze_x, frame.header.eyes_open) == (pytest.approx(0.8), True)
    assert frame.gaze_received_at is None  # no new gaze from B


def test_remote_binds_once_exactly_one_tracker_is_connected() -> None:
    trackers = Trackers()
    session = new_session(SETTINGS, trackers=trackers, name="s")
    first = trackers.connect("rig 1")
    second = trackers.connect("rig 2")
    _, notes = tick(session, 0.0, [(Choose("gaze_source", "remote"), 0.0)])
    assert notes[-1]["gaze_source"] == "remote"  # two connected: waits for the viewer
    first.fixate(0.9, 0.9, True, now=1.0)
    frame, _ = tick(session, 0.1, [])
    assert frame.header.gaze_x == pytest.approx(0.5)  # held where it was
    trackers.disconnect(first)
    second.fixate(0.25, 0.75, True, now=2.0)
    frame, notes = tick(session, 0.1, [])
    assert notes[-1]["gaze_source"] == "remote:rig 2"
    assert (frame.header.gaze_x, frame.header.gaze_y) == (pytest.approx(0.25), 0.75)
    trackers.connect("rig 1")  # bound now: another tracker coming back changes nothing
    first.fixate(0.9, 0.9, True, now=3.0)
    frame, notes = tick(session, 0.1, [])
    assert notes == [] and frame.header.gaze_x == pytest.approx(0.25)


def test_the_session_times_its_step_with_the_clock_it_is_given() -> None:
    readings = iter([10.0, 10.25, 10.75])  # start, simulated (pixels in the message), encoded
    session = new_session(SETTINGS)
    session.clock = lambda: next(readings)
    frame, _ = tick(session, 0.0, [])
    assert (frame.sim_seconds, frame.encode_seconds) == (0.25, 0.5)
    assert frame.header.server_ms == 750.0


# --- the source's figures reach the model (Sec. 5 foveal blind spot) -------------------------

BLIND = dataclasses.replace(SETTINGS, params=Params(foveal_blind_spot=1.0), fps=60.0)
MS_4 = 4_000_000  # a 250 Hz tracker's sample interval, ns


def _strength(session) -> float:
    return blind_spot_strength(session.params)


def test_a_feed_measures_its_trackers_rate_from_the_samples_times() -> None:
    feed = Trackers().connect("t")
    feed.hello(0.5)
    feed.count([i * MS_4 for i in range(200)])  # 0.8 s: not measured yet
    assert feed.known == TrackerFigures(0.5, None) and feed.samples == 200
    feed.count([i * MS_4 + (i % 3) * 100_000 for i in range(200, 600)])  # jitter: still 250
    assert feed.known == TrackerFigures(0.5, 250.0)
    feed.count([10**12 + i * 8_000_000 for i in range(130)])  # after a pause, 125 Hz
    assert feed.known == TrackerFigures(0.5, 125.0)
    feed.count([5 * MS_4 + i * MS_4 for i in range(200)])  # the clock went back: a new window
    assert feed.known == TrackerFigures(0.5, 125.0)
    feed.hello(None)  # a new hello that does not say: the accuracy is no longer known
    assert feed.known.accuracy_deg is None


def test_a_session_takes_its_trackers_figures_and_the_pointer_is_exact() -> None:
    """A tracker whose hello says 0.5 deg and whose samples come at 250 Hz gives the blind
    spot the strength of a 0.5 deg, 250 Hz tracker; the pointer is exact, read once a frame."""
    trackers = Trackers()
    feed = trackers.connect("eyes")
    session = new_session(BLIND, trackers=trackers)
    exact = blind_spot_strength(Params(foveal_blind_spot=1.0).replace(
        tracker_accuracy_deg=0.0, tracker_rate_hz=60.0))  # fmt: skip
    assert (session.params.tracker_accuracy_deg, session.params.tracker_rate_hz) == (0.0, 60.0)
    assert _strength(session) == pytest.approx(exact) and exact > 0.9
    feed.hello(0.5)
    feed.count([i * MS_4 for i in range(400)])
    _, notes = tick(session, 0.1, [(Choose("gaze_source", "remote:eyes"), 0.0)])
    assert notes[-1]["params"]["tracker_accuracy_deg"] == 0.5
    tracker = Params(foveal_blind_spot=1.0, tracker_accuracy_deg=0.5, tracker_rate_hz=250.0)
    assert _strength(session) == pytest.approx(blind_spot_strength(tracker))
    assert 0.4 < _strength(session) < 0.6  # docs/model.md: such a tracker allows half
    _, notes = tick(session, 0.1, [])
    assert notes == []  # nothing changed: no rebuild, no state
    feed.hello(None)  # reconnected without an accuracy: the default (the paper's tracker)
    tick(session, 0.1, [])
    assert session.params.tracker_accuracy_deg == Params().tracker_accuracy_deg
    tick(session, 0.1, [(Choose("gaze_source", "mouse"), 0.0)])
    assert _strength(session) == pytest.approx(exact)
    track = TrackGaze(None, 0.0, 1.0, TrackerFigures(None, 500.0))  # a log with a rate only
    assert track.figures(60.0) == TrackerFigures(0.0, 500.0)


def test_tracker_parameters_the_user_set_stay_as_set() -> None:
    trackers = Trackers()
    feed = trackers.connect("eyes")
    feed.hello(0.5)
    feed.count([i * MS_4 for i in range(400)])
    mine = dataclasses.replace(BLIND, params=BLIND.params.replace(tracker_accuracy_deg=0.8))
    session = new_session(mine, trackers=trackers)
    tick(session, 0.1, [(Choose("gaze_source", "remote:eyes"), 0.0)])
    assert (session.params.tracker_accuracy_deg, session.params.tracker_rate_hz) == (0.8, 250.0)
    tick(session, 0.1, [(ParamChange({"tracker_rate_hz": 100.0}), 0.0)])
    tick(session, 0.1, [])
    assert session.params.tracker_rate_hz == 100.0
    defaults = Params()  # the panel's paper preset: the source's figures apply again
    reset = {"tracker_accuracy_deg": 1.0, "tracker_rate_hz": defaults.tracker_rate_hz}
    tick(session, 0.1, [(ParamChange(reset), 0.0)])
    assert (session.params.tracker_accuracy_deg, session.params.tracker_rate_hz) == (0.5, 250.0)


# --- through a real server -------------------------------------------------------------------


async def _daemon(server, name: str, x: float, y: float) -> websockets.ClientConnection:
    auth = {"Authorization": f"Bearer {server.token}"}
    ws = await websockets.connect(server.ws_url + "/ws/gaze", additional_headers=auth)
    await ws.send(json.dumps({"type": "hello", "protocol": 1, "tracker": name}))
    assert json.loads(await ws.recv())["type"] == "welcome"
    fixation = {"type": "event", "kind": "fixation_start", "id": 1, "t": 1, "x": x, "y": y}
    await ws.send(json.dumps(fixation))
    return ws


def test_two_stations_on_one_server_each_drive_only_their_sessions(live_server) -> None:
    server = live_server(token="t", gaze_source="remote")

    async def check() -> None:
        a = await _daemon(server, "station A", 0.2, 0.3)
        b = await _daemon(server, "station B", 0.7, 0.6)
        viewers = [await Client.open(server), await Client.open(server)]
        for viewer in viewers:
            assert {"remote:station A", "remote:station B"} <= set(viewer.hello["gaze_sources"])
            assert viewer.hello["gaze_source"] == "remote"  # two trackers: it waits
        for viewer, name in zip(viewers, ("station A", "station B"), strict=True):
            await viewer.send(type="gaze_source", name=f"remote:{name}")
        h_a, _ = await viewers[0].frame(lambda h: abs(h.gaze_x - 0.2) < 1e-6)
        h_b, _ = await viewers[1].frame(lambda h: abs(h.gaze_x - 0.7) < 1e-6)
        assert (h_a.gaze_y, h_b.gaze_y) == (pytest.approx(0.3), pytest.approx(0.6))
        # Station B's next fixation moves B's session only; A's keeps following A.
        move = {"type": "event", "kind": "fixation_start", "id": 2, "t": 2, "x": 0.9, "y": 0.1}
        await b.send(json.dumps(move))
        await viewers[1].frame(lambda h: abs(h.gaze_x - 0.9) < 1e-6)
        for _ in range(5):
            header, _ = await viewers[0].frame()
            assert header.gaze_x == pytest.approx(0.2) and header.tracker
        await a.close()
        note = await viewers[1].note("tracker")
        assert note == {"type": "tracker", "name": "station A", "connected": False, "samples": 0}
        await b.close()
        for viewer in viewers:
            await viewer.ws.close()

    run(asyncio.wait_for(check(), 120))


def test_each_station_names_its_tracker(live_server, tmp_path) -> None:
    """`gazehdr daemon --name`: the hello, and so the server's list, carries the station's name
    (two identical trackers would otherwise be told apart only by the order they connect in)."""
    from gazehdr.drivers.daemon_cli import daemon_main
    from gazehdr.drivers.sessionlog import SessionHeader, SessionLogWriter
    from gazehdr.drivers.sources import SyntheticSource

    server = live_server(token="t")
    log = tmp_path / "in.jsonl"
    with SessionLogWriter(log, SessionHeader(tracker={"name": "Tobii Pro Fusion"})) as writer:
        writer.write_all(SyntheticSource(3, 250.0, duration=0.5, realtime=False, start_ns=0))
    argv = ["--source", f"replay:{log}@max", "--server", server.ws_url, "--token", "t", "-q"]
    assert daemon_main([*argv, "--name", "station 3", "--record", str(tmp_path / "o.jsonl")]) == 0
    assert [t["name"] for t in server.hub.trackers.describe()] == ["station 3"]
    assert sole_tracker(server).samples == 126


def test_a_daemons_accuracy_and_rate_reach_the_sessions_that_follow_it(live_server, tmp_path):
    """`gazehdr daemon --accuracy-deg 0.5` streaming a 250 Hz recording: the hello carries the
    accuracy, the server measures the rate, a session bound to the tracker gets both."""
    from gazehdr.drivers.daemon_cli import daemon_main
    from gazehdr.drivers.sessionlog import SessionHeader, SessionLogWriter
    from gazehdr.drivers.sources import SyntheticSource

    server = live_server(token="t")
    log = tmp_path / "in.jsonl"
    with SessionLogWriter(log, SessionHeader(tracker={"name": "rig"})) as writer:
        writer.write_all(SyntheticSource(3, 250.0, duration=2.5, realtime=False, start_ns=0))
    argv = ["--source", f"replay:{log}@max", "--server", server.ws_url, "--token", "t", "-q"]
    assert daemon_main([*argv, "--accuracy-deg", "0.5", "--name", "rig"]) == 0
    assert sole_tracker(server).known == TrackerFigures(0.5, 250.0)
    session = new_session(BLIND, trackers=server.hub.trackers)
    tick(session, 0.1, [(Choose("gaze_source", "remote:rig"), 0.0)])
    assert (session.params.tracker_accuracy_deg, session.params.tracker_rate_hz) == (0.5, 250.0)


def test_the_table_of_tracker_names_is_bounded() -> None:
    """A viewer choosing ever new `remote:NAME`s cannot grow the server's table without end."""
    from gazehdr.gaze import MAX_TRACKERS

    trackers = Trackers()
    session = new_session(SETTINGS, trackers=trackers)
    for i in range(MAX_TRACKERS):
        trackers.feed(f"t{i}")
    _, notes = tick(session, 0.0, [(Choose("gaze_source", "remote:one more"), 0.0)])
    full = f"this server knows {MAX_TRACKERS} tracker names already"
    assert notes == [{"type": "error", "in": "gaze_source", "message": full}]
    assert session.gaze_source == "mouse" and len(trackers.feeds()) == MAX_TRACKERS
    with pytest.raises(ValueError, match="tracker names already"):
        trackers.connect("a new station")


def test_serve_streams_a_tracker_of_its_own_machine_to_its_sessions(tmp_path) -> None:
    """`gazehdr serve --tracker SOURCE`: the source reaches sessions as a daemon's would, over
    /ws/gaze (one gaze path), and its samples are recorded where the viewer can replay them."""
    import os
    import re
    import subprocess
    import sys
    from urllib.request import Request, urlopen

    argv = [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--size", "64x36",
            "--backend", "reference", "--gaze", "remote", "--tracker", "synthetic:4",
            "--data-dir", str(tmp_path), "--token", "gaze-test"]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    server = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=env)  # fmt: skip
    try:
        assert server.stdout is not None
        url = next(m[1] for line in server.stdout if (m := re.search(r"open (http://\S+)/ ", line)))

        async def follow() -> set[tuple[float, float]]:
            async with websockets.connect(
                url.replace("http", "ws") + "/ws/view", additional_headers=AUTH
            ) as ws:
                seen: set[tuple[float, float]] = set()
                while len(seen) < 3:  # the scan path moves from fixation to fixation
                    message = await ws.recv()
                    if isinstance(message, str):
                        note = json.loads(message)
                        if note["type"] == "state":
                            assert note["gaze_source"] == "remote:synthetic (seed 4)"
                        continue
                    header, _ = decode_frame(message)
                    if header.tracker:
                        seen.add((round(header.gaze_x, 6), round(header.gaze_y, 6)))
                return seen

        assert len(run(asyncio.wait_for(follow(), 120))) == 3
        with urlopen(Request(url + "/api/recordings", headers=AUTH), timeout=30) as response:
            names = json.loads(response.read())["recordings"]
        assert any(name.startswith("gaze-") for name in names), names
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_serve_follows_an_lsl_tracker_of_its_own_machine(tmp_path, lsl_outlet) -> None:
    """`gazehdr serve --tracker lsl:NAME`: a real pylsl outlet in the test (liblsl on loopback,
    tests/lsl_loopback.py) fixating A then B by turns; the session follows the tracker's
    fixations to A and to B (normalised on the default 1920x1080 screen)."""
    import os
    import re
    import subprocess
    import sys
    import threading
    import time

    import lsl_loopback as loopback  # sets LSLAPICFG (loopback only) as it is imported

    xy = [("x", "both", "ScreenX", "pixels"), ("y", "both", "ScreenY", "pixels")]
    info = loopback.stream_info("ServeLoop", "Gaze", xy, rate=100, source_id="serve-loop")
    outlet = lsl_outlet(info)
    stop = threading.Event()

    def fixate() -> None:  # A for 0.4 s, B for 0.4 s, ... at 100 Hz until stopped
        i = 0
        while not stop.is_set():
            outlet.push_sample([480.0, 270.0] if (i // 40) % 2 == 0 else [1440.0, 675.0])
            i += 1
            time.sleep(0.01)

    argv = [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--size", "64x36",
            "--backend", "reference", "--gaze", "remote", "--tracker", "lsl:ServeLoop",
            "--data-dir", str(tmp_path), "--token", "gaze-test"]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    pusher = threading.Thread(target=fixate, daemon=True)
    pusher.start()
    server = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=env)  # fmt: skip
    try:
        assert server.stdout is not None
        url = next(m[1] for line in server.stdout if (m := re.search(r"open (http://\S+)/ ", line)))

        async def follow() -> tuple[set[tuple[float, float]], set[str]]:
            async with websockets.connect(
                url.replace("http", "ws") + "/ws/view", additional_headers=AUTH
            ) as ws:
                seen: set[tuple[float, float]] = set()
                sources: set[str] = set()
                while not {(0.25, 0.25), (0.75, 0.625)} <= seen:
                    message = await ws.recv()
                    if isinstance(message, str):
                        note = json.loads(message)
                        if note["type"] == "state":
                            sources.add(note["gaze_source"])
                        continue
                    header, _ = decode_frame(message)
                    if header.tracker:
                        seen.add((round(header.gaze_x, 3), round(header.gaze_y, 3)))
                return seen, sources

        seen, sources = run(asyncio.wait_for(follow(), 120))
        assert "remote:lsl ServeLoop" in sources
        # A and B, nothing between them; the centre until the first fixation is followed
        assert seen - {(0.5, 0.5)} == {(0.25, 0.25), (0.75, 0.625)}, seen
    finally:
        stop.set()
        server.terminate()
        server.wait(timeout=30)
        pusher.join(timeout=5)
