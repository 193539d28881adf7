"""The gaze daemon against a real server on loopback (uvicorn in a thread, see conftest.py;
or in a subprocess where the test kills it)."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import math
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import websockets
from conftest import samples_received, sole_tracker

from gazehdr import gaze_link
from gazehdr.drivers import wire
from gazehdr.drivers.daemon import (
    Daemon,
    UnauthorizedError,
    gaze_url,
    open_record_dir,
    run_daemon,
)
from gazehdr.drivers.daemon_cli import daemon_main
from gazehdr.drivers.delivery import ClockEstimator, DaemonStats
from gazehdr.drivers.fixations import detect
from gazehdr.drivers.formats import import_recording
from gazehdr.drivers.formats.bids import write_bids
from gazehdr.drivers.replay import ReplaySource
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.sessionlog import (
    GazeEvent,
    SessionHeader,
    SessionLog,
    SessionLogWriter,
    read_session_log,
    write_session_log,
)
from gazehdr.drivers.sources import IterableSource, SourceInfo, SyntheticSource
from gazehdr.gaze import TrackerFeed
from gazehdr.protocol import decode_frame
from gazehdr.serve import BackgroundServer
from tests.waiting import until

TIMEOUT = 30.0
GEOMETRY = ScreenGeometry()
FORMATS = Path(__file__).parent / "data" / "formats"
REPO = Path(__file__).resolve().parent.parent
#: Positions the server holds are the daemon's pixels over the screen's: exact but for float
#: rounding, so a hundred-millionth of the screen (far below a pixel) is the tolerance.
SCREEN_TOLERANCE = 1e-8


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT))


@pytest.fixture
def received(monkeypatch) -> list[tuple[int, list[int]]]:
    """Every `samples` message any server handles: (id of its hub, sample times), in order."""
    log: list[tuple[int, list[int]]] = []
    original = gaze_link.GazeLink.handle

    def handle(self, msg, now):
        if isinstance(msg, wire.Samples):
            log.append((id(self.hub), [s.t_ns for s in msg.samples]))
        return original(self, msg, now)

    monkeypatch.setattr(gaze_link.GazeLink, "handle", handle)
    return log


def _position(feed: TrackerFeed) -> tuple[float, float]:
    """Where a tracker's gaze is, as fractions of its screen."""
    return (feed.reading.x, feed.reading.y)


@pytest.fixture
def followed(monkeypatch) -> list[tuple[wire.Message, float, float]]:
    """Every message any server handles, with where its remote gaze is once it has."""
    log: list[tuple[wire.Message, float, float]] = []
    original = gaze_link.GazeLink.handle

    def handle(self, msg, now):
        reply = original(self, msg, now)
        log.append((msg, *_position(self.feed)))
        return reply

    monkeypatch.setattr(gaze_link.GazeLink, "handle", handle)
    return log


def _write_log(path: Path, samples: list[GazeSample], geometry: ScreenGeometry = GEOMETRY) -> Path:
    with SessionLogWriter(path, SessionHeader({"name": "recorded rig"}, geometry)) as w:
        w.write_all(samples)
    return path


def test_gaze_url_and_clock_estimator() -> None:
    assert gaze_url("ws://h:1") == "ws://h:1/ws/gaze"
    assert gaze_url("http://h:1/") == "ws://h:1/ws/gaze"
    assert gaze_url("h:1") == "ws://h:1/ws/gaze"
    assert gaze_url("wss://h/custom") == "wss://h/custom"
    with pytest.raises(ValueError):
        gaze_url("ftp://h")
    est = ClockEstimator(window=3)
    est.add(0, 1_000_500, 1_000)  # rtt 1000: offset 1_000_000 ± 500
    assert est.best.offset_ns == 1_000_000 and est.best.uncertainty_ns == 500
    est.add(10_000, 1_011_000, 14_000)  # rtt 4000: worse, ignored
    assert est.best.rtt_ns == 1_000
    est.add(20_000, 1_020_150, 20_200)
    est.add(30_000, 1_030_100, 30_200)  # the rtt-1000 estimate slid out of the window
    assert est.best.rtt_ns == 200 and est.best.offset_ns == 1_000_050


def test_samples_arrive_in_order_and_are_recorded(live_server, received, tmp_path) -> None:
    server = live_server(token="t")
    record = tmp_path / "rec.jsonl"
    source = SyntheticSource(2, 500.0, duration=1.5)  # real time
    stats = run(run_daemon(source, server.ws_url, "t", record=record))

    produced = stats.samples_produced
    assert produced == 751 and stats.samples_delivered == produced
    assert stats.samples_dropped == stats.samples_undelivered == 0
    assert sole_tracker(server).samples == produced
    assert sole_tracker(server).name == "synthetic (seed 2)"
    times = [t for _, batch in received for t in batch]
    recorded = read_session_log(record)
    assert times == [s.t_ns for s in recorded.samples]  # all, once, in order
    assert all(len(batch) <= 50 for _, batch in received)
    # the server follows the last fixation start or update the daemon sent
    follows = ("fixation_start", "fixation_update")
    last_fix = [e for e in recorded.events if e.kind in follows][-1]
    reading = sole_tracker(server).reading
    assert reading.x == pytest.approx(last_fix.x / GEOMETRY.screen_width_px)
    assert reading.y == pytest.approx(last_fix.y / GEOMETRY.screen_height_px)
    assert stats.events_delivered == stats.events_produced == len(recorded.events) > 0
    # one process, one monotonic clock: the offset is 0 within its uncertainty
    assert stats.clock is not None and stats.clock.uncertainty_ns < 50_000_000
    assert abs(stats.clock.offset_ns) <= stats.clock.uncertainty_ns + 1_000
    assert recorded.clocks and recorded.header.clock.source == "monotonic_ns"
    assert server.metrics.gaze_rate_limited.value == 0


