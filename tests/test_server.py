"""The server for real: uvicorn on loopback, WebSocket clients from the `websockets` library."""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import re
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import websockets
from conftest import sole_tracker
from websockets.exceptions import ConnectionClosed

from gazehdr import gaze_link
from gazehdr.live import MAX_IDLE_S
from gazehdr.metrics import Counter
from gazehdr.protocol import FrameHeader, decode_frame
from gazehdr.scenes.exr import write_exr
from gazehdr.session import MAX_FRAME_DT
from tests.waiting import until

TIMEOUT = 30.0


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT))


def http(method: str, url: str, body: bytes | None = None, **headers: str) -> tuple[int, Any]:
    request = urllib.request.Request(url, data=body, method=method, headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=TIMEOUT) as response:
            status, raw, kind = response.status, response.read(), response.headers["content-type"]
    except urllib.error.HTTPError as e:
        status, raw, kind = e.code, e.read(), e.headers["content-type"]
    return status, json.loads(raw) if "json" in (kind or "") else raw.decode()


class Client:
    """A viewer: keeps the JSON notes it receives, returns frames on request."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.notes: list[dict[str, Any]] = []

    @classmethod
    async def open(cls, server, query: str = "", **kw) -> Client:
        kw.setdefault("additional_headers", server.auth)
        ws = await websockets.connect(f"{server.ws_url}/ws/view{query}", **kw)
        client = cls(ws)
        hello = await client.note("hello")
        client.hello = hello
        return client

    async def send(self, **message: Any) -> None:
        await self.ws.send(json.dumps(message))

    async def _next(self) -> tuple[FrameHeader, np.ndarray] | None:
        message = await self.ws.recv()
        if isinstance(message, str):
            self.notes.append(json.loads(message))
            return None
        return decode_frame(message)

    async def frame(self, until=lambda h: True) -> tuple[FrameHeader, np.ndarray]:
        while True:
            got = await self._next()
            if got and until(got[0]):
                return got

    async def note(self, kind: str) -> dict[str, Any]:
        while True:
            for note in self.notes:
                if note["type"] == kind:
                    self.notes.remove(note)
                    return note
            await self._next()


# --- REST ---------------------------------------------------------------------------------------


def test_health_metrics_scenes_openapi(live_server) -> None:
    server = live_server()
    assert http("GET", server.url + "/api/health") == (
        200,
        {"status": "ok", "sessions": 0, "viewers": 0, "trackers": 0},
    )
    status, scenes = http("GET", server.url + "/api/scenes")
    assert status == 200 and {"flash", "lamp", "checker-night"} <= set(scenes["scenes"])
    status, spec = http("GET", server.url + "/openapi.json")
    assert status == 200 and "/api/scenes/{name}" in spec["paths"]
    status, text = http("GET", server.url + "/metrics")
    assert status == 200 and "# TYPE gazehdr_frames_sent_total counter" in text


def test_params_rest_validates_and_sets_new_sessions(live_server) -> None:
    server = live_server()
    status, body = http("GET", server.url + "/api/params")
    assert status == 200 and body["params"] == body["defaults"] and body["defaults"]["j1"] == 0.03
    assert "2.2 Afterimages" in body["sections"] and "plateau_K" in body["ours"]
    bad = [b'{"n": -1}', b'{"nope": 1}', b'{"b1": [1, 2]}', b'{"n": "x"}', b"[1]", b"{"]
    bad.append(b'{"mikamo_sequence": "/etc/passwd"}')  # the server's files are not for clients
    for payload in bad:
        status, err = http(
            "PUT",
            server.url + "/api/params",
            payload,
            **{"content-type": "application/json"},
            **server.auth,
        )
        assert status == 422, (payload, err)
    assert "cannot be set remotely" in err["detail"] and "passwd" not in err["detail"]
    status, body = http(
        "PUT",
        server.url + "/api/params",
        b'{"j1": 0.2}',
        **{"content-type": "application/json"},
        **server.auth,
    )
    assert status == 200 and body["params"]["j1"] == 0.2

    async def check() -> None:
        client = await Client.open(server)
        assert client.hello["params"]["j1"] == 0.2 and client.hello["defaults"]["j1"] == 0.03
        await client.ws.close()

    run(check())


def test_exr_upload(live_server, tmp_path) -> None:
    server = live_server(max_upload_bytes=200_000)
    good = tmp_path / "good.exr"
    write_exr(good, np.full((20, 30, 3), 50.0, np.float32))
    status, body = http("PUT", server.url + "/api/scenes/office", good.read_bytes(), **server.auth)
    assert (status, body) == (201, {"name": "office"})
    assert "office" in http("GET", server.url + "/api/scenes")[1]["scenes"]
    stored = server.config.data_dir / "scenes"
    assert sorted(p.name for p in stored.iterdir()) == ["office.exr"]

    cases = [
        ("broken", b"\x76\x2f\x31\x01" + b"\x00" * 64, 422, "upload 'broken'"),
        ("text", b"hello", 422, "not an HDR image this viewer reads"),
        ("huge", b"\x00" * 200_001, 413, "limit"),
        ("..%2F..%2Fescape", good.read_bytes(), 400, "not allowed"),
        ("a%2Fb", good.read_bytes(), 400, "not allowed"),
        (".hidden", good.read_bytes(), 400, "not allowed"),
        ("flash", good.read_bytes(), 422, "taken by a built-in"),
    ]
    for name, payload, code, message in cases:
        status, body = http("PUT", f"{server.url}/api/scenes/{name}", payload, **server.auth)
        assert status == code and message in body["detail"], (name, status, body)
    # Nothing of the refused uploads was kept, in the folder or outside it.
    assert sorted(p.name for p in stored.iterdir()) == ["office.exr"]
    # (viewer-secret: the viewer cookie's secret, gazehdr.security, made when the server starts)
    assert sorted(p.name for p in server.config.data_dir.iterdir()) == ["scenes", "viewer-secret"]

    async def view_upload() -> None:
        client = await Client.open(server)
        await client.send(type="scene", name="office")
        state = await client.note("state")
        assert state["scene"] == "office"
        await client.ws.close()

    run(view_upload())


# --- /ws/view -----------------------------------------------------------------------------------


def test_frames_flow_at_real_time_and_follow_the_pointer(live_server) -> None:
    fps = 20.0
    server = live_server(scene="lamp", fps=fps)

    async def check() -> None:
        client = await Client.open(server)
        hello = client.hello
        assert hello["protocol"] == 1 and hello["scene"] == "lamp" and hello["width"] == 160
        sent_at = time.monotonic()
        await client.send(type="gaze", x=0.125, y=0.75, seq=9)
        first, v = await client.frame(lambda h: h.gaze_seq == 9)
        received_at = time.monotonic()
        assert (first.gaze_x, first.gaze_y) == (0.125, 0.75)
        assert v.shape == (96, 160, 3) and np.all((v >= 0) & (v <= 1))
        # Simulation time follows the wall clock, which only causality can check on a loaded
        # machine. Each step moves the eye by the wall time since the last one, at most
        # MAX_FRAME_DT; on average no faster than fps (steps keep a fixed cadence, so a step
        # after a late one may start at once: live.next_due). And it never runs ahead:
        # the step of `first` started at most its own length before the gaze it shows was sent
        # (the late gaze: read once the step is simulated), each later frame before it
        # arrived here.
        headers = [first]
        started = sent_at - first.server_ms / 1e3
        while len(headers) < 12:
            header, _ = await client.frame()
            assert header.time - first.time <= time.monotonic() - started
            headers.append(header)
        for a, b in itertools.pairwise(headers):
            steps = b.frame - a.frame
            assert steps >= 1, (a, b)
            assert 0 < b.time - a.time <= steps * MAX_FRAME_DT + 1e-6, (a, b)
        steps = headers[-1].frame - headers[0].frame  # a late first step: one interval made up
        assert headers[-1].time - headers[0].time >= (steps - 2) / fps, headers
        # Nor does it fall behind: a frame that shows a gaze sent some time after `first`
        # arrived was stepped at least that much later (at most MAX_FRAME_DT a step).
        await asyncio.sleep(0.3)
        idle = time.monotonic() - received_at
        await client.send(type="gaze", x=0.5, y=0.5, seq=10)
        later, _ = await client.frame(lambda h: h.gaze_seq == 10)
        assert later.time - first.time >= min(idle, MAX_FRAME_DT) - 1e-6, (first, later, idle)
        await client.send(type="eyes", open=False)
        closed, _ = await client.frame(lambda h: not h.eyes_open)
        assert not closed.eyes_open
        await client.ws.close()

    run(check())
    assert server.metrics.frames_sent.value > 5
    assert server.metrics.gaze_latency.n >= 1


def test_controls_change_the_session_and_errors_do_not_stop_it(live_server) -> None:
    server = live_server()

    async def check() -> None:
        client = await Client.open(server)
        await client.send(type="viewport", width=500, height=500)
        state = await client.note("state")
        side = state["width"]
        assert state["width"] == state["height"] and abs(side * side - 160 * 96) < 16 * side
        await client.frame(lambda h: h.width == side)

        await client.send(type="params", values={"j1": 0.5})
        assert (await client.note("state"))["params"]["j1"] == 0.5
        for bad, what in [
            ("{oops", "malformed JSON"),
            ('{"type": "teleport"}', "unknown message type"),
            ('{"type": "gaze", "x": NaN, "y": 0, "seq": 1}', "NaN"),
            ('{"type": "scene", "name": "../../etc/passwd"}', "not allowed"),
            ('{"type": "scene", "name": "nowhere"}', "no scene named"),
            ('{"type": "params", "values": {"n": 0}}', "parameters refused"),
            ('{"type": "model", "afterimage": "magic"}', "unknown afterimage model 'magic'"),
            ('{"type": "model", "name": "jacobs"}', "'model' needs 'afterimage', 'acuity'"),
            (json.dumps({"type": "reset", "pad": "x" * 70_000}), "limit is 65536"),
        ]:
            await client.ws.send(bad)
            error = await client.note("error")
            assert what in error["message"], (bad, error)
        await client.ws.send(b"\x00binary")
        assert "binary" in (await client.note("error"))["message"]
        # The session is unharmed: still lamp... no, still its scene, frames keep coming.
        before, _ = await client.frame()
        after, _ = await client.frame(lambda h: h.frame > before.frame + 2)
        assert after.time > before.time
        await client.ws.close()

    run(check())


def test_model_choice_and_split_view_over_the_socket(live_server) -> None:
    """Models by name, split on and off; the frames say so (flag, width) and so does the
    state. Reference backend: every model has one."""
    server = live_server(scene="lamp", backend="reference", size=(64, 36))

    async def check() -> None:
        client = await Client.open(server)
        hello = client.hello
        assert hello["model"] == {"afterimage": "jacobs", "acuity": "stochastic"}
        assert hello["split"] is None and "ritschel" in hello["models"]["afterimage"]
        await client.send(type="viewport", width=64, height=36)  # keep the budget's shape
        await client.send(type="model", acuity="none", split={"afterimage": "ritschel"})
        state = await client.note("state")
        assert state["model"] == {"afterimage": "jacobs", "acuity": "none"}
        assert state["split"] == {"afterimage": "ritschel", "acuity": "none"}
        header, v = await client.frame(lambda h: h.split)
        assert (header.width, header.height) == (64, 36) and v.shape == (36, 64, 3)
        status, sessions = await asyncio.to_thread(
            http, "GET", server.url + "/api/sessions", **server.auth
        )
        assert status == 200
        assert (sessions[0]["model"], sessions[0]["split"]) == ("jacobs+none", "ritschel+none")
        await client.send(type="model", afterimage="nope", split=None)
        assert "unknown afterimage model 'nope'" in (await client.note("error"))["message"]
        seen, _ = await client.frame()
        assert seen.split  # refused as a whole: split view still on
        await client.send(type="model", split=None)
        assert (await client.note("state"))["split"] is None
        await client.frame(lambda h: not h.split and h.frame > seen.frame)
        await client.ws.close()

    run(check())


def test_oversized_message_closes_only_that_connection(live_server) -> None:
    server = live_server()

    async def check() -> None:
        bystander = await Client.open(server)
        rogue = await Client.open(server, max_size=None)
        with pytest.raises(ConnectionClosed) as info:
            # The server may close (1009) before the client has written the whole message: then
            # the send itself raises; otherwise the next read does.
            await rogue.ws.send("x" * (2 * 1024 * 1024))
            while True:
                await rogue._next()
        assert info.value.rcvd.code == 1009  # message too big
        before, _ = await bystander.frame()
        await bystander.frame(lambda h: h.frame >= before.frame + 3)
        await bystander.ws.close()

    run(check())


def test_foreign_origin_is_refused(live_server) -> None:
    server = live_server(allow_origins=("https://lab.example",))

    async def check() -> None:
        ws = await websockets.connect(
            server.ws_url + "/ws/view",
            origin="https://evil.example",
            additional_headers=server.auth,
        )
        with pytest.raises(ConnectionClosed) as info:
            await ws.recv()
        assert info.value.rcvd.code == 4403 and "evil.example" in info.value.rcvd.reason
        for origin in (server.url, "https://lab.example"):
            client = await Client.open(server, origin=origin)
            await client.frame()
            await client.ws.close()

    run(check())


def test_slow_viewer_neither_queues_nor_slows_another(live_server) -> None:
    """Two viewers of one session; one stops reading. Its frames are replaced, not queued, and
    the other viewer's keep coming all the while."""
    server = live_server(size=(480, 270), fps=15.0)  # big frames: socket buffers fill soon
    stuck_for = 20  # frames the other viewer gets while the stalled one's send makes no progress

    async def check() -> None:
        fast = await Client.open(server)
        session = fast.hello["session"]
        live = server.hub.sessions[session]
        (fast_viewer,) = live.viewers
        # max_queue=1: the stalled client stops reading its socket after one message.
        slow = await Client.open(server, f"?session={session}", max_queue=1)
        assert slow.hello["session"] == session
        (slow_viewer,) = live.viewers - {fast_viewer}
        headers: list[FrameHeader] = []
        peak = stuck = 0
        while stuck < stuck_for or slow_viewer.mailbox.dropped < stuck_for:
            slow_sent = slow_viewer.sent
            headers.append((await fast.frame())[0])
            peak = max(peak, *(int(v.mailbox.frame is not None) for v in live.viewers))
            stuck = stuck + 1 if slow_viewer.sent == slow_sent else 0
        assert peak <= 1  # never more than the newest frame waits for anyone
        # The other viewer got frames all along, in order, and each frame the session made that
        # it did not get was replaced in its own mailbox and counted in the next one it got.
        for a, b in itertools.pairwise(headers):
            assert b.frame - a.frame - 1 == b.dropped - a.dropped >= 0, (a, b)
        # While the stalled viewer was stuck the session did not wait for it: it stepped as
        # soon as the other one could take a frame, sooner than the MAX_IDLE_S it waits when
        # nobody can.
        stuck_span = headers[-stuck:]
        steps = [
            b.time - a.time for a, b in itertools.pairwise(stuck_span) if b.frame == a.frame + 1
        ]
        assert min(steps, default=math.inf) < MAX_IDLE_S, steps
        # Once the stalled viewer reads again, it gets the newest frame, not a backlog: the
        # frame after those already on their way is no older than the other viewer's last,
        # and says how many it missed.
        newest, dropped = headers[-1].frame, slow_viewer.mailbox.dropped
        caught_up, _ = await slow.frame(lambda h: h.dropped >= dropped)
        assert caught_up.frame >= newest, (caught_up, newest)
        await fast.ws.close()
        await slow.ws.close()

    run(check())


