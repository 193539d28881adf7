"""Limits under concurrency, and memory given back, against a real uvicorn.

The server's resident memory over sessions is measured by `tests/session_memory.py` on a real
`gazehdr serve` process (too noisy for an assertion here: the test process holds pytest, the
client and everything other tests left); this test asserts what that figure rests on: every
object holding a session's memory (its simulators' device buffers live in their backends) is
freed as soon as the session ends, by reference counting, with the garbage collector off.
"""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import json
import socket
import urllib.error
import urllib.request
import weakref

import pytest
import websockets
from waiting import until
from websockets.exceptions import ConnectionClosed

from gazehdr.app import CLOSE_BUSY, CLOSE_INTERNAL


async def _viewer(
    url: str, admitted: list[str], refused: list[tuple[int, str]], leave, auth: dict[str, str]
) -> None:
    """Open /ws/view with the credential `auth`: admitted (a hello, then a frame) it waits for
    `leave`; refused, it notes the close code and reason."""
    try:
        async with websockets.connect(url, max_size=None, additional_headers=auth) as ws:
            while True:
                message = await ws.recv()
                if isinstance(message, bytes):  # a frame: the session runs
                    break
            admitted.append("ok")
            await leave.wait()
    except ConnectionClosed as e:
        refused.append((e.rcvd.code, e.rcvd.reason) if e.rcvd else (None, ""))


def _session_objects(hub) -> list[weakref.ref]:
    """Weak references to what holds each running session's memory."""
    refs = []
    for live in hub.sessions.values():
        refs.extend(weakref.ref(o) for o in (live, live.session, live.session.eye))
        for sim in live.session.eye.sims:
            refs.extend([weakref.ref(sim), weakref.ref(sim._backend)])
    return refs


@pytest.fixture
def no_gc():
    """The cyclic garbage collector off: what is freed is freed by reference counting."""
    gc.collect()
    gc.disable()
    yield
    gc.enable()


def test_thirty_viewers_at_once_get_eight_sessions_then_memory_goes_back(live_server, no_gc):
    server = live_server(max_sessions=8, size=(64, 48), session_grace_s=0.0)
    url = f"{server.ws_url}/ws/view"
    admitted: list[str] = []
    refused: list[tuple[int, str]] = []
    held: list[weakref.ref] = []

    async def check() -> None:
        leave = asyncio.Event()
        tasks = [
            asyncio.create_task(_viewer(url, admitted, refused, leave, server.auth))
            for _ in range(30)
        ]
        await until(lambda: len(admitted) + len(refused) == 30, "every viewer's answer")
        assert len(admitted) == 8, (admitted, refused)
        assert len(server.hub.sessions) == 8
        assert {code for code, _ in refused} == {CLOSE_BUSY}, refused
        (reason,) = {reason for _, reason in refused}
        assert reason.startswith("server busy: it runs 8 sessions (the limit)"), reason
        held.extend(_session_objects(server.hub))
        leave.set()
        await asyncio.gather(*tasks)
        await until(lambda: not server.hub.sessions, "the sessions to end")
        await until(lambda: all(r() is None for r in held), "every session's objects freed")

    asyncio.run(check())
    assert server.hub.starting == 0
    assert len(held) == 8 * 5


def test_a_sessions_viewer_limit_holds_when_viewers_join_at_once(live_server) -> None:
    server = live_server(size=(64, 48))
    server.hub.max_viewers = 3
    admitted: list[str] = []
    refused: list[tuple[int, str]] = []

    async def check() -> None:
        leave = asyncio.Event()
        first = asyncio.create_task(
            _viewer(f"{server.ws_url}/ws/view", admitted, refused, leave, server.auth)
        )
        await until(lambda: admitted, "the first viewer's session")
        (session,) = server.hub.sessions
        url = f"{server.ws_url}/ws/view?session={session}"
        tasks = [
            asyncio.create_task(_viewer(url, admitted, refused, leave, server.auth))
            for _ in range(10)
        ]
        await until(lambda: len(admitted) + len(refused) == 11, "every viewer's answer")
        assert len(admitted) == 3 and len(server.hub.sessions[session].viewers) == 3
        assert {code for code, _ in refused} == {CLOSE_BUSY}
        assert all("has 3 viewers (the limit)" in reason for _, reason in refused), refused
        leave.set()
        await asyncio.gather(first, *tasks)

    asyncio.run(check())


def test_a_session_that_fails_to_start_gives_its_slot_back(live_server) -> None:
    server = live_server(max_sessions=2, size=(64, 48))
    good = server.hub.settings
    server.hub.settings = dataclasses.replace(good, scene="no-such-scene")
    admitted: list[str] = []
    refused: list[tuple[int, str]] = []

    async def check() -> None:
        leave = asyncio.Event()
        url = f"{server.ws_url}/ws/view"
        await asyncio.gather(
            *[_viewer(url, admitted, refused, leave, server.auth) for _ in range(5)]
        )
        # Two were building at once (the limit), the others busy or failing in their turn.
        codes = [code for code, _ in refused]
        assert not admitted and set(codes) <= {CLOSE_INTERNAL, CLOSE_BUSY}, refused
        assert codes.count(CLOSE_INTERNAL) >= 2, refused
        assert server.hub.starting == 0 and not server.hub.sessions
        server.hub.settings = good  # both slots are free again
        admitted.clear(), refused.clear()
        tasks = [
            asyncio.create_task(_viewer(url, admitted, refused, leave, server.auth))
            for _ in range(2)
        ]
        await until(lambda: len(admitted) + len(refused) == 2, "both viewers' answers")
        assert len(admitted) == 2, refused
        leave.set()
        await asyncio.gather(*tasks)

    asyncio.run(check())


def test_uploads_beyond_the_limit_are_refused_while_one_is_in_flight(live_server) -> None:
    """With `max_uploads=1`, an upload whose body is still arriving holds the one slot: another
    gets 503 with Retry-After and a reason, and once the first has finished the next goes in."""
    server = live_server(max_uploads=1)
    slots = server.app.state.uploads
    body = b"#?RADIANCE\n" + bytes(200)  # not an image: the first upload ends in a 422
    head = (
        f"PUT /api/scenes/slow HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
        f"Authorization: Bearer {server.token}\r\nContent-Length: {len(body)}\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as slow:
        slow.sendall(head + body[:10])  # the rest is held back: the upload stays in flight
        asyncio.run(until(lambda: slots.busy == 1, "the first upload to take its slot"))
        request = urllib.request.Request(
            f"{server.url}/api/scenes/other", data=b"x", method="PUT", headers=server.auth
        )
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=30)
        assert refused.value.code == 503 and refused.value.headers["Retry-After"] == "1"
        assert "1 uploads at once" in json.loads(refused.value.read())["detail"]
        slow.sendall(body[10:])
        assert b" 422 " in slow.recv(4096).split(b"\r\n")[0] + b" "
    asyncio.run(until(lambda: slots.busy == 0, "the first upload to give its slot back"))
    with pytest.raises(urllib.error.HTTPError) as answered:  # admitted: refused as no image
        urllib.request.urlopen(request, timeout=30)
    assert answered.value.code == 422