def _scripted(rate_hz: float = 500.0) -> list[GazeSample]:
    """Fixate A for 400 ms, a 40 ms saccade to B, fixate B for 500 ms; screen pixels."""
    w, h = GEOMETRY.screen_width_px, GEOMETRY.screen_height_px
    a, b = (0.25 * w, 0.25 * h), (0.75 * w, 0.7 * h)
    out = []
    for i in range(int(0.94 * rate_hz)):
        t = i / rate_hz
        k = min(max((t - 0.4) / 0.04, 0.0), 1.0)
        out.append(GazeSample(round(t * 1e9), a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1])))
    return out


def test_a_remote_session_follows_the_daemons_fixations(live_server) -> None:
    server = live_server(token="t", gaze_source="remote", fps=30.0)
    info = SourceInfo("scripted rig", GEOMETRY, 500.0, live=True)
    source = IterableSource(_scripted(), info, speed=1.0)

    async def check() -> list[tuple[float, float, bool]]:
        seen: list[tuple[float, float, bool]] = []
        async with websockets.connect(
            server.ws_url + "/ws/view", additional_headers=server.auth
        ) as view:

            async def watch() -> None:
                async for message in view:
                    if isinstance(message, bytes):
                        header, _ = decode_frame(message)
                        seen.append((header.gaze_x, header.gaze_y, header.tracker))

            watcher = asyncio.create_task(watch())
            await until(lambda: len(seen) > 2, what="first frames")
            stats = await run_daemon(source, server.ws_url, "t")
            assert stats.events_delivered > 0
            done = len(seen)  # the frames from here on show where the daemon left the gaze
            await until(
                lambda: len(seen) > done and near(seen[-1][:2], targets[2]),
                what="a frame at the last fixation",
            )
            watcher.cancel()
        return seen

    targets = [(0.5, 0.5), (0.25, 0.25), (0.75, 0.7)]  # start, fixation A, fixation B

    def near(p, q) -> bool:
        return math.dist(p, q) < 0.02

    seen = run(check())
    assert all(tracker for *_, tracker in seen)
    # only fixation positions, never a point along the saccade
    assert all(any(near((x, y), q) for q in targets) for x, y, _ in seen), seen
    assert any(near((x, y), targets[1]) for x, y, _ in seen)
    assert near(seen[-1][:2], targets[2])


def _second_server(live_server, listener: socket.socket, tmp_path: Path) -> BackgroundServer:
    """A server started where one was stopped or killed (`listener`), as after a crash."""
    return live_server(token="t", data_dir=tmp_path / "data2", sock=listener)


OUTAGE_BOUND = 300  # items the daemon keeps through a server outage: less than it lasts


def _outage_daemon(url: str, record: Path) -> Daemon:
    """A live, endless 1000 Hz source behind a buffer that an outage overflows. Draining what
    it holds at the end takes well under a second; the drain timeout is only a safety net."""
    return Daemon(
        SyntheticSource(4, 1000.0),
        url,
        "t",
        record=record,
        buffer=OUTAGE_BOUND,
        backoff=(0.05, 0.2),
        drain_timeout=20.0,
    )


async def _through_an_outage(daemon: Daemon, take_down, bring_up) -> DaemonStats:
    """Run `daemon` until it has delivered, `take_down()` its server, go on past what the
    buffer keeps, `bring_up()` a server on the same port, and stop once it delivers to it."""
    task = asyncio.create_task(daemon.run())
    await until(lambda: daemon.stats.samples_delivered >= 300, what="first deliveries")
    await take_down()
    await until(lambda: not daemon.connected, what="the daemon to notice")
    await until(lambda: daemon.stats.samples_dropped > 0, what="more than the buffer keeps")
    assert daemon.backlog <= OUTAGE_BOUND + daemon.max_inflight
    await bring_up()
    await until(lambda: daemon.stats.connects == 2, what="the reconnect")
    delivered = daemon.stats.samples_delivered
    await until(lambda: daemon.stats.samples_delivered > delivered, what="deliveries again")
    daemon.stop()
    return await task


