"""`/ws/gaze`'s connections: a daemon's messages to its tracker's feed, each kind of message
under its own rate limit (docs/protocol.md). The endpoint in `gazehdr.app` only accepts the
socket and hands it to a `GazeLink`."""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass

from fastapi import WebSocket, WebSocketDisconnect

from gazehdr.drivers import wire
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.fair_share import DAEMON_BURST, DAEMON_RATE, ConnectionShare, error_text
from gazehdr.gaze import TrackerFeed
from gazehdr.live import SessionHub
from gazehdr.metrics import Counter, Metrics


@dataclass(frozen=True)
class GazeLimit:
    """A per-connection rate limit on one kind of `/ws/gaze` message."""

    unit: str  # what it counts, as the note to the daemon names it
    rate: float
    burst: float


# Per-connection limits on /ws/gaze, per kind of message. What passes a limit is dropped, counted
# in /metrics and noted to the daemon (at most every NOTE_INTERVAL_S), and the connection is not
# read until the limit has taken the excess back (GazeLink.run). Each sits well above what a
# real daemon sends, measured against this server with a 1200 Hz live synthetic source and with
# 30 and 60 Hz recordings replayed at full speed.
GAZE_RATE_HZ = 2000.0  # samples per second per daemon connection, sustained
GAZE_BURST = 4000.0
SAMPLE_LIMIT = GazeLimit("samples", GAZE_RATE_HZ, GAZE_BURST)
# Events: live, about 20/s (I-VT: a fixation_update per 50 ms of sample time, a start and an end
# per fixation, blinks). Only a recording replayed at full speed makes them follow the sample
# rate, which the daemon keeps below GAZE_RATE_HZ: a 30 Hz one measured 800 events/s (2400/s over
# a quarter second). The sample limit covers that with room to spare.
EVENT_LIMIT = GazeLimit("events", 2000.0, 4000.0)
# Echoes: the daemon echoes after each sending round (every 20 ms at most, plus a round per event)
# to acknowledge delivery and follow the clock: measured at most 64/s. 500/s is eight times that.
ECHO_LIMIT = GazeLimit("echoes", 500.0, 1000.0)
NOTE_INTERVAL_S = 1.0  # one rate-limit note a second per kind and connection tells enough


class Limiter:
    """One `GazeLimit` on one connection: what it drops is counted at once and reported to the
    daemon at most every `NOTE_INTERVAL_S`, as the number dropped since the previous note (the
    daemon adds them up)."""

    def __init__(self, limit: GazeLimit, dropped: Counter) -> None:
        self.limit, self.dropped = limit, dropped
        self.bucket = TokenBucket(limit.rate, limit.burst)
        self.unreported = 0
        self.noted_at = -math.inf

    def admit(self, n: int, now: float) -> tuple[int, wire.Notice | None]:
        """How many of `n` items pass, and the note to send, if one is due."""
        allowed = self.bucket.admit(n, now)
        if allowed == n:
            return allowed, None
        self.dropped.inc(n - allowed)
        self.unreported += n - allowed
        if now - self.noted_at < NOTE_INTERVAL_S:
            return allowed, None
        unit, rate = self.limit.unit, self.limit.rate
        note = wire.Notice(
            f"rate limit: {self.unreported} {unit} dropped; at most {rate:g} {unit}/s are accepted"
        )
        self.noted_at, self.unreported = now, 0
        return allowed, note


