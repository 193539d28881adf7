"""The Pupil Capture source over real ZeroMQ sockets, against `pupil_capture.FakeCapture` (Pupil
Remote and the backbone as Capture's sources make them): samples on the host clock, surfaces
and malformed messages, Capture quitting, hanging and coming back, Pupil time set by someone
else, and `gazehdr daemon --source pupil:…` into a real server, its log replayed."""

from __future__ import annotations

import itertools
import logging
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zmq
from conftest import samples_received, sole_tracker
from pupil_capture import FakeCapture, Fixation, gaze_datum, play, surface_message

from gazehdr.drivers.pupil.source import PupilGazeSource, _Limited
from gazehdr.drivers.registry import SourceUnavailableError, open_source, open_track
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import Note, read_session_log

#: Short waits, so that a Capture that goes away is noticed in a fraction of a second.
FAST: dict[str, Any] = {
    "timeout_s": 0.3,
    "sync_interval_s": 0.2,
    "backoff_initial_s": 0.05,
    "backoff_max_s": 0.2,
}
LOGGER = "gazehdr.drivers.pupil"
#: How far a sample may lie from its datum's Pupil time on the host clock: the offset's
#: uncertainty is RTT/2 on loopback, well under this even on a busy machine; a forgotten offset
#: is 5000 s.
TIME_TOLERANCE_NS = 5_000_000
NOT_MSGPACK = b"\xc1not msgpack"  # 0xc1 is never used in msgpack