def test_restarted_server_gets_everything_the_buffer_kept(
    live_server, listener, received, tmp_path
):
    first = live_server(token="t", sock=listener)
    record = tmp_path / "rec.jsonl"
    daemon = _outage_daemon(first.ws_url, record)
    second: list[BackgroundServer] = []

    async def restart() -> None:
        second.append(await asyncio.to_thread(_second_server, live_server, listener, tmp_path))

    stats = run(_through_an_outage(daemon, lambda: asyncio.to_thread(first.stop), restart))
    (restarted,) = second
    hubs = {id(first.hub): [], id(restarted.hub): []}
    for hub, batch in received:
        hubs[hub].extend(batch)
    _nothing_lost_but_counted(
        read_session_log(record), stats, hubs[id(first.hub)], hubs[id(restarted.hub)]
    )
    assert sole_tracker(restarted).samples > 0
    assert first.metrics.gaze_rate_limited.value == restarted.metrics.gaze_rate_limited.value == 0


def _nothing_lost_but_counted(
    recorded: SessionLog, stats, first: list[int], second: list[int]
) -> None:
    """What a server restart must leave: the sample times each server handled, in order,
    together hold every sample the source gave except the ones counted dropped."""
    produced = [s.t_ns for s in recorded.samples]
    # the local recording has everything the source gave
    assert len(produced) == stats.samples_produced == stats.samples_recorded
    assert len(recorded.events) == stats.events_produced == stats.events_recorded
    # each server saw its samples in order
    for times in (first, second):
        assert times == sorted(times) and len(set(times)) == len(times)
    # nothing lost but what the bound dropped, and that exactly as counted
    arrived = set(first) | set(second)
    missing = [t for t in produced if t not in arrived]
    assert len(missing) == stats.samples_dropped > 0
    assert stats.samples_undelivered == 0
    assert stats.samples_delivered + stats.samples_dropped == stats.samples_produced
    # the oldest were dropped, in one run: the gap lies between the two servers' streams, and
    # everything after it (what the buffer kept, and what came later) reached the second
    gap = produced.index(missing[0])
    assert produced[gap : gap + len(missing)] == missing
    assert max(first) < min(missing) and set(produced[gap + len(missing) :]) <= set(second)
    resent = set(first) & set(second)
    assert len(resent) <= stats.resent  # at least once: only unacknowledged ones twice
    assert stats.connects == 2 and stats.server_rate_limited == {}
    assert any("dropped" in n.text for n in recorded.notes)


def test_a_connection_lost_before_its_welcome_is_tried_again() -> None:
    """A server that closes the first connection on its hello, then welcomes the next: the
    daemon says hello again and delivers everything, and the unwelcomed one is neither a
    connection nor a disconnect. Guards the daemon telling its core of a connection lost
    before the welcome (mutation: `connection_lost` only once welcomed; the core then refuses
    the next hello, InvalidStateError)."""
    from websockets.asyncio.server import serve

    hellos: list[wire.Hello] = []
    arrived: list[int] = []

    async def handler(ws) -> None:
        hellos.append(wire.parse(await ws.recv()))
        if len(hellos) == 1:
            await ws.close()
            return
        await ws.send(wire.dumps(wire.Welcome(wire.PROTOCOL)))
        async for text in ws:
            message = wire.parse(text)
            if isinstance(message, wire.Samples):
                arrived.extend(s.t_ns for s in message.samples)
            elif isinstance(message, wire.Echo):
                reply = wire.EchoReply(message.t0_ns, time.monotonic_ns())
                await ws.send(wire.dumps(reply))

    samples = [GazeSample(i * 1_000_000, 960.0, 540.0) for i in range(300)]
    source = IterableSource(samples, SourceInfo("rig", GEOMETRY, live=False))

    async def scenario() -> DaemonStats:
        async with serve(handler, "127.0.0.1", 0) as server:
            port = server.sockets[0].getsockname()[1]
            daemon = Daemon(source, f"ws://127.0.0.1:{port}", "t", backoff=(0.01, 0.05))
            return await daemon.run()

    stats = run(scenario())
    assert [type(h) for h in hellos] == [wire.Hello, wire.Hello]
    assert arrived == [s.t_ns for s in samples]
    assert (stats.connects, stats.disconnects, stats.resent) == (1, 1, 0)  # the welcomed one
    assert stats.samples_delivered == 300 and stats.samples_undelivered == 0


def test_a_wrong_token_is_fatal_and_clear(live_server, capsys, monkeypatch, caplog) -> None:
    server = live_server(token="right")
    source = SyntheticSource(0, 100.0)
    with (
        caplog.at_level(logging.INFO, logger="gazehdr.daemon"),
        pytest.raises(UnauthorizedError, match="refused the token"),
    ):
        run(run_daemon(source, server.ws_url, "wrong", backoff=(0.05, 0.1)))
    # fatal at the first refusal: no retry
    assert [r.getMessage() for r in caplog.records if "retrying" in r.getMessage()] == []
    code = daemon_main(["--source", "synthetic", "--server", server.ws_url, "--token", "nope"])
    assert code == 2
    err = capsys.readouterr().err
    assert "gazehdr daemon: error: the server at" in err and "refused the token" in err
    assert "wrong bearer token" in err
    monkeypatch.setenv("GAZEHDR_SERVER", server.ws_url)
    monkeypatch.setenv("GAZEHDR_TOKEN", "still wrong")
    assert daemon_main(["--source", "synthetic:1"]) == 2
    monkeypatch.delenv("GAZEHDR_TOKEN")
    with pytest.raises(SystemExit):
        daemon_main(["--source", "synthetic"])
    assert "--token" in capsys.readouterr().err


