"""uvicorn's WebSocket protocol (the websockets library's sans-I/O core) sending a large binary
message, a frame of the viewer's pixels, with one copy where it made three.

uvicorn hands each message to websockets' `send_binary`, whose `Frame.serialize` copies the
payload behind its header; then to asyncio's selector transport, which on Python 3.11 copies
what the socket did not take at once (about half of a 1080p frame's 8 MB) twice, by slicing the
bytes and by adding them to its buffer. Here a binary message of at least `LARGE` bytes on an
open connection without extensions goes out as its RFC 6455 header and a memoryview of the
payload: the transport copies the rest once. Everything else (text, small messages, the close,
the handshake, a connection that is closing) takes uvicorn's and websockets' own path.
"""

from __future__ import annotations

import struct
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.protocol import State

#: Messages from this size on are written directly (smaller ones: the copies cost nothing).
LARGE = 64 * 1024


def binary_header(n: int) -> bytes:
    """The header of a final, unmasked binary frame of n payload bytes (RFC 6455, 5.2): what
    websockets' `Frame(Opcode.BINARY, data).serialize(mask=False)` puts before the data."""
    if n < 126:
        return bytes((0x82, n))
    if n < 1 << 16:
        return struct.pack("!BBH", 0x82, 126, n)
    return struct.pack("!BBQ", 0x82, 127, n)


class FrameWritingProtocol(WebSocketsSansIOProtocol):
    """`uvicorn.Config(ws=FrameWritingProtocol)`: as "websockets-sansio", large binary
    messages written as header and payload."""

    async def send(self, message: Any) -> None:
        payload = message.get("bytes") if message["type"] == "websocket.send" else None
        if payload is None or len(payload) < LARGE:
            return await super().send(message)
        await self.writable.wait()  # flow control, as uvicorn's own send waits
        if (
            not self.handshake_complete
            or self.close_sent
            or self.transport.is_closing()  # gone: uvicorn's send raises ClientDisconnected
            or self.conn.state is not State.OPEN
            or self.conn.extensions
        ):
            return await super().send(message)
        # Both writes before any await: no other frame (a keepalive ping) comes between them.
        self.transport.write(binary_header(len(payload)))
        self.transport.write(memoryview(payload))