class Reader:
    """A source's records, read in a thread as the daemon reads them, each with its arrival."""

    def __init__(self, source: PupilGazeSource) -> None:
        self.source = source
        self.records: list[tuple[int, Any]] = []
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for record in self.source.records():
                self.records.append((time.monotonic_ns(), record))
        except BaseException as e:
            self.error = e

    @property
    def samples(self) -> list[GazeSample]:
        return [r for _, r in self.records if isinstance(r, GazeSample)]

    @property
    def notes(self) -> list[Note]:
        return [r for _, r in self.records if isinstance(r, Note)]

    def wait(self, until: Callable[[], bool], what: str, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not until():
            assert self.error is None, self.error
            assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s"
            time.sleep(0.01)

    def stop(self) -> None:
        self.source.close()
        self.thread.join(5)
        assert not self.thread.is_alive()
        assert self.error is None, self.error


@pytest.fixture
def capture() -> Any:
    started: list[FakeCapture] = []

    def start(remote_port: int = 0, **kw: Any) -> FakeCapture:
        fake = FakeCapture(remote_port, **kw)
        started.append(fake)
        return fake

    yield start
    for fake in started:
        fake.stop()


def _host_ns(datum: dict[str, Any], fake: FakeCapture) -> int:
    """Where the datum's Pupil time falls on the host clock, as the fake knows it."""
    return round((datum["timestamp"] + fake.timebase) * 1e9)


def _noted_offset(note: Note) -> float:
    """The offset in s a clock note gives."""
    match = re.fullmatch(r"pupil clock: pupil time = host monotonic \+ (\S+) s ± .*", note.text)
    assert match, note.text
    return float(match[1])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_samples_on_the_screen_and_the_host_clock(capture: Any) -> None:
    """Gaze published as Capture publishes it comes out in screen pixels, flipped to a top-left
    origin, on the host clock: Pupil time minus the offset measured by `t` round trips."""
    fake = capture()
    screen = ScreenGeometry(screen_width_px=1280, screen_height_px=720)
    source = open_source(fake.spec, geometry=screen, **FAST)
    assert isinstance(source, PupilGazeSource)
    assert source.info.name == f"pupil 127.0.0.1:{fake.remote_port}/screen"
    assert source.info.header_tracker() == {
        "name": source.info.name,
        "source": "pupil",
        "remote": f"tcp://127.0.0.1:{fake.remote_port}",
        "surface": "screen",
        "min_confidence": 0.6,
        "coordinates": "surface-normalised, origin bottom-left, as screen pixels",
        "clock": "Pupil time on the host clock by Pupil Remote 't' round trips",
        "capture_version": "3.6.0",
    }
    reader = Reader(source)
    fake.wait_subscribed()
    sent = play(
        fake,
        [
            Fixation(0.25, 0.75, 0.2),
            Fixation(0.5, 0.5, 0.1, confidence=0.3),
            Fixation(1.5, 0.5, 0.2),
        ],
    )
    reader.wait(lambda: len(reader.samples) == len(sent), "every datum")
    time.sleep(0.5)  # a few clock syncs more
    reader.stop()
    samples = reader.samples
    assert len(samples) == len(sent)
    best = source.clock.best
    assert best is not None
    assert abs(best.offset_ns - round(-fake.timebase * 1e9)) <= best.uncertainty_ns + 1_000
    for sample, datum in zip(samples, sent, strict=True):
        assert abs(sample.t_ns - _host_ns(datum, fake)) <= TIME_TOLERANCE_NS
        x, y = datum["norm_pos"]
        if datum["confidence"] >= 0.6:
            assert (sample.x, sample.y, sample.valid) == (x * 1280, (1 - y) * 720, True)
        else:
            assert not sample.valid
    assert samples[0].x == 320 and samples[0].y == 180
    assert samples[-1].x == 1920 and samples[-1].valid  # off the screen, to its right
    assert all(a.t_ns < b.t_ns for a, b in itertools.pairwise(samples))
    assert reader.records[0][1] == reader.notes[0]  # the clock first
    assert len(reader.notes) >= 3 and all(n.text.startswith("pupil clock: ") for n in reader.notes)
    assert fake.requests[:2] == ["v", "SUB_PORT"]
    assert set(fake.requests[2:]) == {"t"}  # never `T`: Pupil time is Capture's to set


def test_other_surfaces_and_malformed_messages(capture: Any, caplog: Any) -> None:
    """A surface whose name begins with ours is skipped quietly; a malformed message or datum
    is left out with a warning naming what was wrong, and the source goes on."""
    caplog.set_level(logging.WARNING, LOGGER)
    fake = capture()
    reader = Reader(open_source(fake.spec, **FAST))
    fake.wait_subscribed()
    now = fake.pupil_time()
    fake.publish(surface_message("screen 2", [gaze_datum(0.1, 0.1, now)], now))
    fake.send([b"surfaces.screen", NOT_MSGPACK])
    fake.send([b"surfaces.screen"])
    fake.publish({"topic": "surfaces.screen", "name": "screen"})
    bad = {**gaze_datum(0.2, 0.2, now), "norm_pos": None}
    fake.publish(surface_message("screen", [bad, gaze_datum(0.5, 0.5, now + 0.005)], now))
    fake.publish(surface_message("screen", [gaze_datum(0.75, 0.25, now + 0.01)], now + 0.01))
    reader.wait(lambda: len(reader.samples) == 2, "the two good datums")
    time.sleep(0.1)
    reader.stop()
    assert [(s.x, s.y) for s in reader.samples] == [(960, 540), (1440, 810)]
    assert reader.source.malformed == 4
    # One a second at most: the first says what was wrong, the next how many were held back.
    assert [r.getMessage() for r in caplog.records if r.name.startswith(LOGGER)] == [
        "Pupil Capture sent a malformed message: surfaces.screen: the payload is not msgpack "
        + _unpack_error(NOT_MSGPACK)
    ]


def test_warnings_are_held_back_and_counted(caplog: Any) -> None:
    caplog.set_level(logging.WARNING, LOGGER)
    limited = _Limited(1000)
    for text, t in [("a", 0), ("b", 10), ("c", 999), ("d", 1000), ("e", 1500), ("f", 2000)]:
        limited.warn(text, t)
    assert [r.getMessage() for r in caplog.records] == [
        "a",
        "d (2 more like it not shown)",
        "f (1 more like it not shown)",
    ]
    assert limited.count == 6


def test_each_malformed_thing_is_named(capture: Any, caplog: Any) -> None:
    """With the warnings not held back, each says what it was."""
    caplog.set_level(logging.WARNING, LOGGER)
    fake = capture()
    source = open_source(fake.spec, **FAST)
    source._malformed.interval_ns = 0
    reader = Reader(source)
    fake.wait_subscribed()
    now = fake.pupil_time()
    fake.send([b"surfaces.screen", NOT_MSGPACK])
    fake.send([b"surfaces.screen"])
    fake.publish({"topic": "surfaces.screen", "name": "screen"})
    no_time = {k: v for k, v in gaze_datum(0.2, 0.2, now).items() if k != "timestamp"}
    fake.publish(surface_message("screen", [no_time, gaze_datum(0.5, 0.5, now)], now))
    reader.wait(lambda: len(reader.samples) == 1, "the good datum")
    reader.stop()
    assert [r.getMessage() for r in caplog.records if r.name.startswith(LOGGER)] == [
        "Pupil Capture sent a malformed message: surfaces.screen: the payload is not msgpack "
        + _unpack_error(NOT_MSGPACK),
        "Pupil Capture sent a malformed message: 1 frames; a message is [topic, msgpack payload, "
        "...]",
        "Pupil Capture sent a malformed message: surfaces.screen: 'gaze_on_surfaces' is missing, "
        "not a list",
        "Pupil Capture sent a malformed datum: surfaces.screen: gaze_on_surfaces[0]: "
        "'timestamp' is missing, not a number",
    ]


def _unpack_error(data: bytes) -> str:
    """How the source says msgpack's complaint about `data`."""
    try:
        msgpack.unpackb(data)
    except Exception as e:
        return f"({type(e).__name__}: {e})"
    raise AssertionError("valid msgpack")


def test_capture_quits_and_comes_back(capture: Any, caplog: Any) -> None:
    """Capture quits and starts again on the same Pupil Remote port, with new backbone ports and
    a new Pupil time: the source reconnects with back-off, asks for the SUB port again, measures
    the clock afresh, and yields what came before and after."""
    caplog.set_level(logging.INFO, LOGGER)
    first = capture()
    source = open_source(first.spec, **FAST)
    reader = Reader(source)
    first.wait_subscribed()
    before = play(first, [Fixation(0.25, 0.75, 0.1)])
    reader.wait(lambda: len(reader.samples) == len(before), "the first Capture's gaze")
    first.stop()
    reader.wait(lambda: source.reconnects == 1, "noticing that Capture quit")
    time.sleep(0.3)  # a few attempts with back-off
    second = capture(first.remote_port, timebase=-9000.0)
    assert second.sub_port != first.sub_port
    second.wait_subscribed()
    after = play(second, [Fixation(0.75, 0.25, 0.1)])
    reader.wait(lambda: len(reader.samples) == len(before) + len(after), "the second's gaze")
    reader.stop()
    samples = reader.samples
    assert [(s.x, s.y) for s in samples] == [(480, 270)] * len(before) + [(1440, 810)] * len(after)
    for sample, datum in zip(samples[len(before) :], after, strict=True):
        assert abs(sample.t_ns - _host_ns(datum, second)) <= TIME_TOLERANCE_NS
    assert all(a.t_ns < b.t_ns for a, b in itertools.pairwise(samples))
    assert second.requests[:2] == ["v", "SUB_PORT"]
    assert "Pupil Capture stopped answering (Pupil Remote at tcp://127.0.0.1:" in caplog.text
    assert f"{len(before)} samples recorded so far are kept; reconnecting" in caplog.text
    assert "Pupil Capture not available" in caplog.text and "retrying in 0.05 s" in caplog.text
    assert "Pupil Capture reconnected" in caplog.text
    offsets = [_noted_offset(n) for n in reader.notes]
    assert offsets[0] == pytest.approx(5000, abs=1e-3)
    assert offsets[-1] == pytest.approx(9000, abs=1e-3)


def test_a_hung_capture_what_it_sent_is_kept(capture: Any) -> None:
    """Pupil Remote stops answering while the backbone still delivers: the gaze already on the
    SUB socket when the `t` request times out is read before the sockets close."""
    fake = capture()
    source = open_source(fake.spec, **{**FAST, "timeout_s": 0.5})
    reader = Reader(source)
    fake.wait_subscribed()
    fake.mute = True
    asked = len(fake.requests)
    reader.wait(lambda: len(fake.requests) > asked, "a request that will not be answered")
    now = fake.pupil_time()
    gaze = [gaze_datum(0.5, 0.5, now + i / 200) for i in range(3)]
    fake.publish(surface_message("screen", gaze, now))
    reader.wait(lambda: source.reconnects == 1, "the timeout")
    reader.wait(lambda: len(reader.samples) == 3, "the gaze that came while it hung")
    reader.stop()


def test_pupil_time_set_by_another_client(capture: Any, caplog: Any) -> None:
    """Someone sends `T 100` to Pupil Remote: gaze is stamped in the new Pupil time; the source
    sees samples stamped far from their arrival, measures at once, and places them right."""
    caplog.set_level(logging.WARNING, LOGGER)
    fake = capture()
    source = open_source(fake.spec, **{**FAST, "sync_interval_s": 60.0})
    reader = Reader(source)
    fake.wait_subscribed()
    ctx = zmq.Context.instance()
    other = ctx.socket(zmq.REQ)
    other.connect(f"tcp://127.0.0.1:{fake.remote_port}")
    other.send_string("T 100.0")
    assert other.recv_string() == "Timesync successful."
    other.close(linger=0)
    sent = play(fake, [Fixation(0.5, 0.5, 0.1)])
    reader.wait(lambda: len(reader.samples) == len(sent), "the gaze after the T")
    reader.stop()
    for sample, datum in zip(reader.samples, sent, strict=True):
        assert abs(sample.t_ns - _host_ns(datum, fake)) <= TIME_TOLERANCE_NS
    assert "Pupil Capture's gaze is stamped far from when it came" in caplog.text
    assert "Pupil time jumped" in caplog.text
    assert source.clock.jumps == 1


def test_a_quiet_surface_is_said(capture: Any, caplog: Any) -> None:
    caplog.set_level(logging.WARNING, LOGGER)
    fake = capture()
    reader = Reader(open_source(fake.spec, quiet_warning_s=0.2, **FAST))
    reader.wait(lambda: "has sent nothing" in caplog.text, "the warning")
    time.sleep(0.5)  # quiet for longer still: said once, not again every 0.2 s
    reader.stop()
    assert re.search(
        rf"Pupil Capture at tcp://127\.0\.0\.1:{fake.remote_port} has sent nothing on "
        r"'surfaces\.screen' for \d+ s: is the Surface Tracker plugin on, a surface named "
        r"'screen' defined, and its markers in the world camera's view\?",
        caplog.text,
    )
    assert caplog.text.count("has sent nothing") == 1


def test_no_capture(caplog: Any) -> None:
    """Nothing answers: without waiting, a clear error at once; waiting, a line per attempt with
    back-off, then the error after `give_up_after_s`."""
    port = _free_port()
    with pytest.raises(
        SourceUnavailableError,
        match=rf"Pupil source unavailable: Pupil Remote at tcp://127\.0\.0\.1:{port} did not "
        r"answer 'v' within 0\.1 s",
    ):
        open_source(f"pupil:127.0.0.1:{port}", timeout_s=0.1)
    caplog.set_level(logging.INFO, LOGGER)
    now = [0]  # the back-off's clock, moved by its sleeps alone

    def sleep(s: float) -> None:
        waits.append(s)
        now[0] += round(s * 1e9)

    waits: list[float] = []
    with pytest.raises(SourceUnavailableError, match=r"no Pupil Capture for 0\.7 s: Pupil"):
        open_source(
            f"pupil:127.0.0.1:{port}/screen",
            wait=True,
            clock=lambda: now[0],
            sleep=sleep,
            timeout_s=0.05,
            backoff_initial_s=0.1,
            give_up_after_s=0.35,
        )
    assert waits == [0.1, 0.2, 0.4]
    assert "Pupil Capture not available (Pupil Remote at" in caplog.text
    with pytest.raises(ValueError, match="the port must be a number"):
        open_source("pupil:127.0.0.1:fifty")


def test_a_server_that_is_not_pupil_remote(capture: Any) -> None:
    """Something on the port answers, but not as Pupil Remote does: said, not retried for ever."""
    fake = capture()
    fake._answer = lambda msg: "Unknown command."  # type: ignore[method-assign]
    with pytest.raises(
        SourceUnavailableError,
        match=re.escape("answered 'SUB_PORT' with 'Unknown command.', not a port"),
    ):
        open_source(fake.spec, **FAST)


MISSING = """
import sys
sys.modules[sys.argv[1]] = None  # as if it were not installed
from gazehdr.drivers.registry import SourceUnavailableError, open_source
try:
    open_source("pupil")
except SourceUnavailableError as e:
    print(e)
"""


@pytest.mark.parametrize("module", ["zmq", "msgpack"])
def test_a_missing_dependency_is_a_clear_error(module: str) -> None:
    run = subprocess.run(
        [sys.executable, "-c", MISSING, module], capture_output=True, text=True, check=True
    )
    assert run.stdout.strip() == (
        "Pupil source unavailable: the Pupil Capture source needs pyzmq and msgpack: install "
        "gazehdr[pupil]"
    )


def test_gazehdr_daemon_follows_pupil_capture_and_the_log_replays(
    capture: Any, live_server: Any, tmp_path: Path
) -> None:
    """`gazehdr daemon --source pupil:127.0.0.1:PORT/screen` into a real server: the server's
    tracker follows the fixations Capture's gaze makes; SIGTERM ends it with its summary; the
    session log holds every datum as a sample, the clock notes and the fixations and blink, and
    replays as a stream and as a track."""
    fake = capture()
    server = live_server(token="t")
    record = tmp_path / "pupil.jsonl"
    argv = ["--source", fake.spec, "--server", server.ws_url, "--token", "t"]
    argv += ["--record", str(record), "--screen", "1280x720"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "gazehdr", "daemon", *argv], stderr=subprocess.PIPE, text=True
    )
    try:
        fake.wait_subscribed(timeout_s=30)

        def follows(x: float, y: float) -> Callable[[], bool]:
            def check() -> bool:
                feeds = server.hub.trackers.feeds()
                assert proc.poll() is None
                if not feeds:
                    return False
                r = sole_tracker(server).reading
                return abs(r.x - x) < 1e-6 and abs(r.y - y) < 1e-6 and r.eyes_open

            return check

        sent = play(fake, [Fixation(0.25, 0.75, 0.5)])
        _wait(follows(0.25, 0.25), "the server following the first fixation")
        sent += play(fake, [Fixation(0.25, 0.75, 0.2, confidence=0.2), Fixation(0.8, 0.3, 0.5)])
        _wait(follows(0.8, 0.7), "the server following the second fixation")
        _wait(lambda: samples_received(server) == len(sent), "every sample at the server")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert f"delivered {len(sent)} samples" in err
    assert sole_tracker(server).name == f"pupil 127.0.0.1:{fake.remote_port}/screen"

    log = read_session_log(record)
    assert log.header.tracker["source"] == "pupil" and log.header.tracker["surface"] == "screen"
    assert (log.header.screen.screen_width_px, log.header.screen.screen_height_px) == (1280, 720)
    assert len(log.samples) == len(sent)
    for sample, datum in zip(log.samples, sent, strict=True):
        assert abs(sample.t_ns - _host_ns(datum, fake)) <= TIME_TOLERANCE_NS
        assert sample.valid == (datum["confidence"] >= 0.6)
    assert log.notes and all(_noted_offset(n) == pytest.approx(5000, abs=1e-3) for n in log.notes)
    starts = [(e.x, e.y) for e in log.events if e.kind == "fixation_start"]
    assert starts[0] == pytest.approx((320, 180), abs=1e-6)
    assert starts[-1] == pytest.approx((1024, 504), abs=1e-6)
    assert [e.kind for e in log.events if e.kind.startswith("blink")] == [
        "blink_start",
        "blink_end",
    ]

    replayed = open_source(f"replay:{record}@max")
    assert [s for s in replayed if isinstance(s, GazeSample)] == log.samples
    track = open_track(str(record))
    first = log.samples[0].t_ns
    mid_a = (_host_ns(sent[0], fake) - first) / 1e9 + 0.3
    mid_b = (_host_ns(sent[-1], fake) - first) / 1e9 - 0.1
    assert track.at(mid_a)[:2] == pytest.approx((0.25, 0.25))
    assert track.at(mid_b)[:2] == pytest.approx((0.8, 0.7))


def _wait(until: Callable[[], bool], what: str, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not until():
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s"
        time.sleep(0.02)


def test_connecting_a_connected_or_closed_source_is_refused(capture: Any) -> None:
    """`connect` only when DISCONNECTED: again while connected would leave the first sockets
    open (a leak), after close would open sockets nothing closes. Guards the state check."""
    from gazehdr.drivers.states import InvalidStateError, Link

    fake = capture()
    source = open_source(fake.spec, **FAST)
    assert source.connection_state is Link.CONNECTED
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state CONNECTED"):
        source.connect()
    source.close()
    assert source.connection_state is Link.CLOSED
    with pytest.raises(InvalidStateError, match=r"connect\(\) in state CLOSED"):
        source.connect()
