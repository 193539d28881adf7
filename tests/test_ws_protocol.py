"""The WebSocket protocol our uvicorn runs (server/ws_protocol.py): a large binary message is
written as its header and payload, byte for byte the frame websockets would have made, and
received whole by the websockets library's client and by bench-live's frame client, beside the
messages that keep uvicorn's own path."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest
import websockets
from fastapi import FastAPI, WebSocket
from websockets.frames import Frame, Opcode

from gazehdr import ws_protocol
from gazehdr.bench.frame_client import FrameClient
from gazehdr.serve import UvicornThread
from gazehdr.ws_protocol import LARGE, binary_header

#: What the test app sends, in order, then it closes with 1000: large (written directly) and
#: small binary messages, text, and the sizes where the header's length changes form.
MESSAGES: list[bytes | str] = [
    bytes(range(256)) * 800,  # 204,800 bytes: the 64-bit length
    b"small",
    "text",
    bytes(LARGE),  # 65,536: just large, the 64-bit length
    bytes(LARGE - 1),  # 65,535: uvicorn's path, the 16-bit length
    bytes(3) * 3_000_000,  # 9 MB, more than the socket takes at once
]


@pytest.mark.parametrize("n", [0, 1, 125, 126, 127, 65_535, 65_536, 8_294_400])
def test_the_header_is_the_one_websockets_writes(n: int) -> None:
    data = bytes(n)
    assert binary_header(n) + data == Frame(Opcode.BINARY, data).serialize(mask=False)


@pytest.fixture
def server() -> Iterator[int]:
    app = FastAPI()

    @app.websocket("/ws")
    async def send_all(ws: WebSocket) -> None:
        await ws.accept()
        for m in MESSAGES:
            await (ws.send_text(m) if isinstance(m, str) else ws.send_bytes(m))
        await ws.close(1000)

    uv = UvicornThread(app)  # under serve.uvicorn_server, as every server of ours
    yield uv.port
    uv.stop()


def test_the_library_client_gets_every_message_whole(server: int, monkeypatch) -> None:
    written: list[int] = []

    def counted(n: int) -> bytes:  # which messages took the direct path
        written.append(n)
        return binary_header(n)

    monkeypatch.setattr(ws_protocol, "binary_header", counted)

    async def receive() -> tuple[list[bytes | str], int | None]:
        async with websockets.connect(f"ws://127.0.0.1:{server}/ws", max_size=None) as ws:
            got = [await ws.recv() for _ in MESSAGES]
            with pytest.raises(websockets.ConnectionClosedOK):
                await ws.recv()
            return got, ws.close_code

    got, code = asyncio.run(receive())
    assert got == MESSAGES and code == 1000
    assert written == [len(m) for m in MESSAGES if isinstance(m, bytes) and len(m) >= LARGE]


def test_the_frame_client_reads_them_in_place(server: int) -> None:
    async def receive() -> list[bytes | str]:
        url = f"ws://127.0.0.1:{server}/ws"
        client = await FrameClient.connect(url, max_message=10_000_000)
        got: list[bytes | str] = []
        try:
            for _ in MESSAGES:
                m = await client.recv()  # a view of the client's buffer, until the next recv
                got.append(m if isinstance(m, str) else bytes(m))
        finally:
            await client.close()
        return got

    assert asyncio.run(receive()) == MESSAGES