def test_cli_replays_a_log_to_the_server(live_server, tmp_path, capsys) -> None:
    server = live_server(token="t")
    samples = list(SyntheticSource(9, 250.0, duration=2.0, realtime=False, start_ns=0))
    log = _write_log(tmp_path / "in.jsonl", samples)
    out = tmp_path / "out.jsonl"
    argv = ["--source", f"replay:{log}@max", "--server", server.ws_url, "--token", "t"]
    assert daemon_main([*argv, "--record", str(out), "--detector", "idt", "-q"]) == 0
    assert sole_tracker(server).samples == len(samples) == 501
    assert read_session_log(out).samples == samples  # the replay emitted what was recorded
    assert "delivered 501 samples" in capsys.readouterr().err


def test_what_the_servers_limits_drop_is_counted(live_server, tmp_path, monkeypatch) -> None:
    """A server whose sample limit is below the daemon's pace drops samples and says so; the
    daemon adds up what its notes report (the drops since the last note, at most one a second),
    so it never counts more than the server dropped, and names it in its summary."""
    monkeypatch.setattr(gaze_link, "SAMPLE_LIMIT", gaze_link.GazeLimit("samples", 200.0, 200.0))
    server = live_server(token="t")
    samples = list(SyntheticSource(3, 1000.0, duration=2.5, realtime=False, start_ns=0))
    source = ReplaySource(_write_log(tmp_path / "fast.jsonl", samples), speed=math.inf)
    stats = run(run_daemon(source, server.ws_url, "t"))
    dropped = server.metrics.gaze_rate_limited.value
    assert dropped > 0 and 0 < stats.server_rate_limited["samples"] <= dropped
    assert set(stats.server_rate_limited) == {"samples"}
    assert f"the server's rate limits dropped {stats.server_rate_limited['samples']} samples" in (
        stats.summary()
    )


def test_a_flood_is_paced_below_the_limit_without_harming_a_viewer(live_server, tmp_path):
    server = live_server(token="t", gaze_source="remote")
    samples = list(SyntheticSource(3, 1000.0, duration=4.0, realtime=False, start_ns=0))
    log = _write_log(tmp_path / "flood.jsonl", samples)
    source = ReplaySource(log, speed=math.inf)  # as fast as it can be read: a flood

    async def check():
        async with websockets.connect(
            server.ws_url + "/ws/view", additional_headers=server.auth
        ) as view:
            frames: list[int] = []

            async def watch() -> None:
                async for message in view:
                    if isinstance(message, bytes):
                        frames.append(decode_frame(message)[0].frame)

            watcher = asyncio.create_task(watch())
            await until(lambda: frames, what="a first frame")
            (live,) = server.hub.sessions.values()
            since, started = live.session.frame, time.monotonic()
            stats = await run_daemon(source, server.ws_url, "t")
            elapsed = time.monotonic() - started
            during = [f for f in frames if f >= since]  # made and received during the flood
            watcher.cancel()
            return stats, started, elapsed, during

    stats, started, elapsed, during = run(check())
    n = len(samples)
    assert sole_tracker(server).samples == stats.samples_delivered == n  # a replay waits, no loss
    assert server.metrics.gaze_rate_limited.value == 0 and stats.server_rate_limited == {}
    # Pacing is wall time by nature: only a lower bound, which a slow machine cannot break (it
    # only takes longer). Paced: never faster than the server's limit.
    assert elapsed >= (n - 1000) / 2000
    # Within any second: at most the daemon's burst + rate (1000 + 1900 samples). Each batch
    # is stamped once sent and takes its tokens after the one before it was sent (or the run
    # began), so the batches stamped within a second of one took theirs over that second and
    # the gap before it; nothing here depends on how fast the machine is.
    sent = list(stats.sent_times)
    for i, (t, _) in enumerate(sent):
        took_from = sent[i - 1][0] if i else started
        in_window = sum(k for u, k in sent[i:] if u - t < 1.0)
        assert in_window <= 1000 + 1900 * (t + 1.0 - took_from), (i, in_window)
    # the viewer's session went on during the flood: its frames kept coming, in order
    assert len(during) >= 3 and during == sorted(set(during)), during