def test_session_ends_when_its_page_closes(live_server) -> None:
    server = live_server()

    async def check() -> None:
        client = await Client.open(server)
        await client.frame()
        assert len(server.hub.sessions) == 1
        await client.ws.close()
        await until(lambda: not server.hub.sessions, "the session to end as its viewer left")

    run(check())
    assert http("GET", server.url + "/api/health")[1]["sessions"] == 0


# --- /ws/gaze -----------------------------------------------------------------------------------


def test_gaze_endpoint_refuses_wrong_or_missing_token(live_server) -> None:
    server = live_server(token="s3cret")

    async def check(headers: dict[str, str], why: str) -> None:
        ws = await websockets.connect(server.ws_url + "/ws/gaze", additional_headers=headers)
        with pytest.raises(ConnectionClosed) as info:
            await ws.recv()
        assert info.value.rcvd.code == 4401
        assert info.value.rcvd.reason == f"unauthorized: {why} bearer token"

    run(check({}, "missing"))
    run(check({"Authorization": "Bearer wrong"}, "wrong"))
    run(check({"Authorization": "s3cret"}, "wrong"))


def test_remote_gaze_drives_a_session(live_server) -> None:
    server = live_server(token="tok", gaze_source="remote")
    auth = {"Authorization": "Bearer tok"}

    async def check() -> None:
        viewer = await Client.open(server)
        async with websockets.connect(server.ws_url + "/ws/gaze", additional_headers=auth) as d:
            hello = json.dumps({"type": "hello", "protocol": 1, "tracker": "test rig"})
            await d.send(hello)
            assert json.loads(await d.recv()) == {"type": "welcome", "protocol": 1}
            note = await viewer.note("tracker")
            assert note["connected"] and note["name"] == "test rig"
            await d.send(hello)  # each hello reaches every viewer: one per connection
            assert "said hello already" in json.loads(await d.recv())["message"]
            await d.send(json.dumps({"type": "echo", "t0": 5}))
            echo = json.loads(await d.recv())
            assert echo["t0"] == 5 and echo["server_ns"] > 0
            samples = [{"t": i, "x": 0.3, "y": 0.6} for i in range(10)]
            await d.send(json.dumps({"type": "samples", "samples": samples}))
            header, _ = await viewer.frame(lambda h: math.isclose(h.gaze_x, 0.3, abs_tol=1e-6))
            assert header.tracker and header.gaze_y == pytest.approx(0.6)
            # Once fixation events arrive the session follows them, not the raw samples.
            event = {
                "type": "event",
                "kind": "fixation_start",
                "id": 1,
                "t": 20,
                "x": 0.8,
                "y": 0.1,
            }
            await d.send(json.dumps(event))
            await d.send(
                json.dumps({"type": "samples", "samples": [{"t": 30, "x": 0.2, "y": 0.2}]})
            )
            await viewer.frame(lambda h: math.isclose(h.gaze_x, 0.8, abs_tol=1e-6))
            await d.send(json.dumps({"type": "event", "kind": "blink_start", "id": 2, "t": 40}))
            await viewer.frame(lambda h: not h.eyes_open)
            await d.send('{"type": "samples", "samples": [{"t": 1, "x": NaN, "y": 0}]}')
            assert "NaN" in json.loads(await d.recv())["message"]
        assert not (await viewer.note("tracker"))["connected"]
        await viewer.ws.close()

    run(check())


