"""bench-live's plain WebSocket client: each message read straight into one reused buffer.

A browser's network stack hands the page each message once. The `websockets` library's asyncio
client copies it on the way: every 256 KiB read is appended to its buffer, then the frame is
cut out of that. At 1920×1080 rgb10a2 (8 MB a frame, 60 a second) those copies took a sixth of
a 2-core machine, in the server's own process and under its GIL, so the benchmark measured its
client as much as the server (docs/performance.md, "The benchmark's client").

Here `loop.sock_recv_into` writes each payload where it is read, and the rest stays the
library's: the opening handshake (the request, and the check of the server's answer) is its
sans-I/O `ClientProtocol`, and the frames we send are its `Frame.serialize` (masked, as a
client's must be). What is ours is reading RFC 6455's frames (§5.2; a server's are unmasked):
`header_size` and `payload_length` below, tested against the library's own server.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
from types import TracebackType

from websockets.client import ClientProtocol
from websockets.frames import Close, Frame, Opcode
from websockets.protocol import State
from websockets.uri import parse_uri

#: The largest message taken (a 3840×2160 float16 frame is 50 MB).
MAX_MESSAGE = 64 << 20

_HANDSHAKE_MAX = 64 << 10  # bytes of the server's answer to the opening handshake


class FrameClientError(ConnectionError):
    """The server closed, refused the handshake, or sent what RFC 6455 does not allow."""


def header_size(first_two: bytes) -> tuple[Opcode, bool, int]:
    """From a frame's first two bytes: its opcode, whether it ends its message (FIN), and how
    many more header bytes follow (the 16- or 64-bit length; a server sends no mask)."""
    b0, b1 = first_two
    if b0 & 0x70:
        raise FrameClientError("a frame with reserved bits set (no extension was agreed)")
    if b1 & 0x80:
        raise FrameClientError("a masked frame from the server (RFC 6455 §5.1)")
    try:
        opcode = Opcode(b0 & 0x0F)
    except ValueError:
        raise FrameClientError(f"unknown opcode {b0 & 0x0F}") from None
    n = b1 & 0x7F
    return opcode, bool(b0 & 0x80), {126: 2, 127: 8}.get(n, 0)


def payload_length(first_two: bytes, extended: bytes) -> int:
    """The payload's length: 7 bits, or the 16- or 64-bit big-endian length after them."""
    n = first_two[1] & 0x7F
    if n < 126:
        return n
    return struct.unpack("!H" if n == 126 else "!Q", extended)[0]


class FrameClient:
    """One connection. `recv` returns a text message as str and a binary one as a memoryview of
    the reused buffer, valid until the next `recv`; pings are answered on the way."""

    def __init__(self, sock: socket.socket, rest: bytes, max_message: int = MAX_MESSAGE) -> None:
        self._sock = sock
        self._loop = asyncio.get_running_loop()
        self._pending = bytearray(rest)  # read past the handshake's end: the first frames
        self._buf = bytearray(1 << 16)
        self._small = bytearray(125)  # a control frame's payload, at most 125 bytes
        self._max = max_message

    @classmethod
    async def connect(
        cls, url: str, headers: dict[str, str] | None = None, max_message: int = MAX_MESSAGE
    ) -> FrameClient:
        """Open `url` (ws://host:port/path) with these extra request headers."""
        uri = parse_uri(url)
        if uri.secure:
            raise ValueError("FrameClient speaks ws:// only (loopback benchmarks)")
        protocol = ClientProtocol(uri)
        request = protocol.connect()
        for name, value in (headers or {}).items():
            request.headers[name] = value
        protocol.send_request(request)
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setblocking(False)
        try:
            await loop.sock_connect(sock, (uri.host, uri.port))
            await loop.sock_sendall(sock, b"".join(protocol.data_to_send()))
            answer = b""
            while b"\r\n\r\n" not in answer:  # the handshake's end; frames may follow it
                chunk = await loop.sock_recv(sock, 4096)
                if not chunk or len(answer) > _HANDSHAKE_MAX:
                    raise FrameClientError("the server did not finish the handshake")
                answer += chunk
            head, rest = answer.split(b"\r\n\r\n", 1)
            protocol.receive_data(head + b"\r\n\r\n")  # parsed and checked by the library
            if protocol.state is not State.OPEN:  # a refusal may have a body not read here
                status = head.split(b"\r\n", 1)[0].decode("latin-1")
                raise FrameClientError(f"handshake refused: {protocol.handshake_exc or status}")
        except BaseException:
            sock.close()
            raise
        return cls(sock, rest, max_message)

    async def _read(self, into: memoryview) -> None:
        """Fill `into` from what the handshake left, then from the socket."""
        n = min(len(into), len(self._pending))
        into[:n] = self._pending[:n]
        del self._pending[:n]
        while n < len(into):
            got = await self._loop.sock_recv_into(self._sock, into[n:])
            if got == 0:
                raise FrameClientError("the server closed the connection")
            n += got

    async def _frame_header(self) -> tuple[Opcode, bool, int]:
        head = bytearray(10)
        view = memoryview(head)
        await self._read(view[:2])
        opcode, fin, more = header_size(head[:2])
        await self._read(view[2 : 2 + more])
        return opcode, fin, payload_length(head[:2], head[2 : 2 + more])

    async def recv(self) -> memoryview | str:
        size, kind = 0, None  # the message so far, and its opcode (TEXT or BINARY)
        while True:
            opcode, fin, n = await self._frame_header()
            if opcode in (Opcode.PING, Opcode.PONG, Opcode.CLOSE):
                if n > 125 or not fin:
                    raise FrameClientError("a control frame over 125 bytes or fragmented")
                payload = memoryview(self._small)[:n]
                await self._read(payload)
                if opcode is Opcode.PING:
                    await self._send(Frame(Opcode.PONG, bytes(payload)))
                elif opcode is Opcode.CLOSE:
                    raise FrameClientError(f"the server closed: {Close.parse(bytes(payload))}")
                continue
            if (opcode is Opcode.CONT) != (kind is not None):
                raise FrameClientError("a continuation frame out of place")
            kind = kind or opcode
            if size + n > self._max:
                raise FrameClientError(f"a message over {self._max} bytes")
            if len(self._buf) < size + n:  # a new buffer: views of the old one stay valid
                grown = bytearray(size + n)
                grown[:size] = self._buf[:size]
                self._buf = grown
            await self._read(memoryview(self._buf)[size : size + n])
            size += n
            if fin:
                message = memoryview(self._buf)[:size]
                return str(message, "utf-8") if kind is Opcode.TEXT else message

    async def send(self, text: str) -> None:
        await self._send(Frame(Opcode.TEXT, text.encode()))

    async def _send(self, frame: Frame) -> None:
        await self._loop.sock_sendall(self._sock, frame.serialize(mask=True))

    async def close(self) -> None:
        """Say so (close code 1000) and close the socket; the server's answer is not awaited."""
        with contextlib.suppress(OSError):  # the server may have gone first
            await self._send(Frame(Opcode.CLOSE, Close(1000, "").serialize()))
        self._sock.close()

    async def __aenter__(self) -> FrameClient:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()