def test_times_the_wire_cannot_carry_are_not_sent_nor_counted_delivered(
    live_server, received, tmp_path
) -> None:
    """An imported log may start before 0 (BIDS StartTime < 0). The server refuses a batch with
    a negative `t`, yet the next echo acknowledges it: such samples must never be sent."""
    server = live_server(token="t")
    samples = [GazeSample((i - 30) * 4_000_000, 960.0 + i, 540.0) for i in range(100)]
    log = _write_log(tmp_path / "early.jsonl", samples)
    stats = run(run_daemon(ReplaySource(log, speed=math.inf), server.ws_url, "t", detector=None))
    sendable = [s.t_ns for s in samples if s.t_ns >= 0]
    assert [t for _, batch in received for t in batch] == sendable  # every one, in order
    assert sole_tracker(server).samples == stats.samples_delivered == len(sendable) == 70
    assert stats.samples_unsendable == 30 and stats.samples_undelivered == 0
    assert "30 samples, 0 events not sendable" in stats.summary()


def test_a_reconnect_forgets_the_old_servers_clock(
    live_server, listener, monkeypatch, tmp_path
) -> None:
    """A rebooted server has another monotonic clock: echoes of the old one must not stand in
    for it, even those with a smaller round trip."""
    shift = 5_000_000_000
    first = live_server(token="t", sock=listener)
    original = gaze_link.GazeLink.handle
    delay_s = [0.0]  # how much slower the restarted server answers echoes

    def handle(self, msg, now):  # the restarted server: its clock 5 s ahead, echoes slower
        reply = original(self, msg, now)
        if isinstance(msg, wire.Echo) and self.hub is not first.hub:
            time.sleep(delay_s[0])
            return wire.EchoReply(reply.t0_ns, reply.server_ns + shift)
        return reply

    monkeypatch.setattr(gaze_link.GazeLink, "handle", handle)
    record = tmp_path / "rec.jsonl"
    daemon = Daemon(
        SyntheticSource(5, 500.0),
        first.ws_url,
        "t",
        record=record,
        backoff=(0.05, 0.2),
        drain_timeout=20.0,
        clock_window=100_000,  # nothing slides out during the test: only a reset can help
    )

    def recorded_the_new_clock() -> bool:
        clocks = read_session_log(record).clocks
        return bool(clocks) and abs(clocks[-1].offset_ns - shift) < shift / 2

    async def scenario():
        task = asyncio.create_task(daemon.run())
        await until(lambda: daemon.stats.samples_delivered >= 200, what="first deliveries")
        await asyncio.to_thread(first.stop)
        await until(lambda: not daemon.connected, what="the daemon to notice")
        before = daemon.stats.clock  # the old server's best: its last echo has come back
        # Every echo of the restarted server takes longer than the old server's best did.
        delay_s[0] = 2 * before.rtt_ns / 1e9 + 0.01
        await asyncio.to_thread(_second_server, live_server, listener, tmp_path)
        await until(lambda: daemon.stats.connects == 2, what="the reconnect")
        await until(lambda: daemon.stats.clock.offset_ns > shift / 2, what="the new clock")
        await until(recorded_the_new_clock, what="a clock record of the new server")
        daemon.stop()
        return before, await task

    before, stats = run(scenario())
    assert abs(before.offset_ns) <= before.uncertainty_ns + 1_000  # one host, one clock
    after = stats.clock
    assert after.rtt_ns >= delay_s[0] * 1e9 > before.rtt_ns
    assert abs(after.offset_ns - shift) <= after.uncertainty_ns + 1_000
    clocks = read_session_log(record).clocks
    assert abs(clocks[0].offset_ns) < shift / 2 and abs(clocks[-1].offset_ns - shift) < shift / 2


# --- a server killed outright ------------------------------------------------------------------

#: A gazehdr server (the project's app factory under uvicorn) on a listening socket it is handed
#: (by descriptor) that writes down the sample times of every batch it handles, flushed before
#: the batch is acknowledged: a SIGKILL loses none of what it handled.
KILLABLE_SERVER = """
import socket
import sys
from pathlib import Path

from gazehdr.drivers import wire
from gazehdr import gaze_link
from gazehdr.app import ServerConfig, create_app
from gazehdr.serve import uvicorn_server
from gazehdr.session import SessionSettings

fd, seen, data = int(sys.argv[1]), open(sys.argv[2], "a"), Path(sys.argv[3])
handle = gaze_link.GazeLink.handle


def writing(self, msg, now):
    reply = handle(self, msg, now)
    if isinstance(msg, wire.Samples):
        seen.write(" ".join(str(s.t_ns) for s in msg.samples) + "\\n")
        seen.flush()
    return reply


gaze_link.GazeLink.handle = writing
settings = SessionSettings(width=160, height=96, fps=20.0)
config = ServerConfig(token="t", session=settings, data_dir=data, session_grace_s=0.0)
sock = socket.socket(fileno=fd)
uvicorn_server(create_app(config), "127.0.0.1", 0, log_level="warning").run(sockets=[sock])
"""