# A rogue daemon, in a process of its own as a real one would be: sends MESSAGE over and over
# (each send waiting for the socket) until a line arrives on its stdin, reading the replies
# meanwhile; then reads on until the server's first rate-limit note has come, and goes away
# without closing. Prints what it started to send and what it received.
FLOODER = """
import asyncio, json, sys
import websockets

async def main(url, token, message):
    replies = []
    noted = asyncio.Event()
    async def read(d):
        async for text in d:
            reply = json.loads(text)
            replies.append(reply)
            if reply["type"] == "error" and reply["message"].startswith("rate limit:"):
                noted.set()
    d = await websockets.connect(url, additional_headers={"Authorization": "Bearer " + token})
    reader = asyncio.create_task(read(d))
    stop = asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
    sent = 0
    while not stop.done():
        sent += 1
        send = asyncio.ensure_future(d.send(message))
        await asyncio.wait([send, stop], return_when=asyncio.FIRST_COMPLETED)
        if send.done():
            send.result()
        else:
            send.cancel()
    note = asyncio.ensure_future(noted.wait())
    await asyncio.wait([note, reader], return_when=asyncio.FIRST_COMPLETED)
    print(json.dumps({"sent": sent, "replies": replies}), flush=True)
    d.transport.abort()

asyncio.run(main(sys.argv[1], sys.argv[2], sys.argv[3]))
"""


