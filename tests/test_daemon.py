"""The gaze daemon against a real server on loopback (uvicorn in a thread, see conftest.py)."""

from __future__ import annotations

import asyncio
import math
import threading
import time
from pathlib import Path

import pytest
import websockets

from drivers import wire
from drivers.daemon import (
    ClockEstimator,
    Daemon,
    UnauthorizedError,
    daemon_main,
    gaze_url,
    run_daemon,
)
from drivers.replay import ReplaySource
from drivers.samples import GazeSample, ScreenGeometry
from drivers.sessionlog import SessionHeader, SessionLogWriter, read_session_log
from drivers.sources import IterableSource, SourceInfo, SyntheticSource
from server import app as app_module
from server.app import ServerConfig, create_app
from server.protocol import decode_frame
from server.serve import uvicorn_server
from server.session import SessionSettings

TIMEOUT = 30.0
GEOMETRY = ScreenGeometry()


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT))


@pytest.fixture
def received(monkeypatch) -> list[tuple[int, list[int]]]:
    """Every `samples` message any server handles: (id of its hub, sample times), in order."""
    log: list[tuple[int, list[int]]] = []
    original = app_module._GazeLink.handle

    def handle(self, msg, now):
        if isinstance(msg, wire.Samples):
            log.append((id(self.hub), [s.t_ns for s in msg.samples]))
        return original(self, msg, now)

    monkeypatch.setattr(app_module._GazeLink, "handle", handle)
    return log


class ServerOnPort:
    """Like `BackgroundServer`, on a given port: a server restarted where the daemon expects it."""

    def __init__(self, config: ServerConfig, port: int) -> None:
        self.app = create_app(config)
        self.server = uvicorn_server(self.app, "127.0.0.1", port, log_level="warning")
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 15
        while not self.server.started:
            assert self.thread.is_alive() and time.monotonic() < deadline, "no restart"
            time.sleep(0.01)
        self.hub = self.app.state.hub
        self.metrics = self.app.state.metrics

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=15)


