"""bench-live's WebSocket client (gazehdr.bench.frame_client) reads what the `websockets`
library's real server sends: frames of every length form, fragmented messages, pings (answered),
text, and the close; and our server's frames, with its credential asked for."""

from __future__ import annotations

import asyncio
import json
import tempfile
from pathlib import Path

import pytest
from websockets.asyncio.server import serve
from websockets.frames import Frame, Opcode

from gazehdr.bench.frame_client import (
    FrameClient,
    FrameClientError,
    header_size,
    payload_length,
)


@pytest.mark.parametrize("n", [0, 1, 125, 126, 127, 65535, 65536, 70000])
@pytest.mark.parametrize("opcode", [Opcode.TEXT, Opcode.BINARY, Opcode.CONT, Opcode.PING])
def test_header_reads_the_librarys_frames(n: int, opcode: Opcode) -> None:
    """Each of RFC 6455's three length forms, as the library writes a server's frame."""
    if opcode is Opcode.PING and n > 125:
        return  # a control frame carries at most 125 bytes
    for fin in (True, False) if opcode is not Opcode.PING else (True,):
        wire = Frame(opcode, bytes(n), fin=fin).serialize(mask=False)
        got_opcode, got_fin, more = header_size(wire[:2])
        assert (got_opcode, got_fin) == (opcode, fin)
        assert payload_length(wire[:2], wire[2 : 2 + more]) == n
        assert len(wire) == 2 + more + n  # the payload starts right after


@pytest.mark.parametrize(
    "first_two, names",
    [
        (bytes([0x82 | 0x40, 5]), "reserved bits"),
        (bytes([0x82, 0x80 | 5]), "masked"),
        (bytes([0x83, 5]), "opcode 3"),
    ],
)
def test_header_refuses_what_a_server_may_not_send(first_two: bytes, names: str) -> None:
    with pytest.raises(FrameClientError, match=names):
        header_size(first_two)


def _run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


def test_reads_the_library_servers_messages_and_answers_its_ping() -> None:
    big = bytes(range(256)) * 300  # 76800 bytes: the 64-bit length form
    pinged: list[float] = []

    async def handler(ws) -> None:
        await ws.send("hello")
        await ws.send(big)
        await ws.send([b"ab", b"cd", b"ef"])  # one message in three frames
        await ws.send([b"x" * 40000, b"y" * 40000])  # and past the first buffer
        pong = await ws.ping(b"are you there")
        pinged.append(await asyncio.wait_for(pong, 10))  # our client's pong
        await ws.send(bytes(300))  # the 16-bit form
        await ws.send(await ws.recv())  # our masked text, back
        await ws.close()

    async def client() -> list:
        async with serve(handler, "127.0.0.1", 0, max_size=None) as server:
            port = server.sockets[0].getsockname()[1]
            got: list = []
            async with await FrameClient.connect(f"ws://127.0.0.1:{port}/") as ws:
                got.append(await ws.recv())
                got.append(bytes(await ws.recv()))
                got.append(bytes(await ws.recv()))
                got.append(bytes(await ws.recv()))
                got.append(bytes(await ws.recv()))  # the ping was answered on the way
                await ws.send("é, back")
                got.append(await ws.recv())
                with pytest.raises(FrameClientError, match="closed: 1000"):
                    await ws.recv()
            return got

    got = _run(client())
    assert got == ["hello", big, b"abcdef", b"x" * 40000 + b"y" * 40000, bytes(300), "é, back"]
    assert len(pinged) == 1


def test_a_view_stays_as_it_was_when_a_larger_message_comes() -> None:
    """A binary message is a view of the client's buffer: a larger message after it gets a new
    buffer, so a view still held is not changed (nor a BufferError raised)."""

    async def handler(ws) -> None:
        await ws.send(b"\x01" * 10)
        await ws.send(b"\x02" * 200_000)
        await ws.close()

    async def client() -> tuple[bytes, bytes]:
        async with serve(handler, "127.0.0.1", 0, max_size=None) as server:
            port = server.sockets[0].getsockname()[1]
            async with await FrameClient.connect(f"ws://127.0.0.1:{port}/") as ws:
                first = await ws.recv()
                second = await ws.recv()
                return bytes(first), bytes(second[:3])

    assert _run(client()) == (b"\x01" * 10, b"\x02" * 3)


def test_a_message_over_the_limit_is_refused() -> None:
    async def handler(ws) -> None:
        await ws.send(bytes(5000))
        await ws.wait_closed()

    async def client() -> None:
        async with serve(handler, "127.0.0.1", 0, max_size=None) as server:
            port = server.sockets[0].getsockname()[1]
            ws = await FrameClient.connect(f"ws://127.0.0.1:{port}/", max_message=4096)
            try:
                with pytest.raises(FrameClientError, match="over 4096 bytes"):
                    await ws.recv()
            finally:
                await ws.close()

    _run(client())


def test_a_refused_handshake_says_so() -> None:
    """The library's server answers 403 instead of switching protocols."""
    from http import HTTPStatus

    def refuse(connection, request):
        return connection.respond(HTTPStatus.FORBIDDEN, "no\n")

    async def handler(ws) -> None:  # never reached
        await ws.close()

    async def client() -> None:
        async with serve(handler, "127.0.0.1", 0, process_request=refuse) as server:
            port = server.sockets[0].getsockname()[1]
            with pytest.raises(FrameClientError, match=r"handshake refused: .*403"):
                await FrameClient.connect(f"ws://127.0.0.1:{port}/")

    _run(client())


def test_our_server_frames_and_credential() -> None:
    """gazehdr's server: without the credential it closes with 4401; with it, frames
    come whose header says the session's size, and a gaze we send comes back in one."""
    from gazehdr.app import ServerConfig
    from gazehdr.protocol import Encoding, split_frame
    from gazehdr.serve import BackgroundServer
    from gazehdr.session import SessionSettings

    settings = SessionSettings(
        width=96, height=54, fps=30, scene="lamp", fit_viewport=False, encoding=Encoding.rgb10a2
    )

    async def client(live) -> None:
        url = f"{live.ws_url}/ws/view"
        async with await FrameClient.connect(url) as ws:  # accepted, then closed: 4401
            with pytest.raises(FrameClientError, match="closed: 4401 "):
                await ws.recv()
        async with await FrameClient.connect(url, live.auth) as ws:
            await ws.send(json.dumps({"type": "gaze", "x": 0.25, "y": 0.5, "seq": 7}))
            for _ in range(200):
                message = await ws.recv()
                if isinstance(message, str):
                    json.loads(message)
                    continue
                header, payload = split_frame(message)
                assert (header.width, header.height) == (96, 54)
                assert len(payload) == 96 * 54 * 4
                if header.gaze_seq == 7:
                    return
            raise AssertionError("no frame used the gaze sent")

    with tempfile.TemporaryDirectory() as data:
        live = BackgroundServer(ServerConfig(session=settings, data_dir=Path(data)))
        try:
            _run(client(live))
        finally:
            live.stop()