@dataclass
class Flood:
    """What a flood of one message on /ws/gaze did."""

    sent: int  # messages the flooder started to send
    replies: list[dict[str, Any]]  # what it read of the server's answers, in order
    seconds: float  # from starting it until the server saw it leave
    frames: list[FrameHeader]  # what a viewer of another session got while it lasted


def flood_gaze(server, message: str, dropped: Counter, frames: int = 20) -> Flood:
    """`FLOODER` floods /ws/gaze with `message` while a viewer of a session that does not
    follow the tracker watches: from the moment the limit drops part of the flood (`dropped`
    counts it) until the viewer got `frames` frames the session made since, and the limit is
    still dropping."""

    async def check() -> Flood:
        viewer = await Client.open(server)
        session = server.hub.sessions[viewer.hello["session"]].session
        started = time.monotonic()
        flooder = await asyncio.create_subprocess_exec(
            sys.executable, "-c", FLOODER, server.ws_url + "/ws/gaze", server.token, message,
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
        )  # fmt: skip
        await until(lambda: dropped.value > 0, "the limit to drop part of the flood")
        since, flooding = session.frame, dropped.value
        seen: list[FrameHeader] = []
        while len(seen) < frames:
            header, _ = await viewer.frame(lambda h: h.frame >= since)
            seen.append(header)
        await until(lambda: dropped.value > flooding, "the flood to go on")
        await viewer.ws.close()
        out, _ = await flooder.communicate(b"stop\n")
        assert flooder.returncode == 0
        # what it left in the server's queue is handled
        await until(lambda: not server.hub.trackers.connections, "the server to see it leave")
        elapsed = time.monotonic() - started
        result = json.loads(out)
        return Flood(result["sent"], result["replies"], elapsed, seen)

    return run(check())