class KillableServer:
    """`KILLABLE_SERVER` in a subprocess on `listener` (the test keeps it open), up once it
    answers there. Connections made before that wait in the listener's backlog, so a request
    that times out (asked again) or a process that dies are what tell it did not start."""

    def __init__(self, script: Path, listener: socket.socket, name: str) -> None:
        self.seen = script.parent / f"{name}.txt"
        fd = listener.fileno()
        self.proc = subprocess.Popen(
            [sys.executable, str(script), str(fd), str(self.seen), str(script.parent / name)],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            pass_fds=[fd],
        )
        health = f"http://127.0.0.1:{listener.getsockname()[1]}/api/health"
        deadline = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(health, timeout=1).close()
                return
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.proc.kill()
                    err = self.proc.stderr.read()
                    raise AssertionError(f"server did not start: {err!r}") from None

    def hang(self) -> None:
        self.proc.send_signal(signal.SIGSTOP)  # reads nothing, answers nothing, closes nothing

    def kill(self) -> None:
        self.proc.kill()  # SIGKILL: no close frame, no shutdown; the kernel drops the socket
        self.proc.wait(timeout=10)

    def times(self) -> list[int]:
        return [int(t) for line in self.seen.read_text().splitlines() for t in line.split()]


def test_a_server_killed_outright_loses_nothing_the_buffer_kept(listener, tmp_path) -> None:
    """A server that hangs (SIGSTOP: what the daemon sends meanwhile is never acknowledged)
    and is then SIGKILLed mid-stream, then a new server on the same port: what was sent but
    not acknowledged is sent again, what the bound kept arrives, and exactly what it dropped is
    missing and counted."""
    script = tmp_path / "killable_server.py"  # not server.py: that would hide the package
    script.write_text(KILLABLE_SERVER)
    servers = [KillableServer(script, listener, "first")]
    record = tmp_path / "rec.jsonl"
    daemon = _outage_daemon(f"ws://127.0.0.1:{listener.getsockname()[1]}", record)

    async def hang_then_kill() -> None:
        servers[0].hang()
        sent = daemon.stats.samples_sent
        # samples sent to it that it can never acknowledge
        await until(lambda: daemon.stats.samples_sent >= sent + 100, what="sends to the hung")
        await asyncio.to_thread(servers[0].kill)

    async def restart() -> None:
        servers.append(await asyncio.to_thread(KillableServer, script, listener, "second"))

    try:
        stats = run(_through_an_outage(daemon, hang_then_kill, restart))
    finally:
        for server in servers:
            if server.proc.poll() is None:
                server.kill()
    first, second = (server.times() for server in servers)
    assert stats.disconnects == 2 and stats.resent >= 100
    _nothing_lost_but_counted(read_session_log(record), stats, first, second)


# --- recordings whose fixation starts have no position ----------------------------------------


def _bids_export(tmp_path: Path) -> Path:
    """The EyeLink fixture as BIDS physio: fixation positions on the physioevents rows, which
    import as a fixation end with the mean and a start without one."""
    log = import_recording(FORMATS / "eyelink_mono.asc")
    written = write_bids(log, tmp_path / "bids")
    return next(p for p in written if p.name.endswith("_physio.tsv.gz"))


@pytest.mark.parametrize("recording", ["eyelink", "bids", "imported log"])
def test_a_replayed_recording_is_followed_fixation_by_fixation(
    live_server, followed, tmp_path, recording
) -> None:
    """EyeLink's SFIX and a BIDS fixation onset carry no position, the fixation's end has its
    mean; so does the log `gazehdr import` writes of them. From each fixation's start until the
    next one's, the server must hold that mean, whatever the samples in between do (a saccade,
    a blink, another recording block)."""
    path = {
        "eyelink": lambda: FORMATS / "eyelink_mono.asc",
        "bids": lambda: _bids_export(tmp_path),
        "imported log": lambda: write_session_log(
            tmp_path / "s01.jsonl", import_recording(FORMATS / "eyelink_mono.asc")
        ),
    }[recording]()
    log = read_session_log(path) if path.suffix == ".jsonl" else import_recording(path)
    w, h = log.header.screen.screen_width_px, log.header.screen.screen_height_px
    means = {e.id: (e.x / w, e.y / h) for e in log.events if e.kind == "fixation_end"}
    starts = [e for e in log.events if e.kind == "fixation_start"]
    assert len(means) == len(starts) == 3 and not any(math.isfinite(e.x) for e in starts)
    server = live_server(token="t")

    stats = run(run_daemon(ReplaySource(path, speed=math.inf), server.ws_url, "t"))
    assert stats.events_unsendable == stats.samples_unsendable == 0
    assert stats.events_delivered == stats.events_produced == len(log.events)
    assert stats.samples_delivered == len(log.samples)
    handled = [
        m.id for m, *_ in followed if isinstance(m, wire.Event) and m.kind == "fixation_start"
    ]
    assert handled == sorted(means)  # each fixation once, in order
    held = None
    for msg, x, y in followed:
        if isinstance(msg, wire.Event) and msg.kind == "fixation_start":
            held = means[msg.id]
        if held is not None:  # from the first fixation on, only fixations move the gaze
            assert math.dist((x, y), held) < SCREEN_TOLERANCE, (msg, (x, y), held)
    assert math.dist(_position(sole_tracker(server)), means[3]) < SCREEN_TOLERANCE