class GazeLink:
    """One daemon connection: its tracker's feed follows the daemon's fixations (or its raw
    samples, if it sends no events). The feed is the tracker its hello names; a daemon that
    sends gaze before any hello is an unnamed tracker."""

    def __init__(self, ws: WebSocket, hub: SessionHub, metrics: Metrics) -> None:
        self.ws, self.hub, self.metrics = ws, hub, metrics
        self.limits = {
            wire.Samples: Limiter(SAMPLE_LIMIT, metrics.gaze_rate_limited),
            wire.Event: Limiter(EVENT_LIMIT, metrics.gaze_events_rate_limited),
            wire.Echo: Limiter(ECHO_LIMIT, metrics.gaze_echoes_rate_limited),
        }
        self.uses_events = False
        self.said_hello = False
        self.feed: TrackerFeed | None = None
        self.hold_s = 0.0  # how long to stop reading, after a message that went over a limit

    async def run(self) -> None:
        share = ConnectionShare(DAEMON_RATE, DAEMON_BURST)  # every message, parsed or not
        while True:
            while (wait := share.admit(time.monotonic())) > 0:
                self.metrics.messages_held.inc()
                await asyncio.sleep(wait)  # not reading: the socket holds the daemon back
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            try:
                text = message.get("text")
                if text is None:
                    raise wire.WireError("binary messages are not accepted; send JSON text")
                reply = self.handle(wire.parse(text), time.monotonic())
            except wire.WireError as e:
                self.metrics.protocol_errors.inc()
                left_out = share.error(time.monotonic())
                reply = None if left_out is None else wire.Notice(error_text(str(e), left_out))
            if reply:
                try:
                    await self.ws.send_text(wire.dumps(reply))
                except WebSocketDisconnect:  # gone while we answered: nothing left to do
                    return
            if self.hold_s:
                # Dropping is not enough: receiving and parsing cost more than the limit saves,
                # so a daemon flooding small messages would take this server's event loop from
                # every session. Reading nothing for as long as the bucket needs to take back
                # what went over lets the socket's flow control hold the daemon back instead.
                await asyncio.sleep(self.hold_s)
                self.hold_s = 0.0

    def close(self) -> None:
        """The connection ended: its tracker is no longer connected; the viewers are told."""
        self.metrics.trackers.set(self.hub.trackers.connections)
        if self.feed is not None:
            self.hub.trackers.disconnect(self.feed)
            self._tell_viewers(self.feed)

    def handle(self, msg: wire.Message, now: float) -> wire.Reply | None:
        if isinstance(msg, wire.Hello):
            return self._hello(msg)
        count = len(msg.samples) if isinstance(msg, wire.Samples) else 1
        limiter = self.limits[type(msg)]
        allowed, note = limiter.admit(count, now)
        self.hold_s = (count - allowed) / limiter.limit.rate
        if isinstance(msg, wire.Samples):
            self._samples(msg.samples[:allowed], now)
        elif allowed and isinstance(msg, wire.Echo):
            return wire.EchoReply(msg.t0_ns, time.monotonic_ns())
        elif allowed:
            self._event(msg, now)
        return note

    def _hello(self, msg: wire.Hello) -> wire.Welcome:
        # Every hello is broadcast to every viewer of every session: a second one on the same
        # connection is refused, so that a flood of them cannot reach the other sessions.
        if self.said_hello:
            raise wire.WireError("hello: this connection has said hello already")
        self.said_hello = True
        if self.feed is not None:  # gaze came first, as an unnamed tracker: that one ends
            self.close()
            self.feed = None
        self.feed = self._connect(msg.tracker)
        self.feed.hello(msg.accuracy_deg)
        return wire.Welcome(wire.PROTOCOL)

    def _connect(self, name: str | None) -> TrackerFeed:
        try:
            feed = self.hub.trackers.connect(name)
        except ValueError as e:  # the table of tracker names is full
            raise wire.WireError(str(e)) from None
        self._tell_viewers(feed)
        return feed

    def _tell_viewers(self, feed: TrackerFeed) -> None:
        self.hub.broadcast({"type": "tracker", **feed.describe()})

    def _tracker(self) -> TrackerFeed:
        if self.feed is None:
            self.feed = self._connect(None)
        return self.feed

    def _event(self, msg: wire.Event, now: float) -> None:
        self.uses_events = True
        self._tracker().events += 1
        if msg.kind in ("fixation_start", "fixation_update"):
            self._tracker().fixate(msg.x, msg.y, True, now)
        elif msg.kind in ("blink_start", "blink_end"):
            self._tracker().fixate(None, None, msg.kind == "blink_end", now)

    def _samples(self, samples: tuple[wire.Sample, ...], now: float) -> None:
        self.metrics.gaze_samples.inc(len(samples))
        feed = self._tracker()
        feed.count([s.t_ns for s in samples])  # the tracker's rate, from the samples' times
        if not self.uses_events:
            valid = [s for s in samples if s.valid]
            if valid:
                feed.fixate(valid[-1].x, valid[-1].y, True, now)