SAMPLES = {"type": "samples", "samples": [{"t": 1, "x": 0.5, "y": 0.5}] * 1000}
FIXATION = {"type": "event", "kind": "fixation_start", "id": 1, "t": 1, "x": 0.5, "y": 0.5}
# kind: (message, its limit, the counter of what the limit dropped)
FLOODS = {
    "samples": (SAMPLES, gaze_link.SAMPLE_LIMIT, "gaze_rate_limited"),
    "events": (FIXATION, gaze_link.EVENT_LIMIT, "gaze_events_rate_limited"),
    "echoes": ({"type": "echo", "t0": 7}, gaze_link.ECHO_LIMIT, "gaze_echoes_rate_limited"),
}


def test_the_daemon_knows_the_servers_gaze_limits() -> None:
    """drivers/delivery.py mirrors the server's limit (a tracker machine has no server code)."""
    from gazehdr.drivers import delivery

    assert delivery.SERVER_RATE_HZ == gaze_link.GAZE_RATE_HZ
    assert delivery.DEFAULT_RATE_HZ < gaze_link.GAZE_RATE_HZ
    assert delivery.DEFAULT_BURST < gaze_link.GAZE_BURST


@pytest.mark.slow
@pytest.mark.parametrize("kind", FLOODS)
def test_a_gaze_flood_is_rate_limited_without_harming_viewers(live_server, kind: str) -> None:
    message, limit, counter = FLOODS[kind]
    batch = len(message.get("samples", [None]))  # items per message
    server = live_server(token="tok")
    metric = getattr(server.metrics, counter)
    flood = flood_gaze(server, json.dumps(message), metric)
    dropped = metric.value
    assert f"\n{metric.name} {dropped:g}\n" in http("GET", server.url + "/metrics")[1]
    passed = {
        "samples": lambda: sole_tracker(server).samples,
        "events": lambda: sole_tracker(server).events,  # the fixation_starts it handled
        "echoes": lambda: sum(r["type"] == "echo" for r in flood.replies),  # those it read
    }[kind]()
    assert limit.burst <= passed <= limit.burst + limit.rate * flood.seconds
    assert passed + dropped <= flood.sent * batch
    # Held back, not only cut: the server handled about twice the limit, and no more, however
    # much more the flooder could send.
    assert passed + dropped <= limit.burst + 2 * limit.rate * flood.seconds + batch
    notes = [r["message"] for r in flood.replies if r["type"] == "error"]
    assert notes and all(
        f"{limit.unit} dropped; at most {limit.rate:g} {limit.unit}/s are accepted" in n
        for n in notes
    )
    told = sum(int(re.match(r"rate limit: (\d+) ", n)[1]) for n in notes)
    assert 0 < told <= dropped  # since the last note; what follows the last one is only counted
    assert len(notes) <= 1 + flood.seconds / gaze_link.NOTE_INTERVAL_S
    # the flood did not starve another session: it went on making frames, in order, for its
    # viewer (flood_gaze waited for them, with the limit dropping before and after)
    assert all(b.frame > a.frame for a, b in itertools.pairwise(flood.frames))