def test_a_binocular_recording_is_followed_by_one_eye(live_server, followed) -> None:
    """Both eyes fixate at slightly different places; the server follows the first eye that
    fixates, as a render of the recording does (`fixation_track`); the other eye's fixations
    are recorded, not sent."""
    path = FORMATS / "eyelink_bino.asc"
    log = import_recording(path)
    starts = [e for e in log.events if e.kind == "fixation_start"]
    assert {e.eye for e in starts} == {"left", "right"}
    first = starts[0].eye
    server = live_server(token="t")
    stats = run(run_daemon(ReplaySource(path, speed=math.inf), server.ws_url, "t"))
    sent = [m for m, *_ in followed if isinstance(m, wire.Event)]
    own = [e for e in log.events if e.eye == first]
    assert [(m.kind, m.id) for m in sent] == [(e.kind, e.id) for e in own]
    assert stats.events_delivered == len(own) and stats.events_unsendable == 0
    w, h = log.header.screen.screen_width_px, log.header.screen.screen_height_px
    end = next(e for e in own if e.kind == "fixation_end")
    assert math.dist(_position(sole_tracker(server)), (end.x / w, end.y / h)) < (SCREEN_TOLERANCE)
    assert log.fixation_track().at(0.002)[:2] == pytest.approx((end.x / w, end.y / h))


@pytest.mark.parametrize("own", ["fixations without positions", "only blinks"])
def test_a_recording_whose_events_place_no_fixation_is_run_through_the_detector(
    live_server, followed, tmp_path, own
) -> None:
    """BIDS physioevents without coordinates, or a recording with blinks only: the server could
    follow none of its events (a blink would even stop it following samples), so the daemon's
    detector finds the fixations; the recording's own events are recorded as they were, and
    not sent."""
    ms = 1_000_000
    samples = _scripted()  # A for 400 ms, a saccade, B for 500 ms
    events = (
        [
            GazeEvent("fixation_start", 1, 0, eye="left"),
            GazeEvent("fixation_end", 1, 398 * ms, duration_ns=398 * ms, eye="left"),
            GazeEvent("fixation_start", 2, 440 * ms, eye="left"),
            GazeEvent("fixation_end", 2, 938 * ms, duration_ns=498 * ms, eye="left"),
        ]
        if own == "fixations without positions"
        else [GazeEvent("blink_start", 1, 100 * ms), GazeEvent("blink_end", 1, 180 * ms)]
    )
    path = tmp_path / "rec.jsonl"
    write_session_log(path, SessionLog(SessionHeader({"name": "rig"}, GEOMETRY), samples, events))
    out = tmp_path / "out.jsonl"
    server = live_server(token="t")

    stats = run(run_daemon(ReplaySource(path, speed=math.inf), server.ws_url, "t", record=out))
    detected = detect(samples, "ivt", GEOMETRY)
    assert [e.kind for e in detected if e.kind != "fixation_update"] == [
        "fixation_start",
        "fixation_end",
    ] * 2  # A, then B
    sent = [m for m, *_ in followed if isinstance(m, wire.Event)]
    assert [(m.kind, m.id, m.t_ns) for m in sent] == [(e.kind, e.id, e.t_ns) for e in detected]
    assert stats.events_unsendable == 0 and stats.events_delivered == len(detected)
    b = next(e for e in detected if e.kind == "fixation_end" and e.id == 2)
    final = _position(sole_tracker(server))
    assert math.dist(final, (b.x / GEOMETRY.screen_width_px, b.y / GEOMETRY.screen_height_px)) < (
        SCREEN_TOLERANCE
    )
    recorded = read_session_log(out)
    assert recorded.samples == samples and recorded.events == events  # the source's, exactly
    assert stats.events_recorded == len(events)


# --- recording for long-running daemons --------------------------------------------------------


def test_record_dir_writes_a_new_file_each_run_and_never_overwrites(
    live_server, tmp_path, monkeypatch, capsys
) -> None:
    at = datetime(2024, 5, 1, 14, 30, 5, tzinfo=timezone.utc)
    folder = tmp_path / "made" / "here"
    names = []
    for _ in range(3):
        with open_record_dir(folder, SessionHeader(), at) as writer:
            writer.note(1, f"run {len(names)}")
            names.append(writer.path.name)
    assert names == [
        "gaze-20240501T143005Z.jsonl",
        "gaze-20240501T143005Z-2.jsonl",
        "gaze-20240501T143005Z-3.jsonl",
    ]
    assert [read_session_log(folder / n).notes[0].text for n in names] == [
        "run 0",
        "run 1",
        "run 2",
    ]
    paris = timezone(timedelta(hours=2))
    with open_record_dir(folder, SessionHeader(), at.astimezone(paris)) as writer:
        assert writer.path.name == "gaze-20240501T143005Z-4.jsonl"  # stamped in UTC

    server = live_server(token="t")
    samples = list(SyntheticSource(9, 250.0, duration=1.0, realtime=False, start_ns=0))
    log = _write_log(tmp_path / "in.jsonl", samples)
    argv = ["--source", f"replay:{log}@max", "--server", server.ws_url, "--token", "t", "-q"]
    env_dir = tmp_path / "env"
    monkeypatch.setenv("GAZEHDR_RECORD_DIR", str(env_dir))
    assert daemon_main(argv) == 0  # a container's first run ...
    assert daemon_main(argv) == 0  # ... and its restart
    files = sorted(env_dir.iterdir())
    assert len(files) == 2
    assert all(re.fullmatch(r"gaze-\d{8}T\d{6}Z(-2)?\.jsonl", f.name) for f in files)
    assert all(read_session_log(f).samples == samples for f in files)
    err = capsys.readouterr().err
    assert all(
        re.search(rf"recorded 251 samples, \d+ events to {re.escape(str(f))}", err) for f in files
    )
    # --record names the one file: the environment's directory is not used
    assert daemon_main([*argv, "--record", str(tmp_path / "one.jsonl")]) == 0
    assert len(list(env_dir.iterdir())) == 2 and (tmp_path / "one.jsonl").is_file()
    with pytest.raises(SystemExit) as stopped:
        daemon_main([*argv, "--record", "a.jsonl", "--record-dir", str(tmp_path / "d")])
    assert stopped.value.code == 2
    assert "argument --record-dir: not allowed with argument --record" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