async def until(predicate, timeout: float = 10.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


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
    assert server.hub.remote.samples == produced
    assert server.hub.remote.tracker == "synthetic (seed 2)"
    times = [t for _, batch in received for t in batch]
    recorded = read_session_log(record)
    assert times == [s.t_ns for s in recorded.samples]  # all, once, in order
    assert all(len(batch) <= 50 for _, batch in received)
    # the server follows the last fixation start or update the daemon sent
    follows = ("fixation_start", "fixation_update")
    last_fix = [e for e in recorded.events if e.kind in follows][-1]
    assert server.hub.remote.x == pytest.approx(last_fix.x / GEOMETRY.screen_width_px)
    assert server.hub.remote.y == pytest.approx(last_fix.y / GEOMETRY.screen_height_px)
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
        async with websockets.connect(server.ws_url + "/ws/view") as view:

            async def watch() -> None:
                async for message in view:
                    if isinstance(message, bytes):
                        header, _ = decode_frame(message)
                        seen.append((header.gaze_x, header.gaze_y, header.tracker))

            watcher = asyncio.create_task(watch())
            await until(lambda: len(seen) > 2, what="first frames")
            stats = await run_daemon(source, server.ws_url, "t")
            assert stats.events_delivered > 0
            await asyncio.sleep(0.3)
            watcher.cancel()
        return seen

    seen = run(check())
    targets = [(0.5, 0.5), (0.25, 0.25), (0.75, 0.7)]  # start, fixation A, fixation B

    def near(p, q) -> bool:
        return math.dist(p, q) < 0.02

    assert all(tracker for *_, tracker in seen)
    # only fixation positions, never a point along the saccade
    assert all(any(near((x, y), q) for q in targets) for x, y, _ in seen), seen
    assert any(near((x, y), targets[1]) for x, y, _ in seen)
    assert near(seen[-1][:2], targets[2])


def _second_server_config(tmp_path: Path) -> ServerConfig:
    """A server started on the port of one that was killed, as after a crash."""
    return ServerConfig(
        token="t",
        session=SessionSettings(width=160, height=96, fps=20.0),
        data_dir=tmp_path / "data2",
        session_grace_s=0.0,
    )


def test_restarted_server_gets_everything_the_buffer_kept(live_server, received, tmp_path):
    first = live_server(token="t")
    port = first.port
    config = _second_server_config(tmp_path)
    record = tmp_path / "rec.jsonl"
    source = SyntheticSource(4, 1000.0)  # live, endless, real time
    bound = 300
    daemon = Daemon(
        source,
        first.ws_url,
        "t",
        record=record,
        buffer=bound,
        backoff=(0.05, 0.2),
        drain_timeout=5.0,
    )
    second: list[ServerOnPort] = []

    async def scenario():
        task = asyncio.create_task(daemon.run())
        await until(lambda: daemon.stats.samples_delivered >= 300, what="first deliveries")
        await asyncio.to_thread(first.stop)
        await until(lambda: not daemon.connected, what="the daemon to notice")
        await asyncio.sleep(0.8)  # ~800 samples at 1000 Hz: more than the bound keeps
        assert daemon.backlog <= bound + daemon.max_inflight
        assert daemon.stats.samples_dropped > 0
        second.append(await asyncio.to_thread(ServerOnPort, config, port))
        await until(lambda: daemon.stats.connects == 2, what="the reconnect")
        await asyncio.sleep(0.3)
        daemon.stop()
        return await task

    try:
        stats = run(scenario())
    finally:
        for s in second:
            s.stop()
    (restarted,) = second
    recorded = read_session_log(record)
    produced = [s.t_ns for s in recorded.samples]
    # the local recording has everything the source gave
    assert len(produced) == stats.samples_produced == stats.samples_recorded
    assert len(recorded.events) == stats.events_produced == stats.events_recorded
    # each server saw its samples in order
    hubs = {id(first.hub): [], id(restarted.hub): []}
    for hub, batch in received:
        hubs[hub].extend(batch)
    for times in hubs.values():
        assert times == sorted(times) and len(set(times)) == len(times)
    # nothing lost but what the bound dropped, and that exactly as counted
    arrived = set(hubs[id(first.hub)]) | set(hubs[id(restarted.hub)])
    missing = [t for t in produced if t not in arrived]
    assert len(missing) == stats.samples_dropped > 0
    assert stats.samples_undelivered == 0
    assert stats.samples_delivered + stats.samples_dropped == stats.samples_produced
    # the oldest were dropped: the gap lies between the two servers' streams
    assert max(hubs[id(first.hub)]) < min(missing) <= max(missing) < max(produced)
    resent = set(hubs[id(first.hub)]) & set(hubs[id(restarted.hub)])
    assert len(resent) <= stats.resent  # at least once: only unacknowledged ones twice
    assert restarted.hub.remote.samples > 0 and stats.connects == 2
    assert any("dropped" in n.text for n in recorded.notes)
    assert first.metrics.gaze_rate_limited.value == restarted.metrics.gaze_rate_limited.value == 0


def test_a_wrong_token_is_fatal_and_clear(live_server, capsys, monkeypatch) -> None:
    server = live_server(token="right")
    source = SyntheticSource(0, 100.0)
    started = time.monotonic()
    with pytest.raises(UnauthorizedError, match="refused the token"):
        run(run_daemon(source, server.ws_url, "wrong", backoff=(0.05, 0.1)))
    assert time.monotonic() - started < 5
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
    assert server.hub.remote.samples == len(samples) == 501
    assert read_session_log(out).samples == samples  # the replay emitted what was recorded
    assert "delivered 501 samples" in capsys.readouterr().err


def test_a_flood_is_paced_below_the_limit_without_harming_a_viewer(live_server, tmp_path):
    server = live_server(token="t", gaze_source="remote")
    samples = list(SyntheticSource(3, 1000.0, duration=4.0, realtime=False, start_ns=0))
    log = _write_log(tmp_path / "flood.jsonl", samples)
    source = ReplaySource(log, speed=math.inf)  # as fast as it can be read: a flood

    async def fps(view, seconds: float) -> float:
        frames = []
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            message = await view.recv()
            if isinstance(message, bytes):
                frames.append(decode_frame(message)[0].frame)
        return (frames[-1] - frames[0]) / (time.monotonic() - t0)

    async def check():
        async with websockets.connect(server.ws_url + "/ws/view") as view:
            quiet = await fps(view, 1.5)
            started = time.monotonic()
            daemon = asyncio.create_task(run_daemon(source, server.ws_url, "t"))
            flooded = await fps(view, 1.5)
            stats = await daemon
            return quiet, flooded, stats, time.monotonic() - started

    quiet, flooded, stats, elapsed = run(check())
    n = len(samples)
    assert server.hub.remote.samples == stats.samples_delivered == n  # a replay waits, no loss
    assert server.metrics.gaze_rate_limited.value == 0 and stats.server_rate_limited == 0
    assert elapsed >= (n - 1000) / 2000  # paced: never faster than the server's limit
    sent = list(stats.sent_times)
    for i, (t, _) in enumerate(sent):  # within any second: at most burst + rate
        assert sum(k for u, k in sent[i:] if u - t < 1.0) <= 1000 + 1900 + 50
    assert flooded > 0.7 * quiet, (quiet, flooded)


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
    assert server.hub.remote.samples == stats.samples_delivered == len(sendable) == 70
    assert stats.samples_unsendable == 30 and stats.samples_undelivered == 0
    assert "30 samples, 0 events not sendable" in stats.summary()


def test_a_reconnect_forgets_the_old_servers_clock(live_server, monkeypatch, tmp_path) -> None:
    """A rebooted server has another monotonic clock: echoes of the old one must not stand in
    for it, even those with a smaller round trip."""
    shift = 5_000_000_000
    first = live_server(token="t")
    original = app_module._GazeLink.handle

    def handle(self, msg, now):  # the restarted server: its clock 5 s ahead, echoes slower
        reply = original(self, msg, now)
        if isinstance(msg, wire.Echo) and self.hub is not first.hub:
            time.sleep(0.01)
            return wire.EchoReply(reply.t0_ns, reply.server_ns + shift)
        return reply

    monkeypatch.setattr(app_module._GazeLink, "handle", handle)
    config = _second_server_config(tmp_path)
    record = tmp_path / "rec.jsonl"
    daemon = Daemon(
        SyntheticSource(5, 500.0),
        first.ws_url,
        "t",
        record=record,
        backoff=(0.05, 0.2),
        drain_timeout=5.0,
        clock_window=100_000,  # nothing slides out during the test: only a reset can help
    )
    second: list[ServerOnPort] = []

    async def scenario():
        task = asyncio.create_task(daemon.run())
        await until(lambda: daemon.stats.samples_delivered >= 200, what="first deliveries")
        before = daemon.stats.clock
        await asyncio.to_thread(first.stop)
        await until(lambda: not daemon.connected, what="the daemon to notice")
        second.append(await asyncio.to_thread(ServerOnPort, config, first.port))
        await until(lambda: daemon.stats.connects == 2, what="the reconnect")
        await until(
            lambda: daemon.stats.clock.offset_ns > shift / 2, timeout=5.0, what="the new clock"
        )
        await asyncio.sleep(1.2)  # one more clock record (they are written at most 1/s)
        daemon.stop()
        return before, await task

    try:
        before, stats = run(scenario())
    finally:
        for s in second:
            s.stop()
    assert abs(before.offset_ns) <= before.uncertainty_ns + 1_000  # one host, one clock
    after = stats.clock
    assert after.rtt_ns >= 10_000_000 > before.rtt_ns
    assert abs(after.offset_ns - shift) <= after.uncertainty_ns + 1_000
    clocks = read_session_log(record).clocks
    assert abs(clocks[0].offset_ns) < shift / 2 and abs(clocks[-1].offset_ns - shift) < shift / 2