def test_a_recorded_session_replays_as_gaze(live_server, tmp_path) -> None:
    from gazehdr.drivers.samples import GazeSample
    from gazehdr.drivers.sessionlog import SessionHeader, SessionLogWriter

    server = live_server()
    log = tmp_path / "rec.jsonl"
    with SessionLogWriter(log, SessionHeader(tracker={"name": "hand-made"})) as writer:
        # 1920x1080 screen: hold (480, 270) px for 10 s, i.e. (0.25, 0.25) of the screen.
        for i in range(100):
            writer.write(GazeSample(t_ns=i * 100_000_000, x=480.0, y=270.0))
    status, body = http(
        "PUT", server.url + "/api/recordings/lab-1", log.read_bytes(), **server.auth
    )
    assert (status, body) == (201, {"name": "lab-1"})
    assert http("GET", server.url + "/api/recordings", **server.auth)[1] == {
        "recordings": ["lab-1"]
    }
    bad = [("no-samples", b'{"format": "gazehdr-session"}\n', 422), ("../x", b"", 400)]
    for name, payload, code in bad:
        assert http("PUT", f"{server.url}/api/recordings/{name}", payload, **server.auth)[0] == code

    async def check() -> None:
        client = await Client.open(server)
        assert "replay:lab-1" in client.hello["gaze_sources"]
        await client.send(type="gaze_source", name="replay:lab-1")
        assert (await client.note("state"))["gaze_source"] == "replay:lab-1"
        header, _ = await client.frame(lambda h: h.tracker)
        assert (header.gaze_x, header.gaze_y) == (0.25, 0.25)
        await client.send(type="gaze_source", name="replay:nothing")
        assert "no recording named 'nothing'" in (await client.note("error"))["message"]
        await client.ws.close()

    run(check())