# --- stopping on SIGTERM, and the screen flags ---------------------------------------------------


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_a_signal_stops_the_daemon_cleanly_and_the_screen_flags_reach_hello_and_detector(
    live_server, followed, tmp_path, signum, code
) -> None:
    """`docker stop` sends SIGTERM, a terminal Ctrl-C: the daemon delivers what it holds,
    closes its log, prints its summary, and exits 0 (stopped on request) or 130 (interrupted).
    --screen, --diagonal and --distance set the screen of the hello, of the log header, and of
    the detector's degrees."""
    server = live_server(token="t")
    geometry = ScreenGeometry(0.43, 1280, 1024, 0.55)
    flags = ["--screen", "1280x1024", "--diagonal", "0.43", "--distance", "0.55"]
    gazehdr = Path(sys.executable).with_name("gazehdr")
    command = [str(gazehdr), "daemon", "--source", "synthetic:3", "--rate", "500"]
    command += ["--server", server.ws_url, "--token", "t", "--record-dir", str(tmp_path / "rec")]
    proc = subprocess.Popen([*command, *flags], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20
        while samples_received(server) < 500:  # a second of gaze
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.02)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert f"gazehdr daemon: {signal.Signals(signum).name}: stopping" in err
    (record,) = (tmp_path / "rec").iterdir()
    log = read_session_log(record)
    assert not log.truncated and log.header.screen == geometry
    n, k = len(log.samples), len(log.events)
    assert n >= 500 and sole_tracker(server).samples == n
    assert (
        f"{n} samples, {k} events from the source; delivered {n} samples, {k} events; "
        f"dropped 0 samples, 0 events (buffer full)"
    ) in err
    assert f"recorded {n} samples, {k} events to {record}" in err
    hellos = [m for m, *_ in followed if isinstance(m, wire.Hello)]
    assert [h.screen for h in hellos] == [
        {name: float(v) for name, v in dataclasses.asdict(geometry).items()}
    ]

    def fields(events) -> list[tuple]:
        return [(e.kind, e.id, e.t_ns, e.x, e.y, e.duration_ns, e.dispersion_deg) for e in events]

    # the daemon's I-VT measured degrees on the flags' screen: offline I-VT on that screen
    # gives its very events; on the default screen's size and distance, other ones
    assert fields(log.events) == fields(detect(log.samples, "ivt", geometry)) != []
    default = ScreenGeometry(screen_width_px=1280, screen_height_px=1024)
    assert fields(log.events) != fields(detect(log.samples, "ivt", default))


def test_screen_flags_fill_in_only_what_a_recording_does_not_record(
    live_server, tmp_path, capsys
) -> None:
    server = live_server(token="t")
    base = ["--server", server.ws_url, "--token", "t", "--screen", "1280x1024"]
    pupil = FORMATS / "gaze_positions.csv"  # normalised positions, no screen of its own
    out = tmp_path / "pupil.jsonl"
    assert daemon_main([*base, "--source", f"replay:{pupil}@max", "--record", str(out)]) == 0
    header = read_session_log(out).header
    assert header.screen == ScreenGeometry(screen_width_px=1280, screen_height_px=1024)
    assert "own screen geometry" not in capsys.readouterr().err

    native = _write_log(tmp_path / "native.jsonl", _scripted())  # its header: 1920 × 1080
    out = tmp_path / "native-out.jsonl"
    assert daemon_main([*base, "--source", f"replay:{native}@max", "--record", str(out)]) == 0
    assert read_session_log(out).header.screen == GEOMETRY
    assert (
        "gazehdr daemon: the recording's own screen geometry is used (screen_width_px 1920, "
        "screen_height_px 1080)"
    ) in capsys.readouterr().err

    with pytest.raises(SystemExit) as stopped:
        daemon_main([*base[:-1], "0x1080"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "--screen: geometry screen_width_px must be a finite positive number, got 0" in err