def test_a_viewer_that_acks_gets_at_most_two_frames_in_flight(live_server) -> None:
    server = live_server(fps=20.0)
    in_flight = 2  # docs/protocol.md: once a viewer acks, at most 2 frames are in flight

    async def check() -> None:
        client = await Client.open(server)
        live = server.hub.sessions[client.hello["session"]]
        (viewer,) = live.viewers
        got = [(await client.frame())[0]]
        await client.send(type="ack", frame=got[0].frame)  # from now on: window of 2
        # Whatever was already on its way, then the window: the server stops sending.
        await until(lambda: viewer.window and not viewer.has_credit(), "the window to fill")
        while len(got) < viewer.sent:
            got.append((await client.frame())[0])
        # With everything acknowledged, exactly two frames come, and no third while the
        # session goes on.
        for header in got[1:]:
            await client.send(type="ack", frame=header.frame)
        window = [(await client.frame())[0] for _ in range(in_flight)]
        last = window[-1]
        # The session makes three more frames (MAX_IDLE_S apart, as nobody can take them).
        await until(lambda: live.session.frame > last.frame + 3, "the session to go on")
        assert viewer.sent == len(got) + in_flight, [h.frame for h in (*got, *window)]
        for header in window:
            await client.send(type="ack", frame=header.frame)
        resumed, _ = await client.frame()
        # The next frame shows the present, not one made before the stall ...
        assert resumed.frame >= last.frame + 3, (last, resumed)
        # ... the eye went on for the whole stall, and while nobody could take frames the
        # session made one every MAX_IDLE_S of its time, not more often (all but the first
        # step after the last frame sent, and the step that made this one).
        gap = resumed.time - last.time
        assert gap >= 2 * MAX_IDLE_S - 1e-6, (last, resumed)
        assert resumed.frame - last.frame - 2 <= gap / MAX_IDLE_S + 1e-6, (last, resumed)
        await client.ws.close()

    run(check())


def _serve_options(data_dir) -> dict:
    """`build_config`'s options as `gazehdr serve` would pass them, for a small test server."""
    return dict(
        host="127.0.0.1", port=0, scene="flash", scale=None, gaze="mouse", fps=30.0,
        size=(96, 54), fit_viewport=False, params_file=None, token="t", data_dir=data_dir,
        allow_origins=(), encoding="rgb10a2", backend="reference", seed=0,
    )  # fmt: skip


def test_serve_shows_frames_from_the_late_gaze_unless_told_not_to(tmp_path) -> None:
    """`gazehdr serve --no-late-gaze` reaches the sessions' settings (docs/server.md)."""
    from gazehdr.cli import build_parser
    from gazehdr.serve import build_config

    options = _serve_options(tmp_path)
    parser = build_parser()
    for argv, late in (["serve"], True), (["serve", "--no-late-gaze"], False):
        args = parser.parse_args(argv)
        assert build_config(**options, late_gaze=not args.no_late_gaze).session.late_gaze is late


def test_serve_can_start_sessions_in_split_view(live_server, tmp_path) -> None:
    """`gazehdr serve --split MODEL`: new sessions open with MODEL in the right pane."""
    from gazehdr.serve import build_config
    from gazehdr.sim.models import Models

    options = _serve_options(tmp_path)
    assert build_config(**options).session.split is None
    config = build_config(**options, split="jacobs+thompson")
    assert config.session.split == Models("jacobs", "thompson")
    server = live_server(split=config.session.split, size=(96, 54), fit_viewport=False)

    async def check() -> None:
        client = await Client.open(server)
        assert client.hello["split"] == {"afterimage": "jacobs", "acuity": "thompson"}
        header, _ = await client.frame()
        assert header.split and header.width == 96
        await client.ws.close()

    run(check())
