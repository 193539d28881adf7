"""What each viewer's frames travel as: the session's raw encoding, or a stream made from it.

A session's simulator writes one raw encoding (`f16` or `rgb10a2`, the server's `--encoding`);
a viewer may ask for a stream instead (`av1`, gazehdr.video: for viewers on another machine,
docs/deployment.md). `Streams` holds one encoder per stream in use and encodes each frame once
for all the viewers that chose it, on a thread of its own, so that encoding frame N overlaps
simulating frame N+1.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
from collections.abc import Callable

import numpy as np

from gazehdr import video
from gazehdr.protocol import RAW, Encoding, ProtocolError
from gazehdr.session import Frame

#: The encodings made from the raw frame, and how.
STREAMS = (Encoding.av1,)


def raw_pixels(frame: Frame) -> np.ndarray:
    """A raw frame's pixels as `Simulator.step` wrote them: H×W×3 float16 or H×W rgb10a2."""
    h = frame.header
    if h.encoding is Encoding.f16:
        return np.frombuffer(frame.payload, "<f2").reshape(h.height, h.width, 3)
    return np.frombuffer(frame.payload, "<u4").reshape(h.height, h.width)


Done = Callable[["concurrent.futures.Future[dict[Encoding, Frame]]"], None]


class Streams:
    """A session's streams, by encoding, encoded one frame at a time on their own thread."""

    def __init__(self, fps: float) -> None:
        self.fps = fps
        self._streams: dict[Encoding, video.Stream] = {}
        self._thread: concurrent.futures.ThreadPoolExecutor | None = None
        self._busy: concurrent.futures.Future[dict[Encoding, Frame]] | None = None

    def submit(self, frame: Frame, encodings: frozenset[Encoding], done: Done) -> bool:
        """Encode `frame` for `encodings` on the streams' thread, then call `done` (there) with
        the future of `encode`'s result. False, and nothing done, while the last frame is still
        being encoded: frames come faster than they can be coded, so this one is left out."""
        if not encodings:  # nobody watches: a new viewer starts a new stream
            if self._streams and self._thread is not None:  # where a stream may be encoding
                self._thread.submit(self._drop, list(self._streams))
            return True
        if self._busy is not None and not self._busy.done():
            return False
        if self._thread is None:
            self._thread = concurrent.futures.ThreadPoolExecutor(1, "gazehdr-encode")
        self._busy = self._thread.submit(self.encode, frame, encodings)
        self._busy.add_done_callback(done)
        return True

    def close(self) -> None:
        """The session ended: no more frames; one being encoded finishes on its own thread,
        which then ends the streams."""
        if self._thread is not None:
            self._thread.submit(self._drop, list(self._streams))
            self._thread.shutdown(wait=False, cancel_futures=False)
            self._thread = None
        else:
            self._drop(list(self._streams))

    def _drop(self, encodings: list[Encoding]) -> None:
        for encoding in encodings:
            stream = self._streams.pop(encoding, None)
            if stream is not None:
                stream.close()

    @staticmethod
    def is_stream(encoding: Encoding) -> bool:
        return encoding in STREAMS

    def check(self, encoding: Encoding) -> None:
        """A ProtocolError saying why `encoding` cannot be sent here, if it cannot."""
        if encoding in RAW:
            raise ProtocolError(
                f"this server's sessions send {encoding.name} frames only with --encoding "
                f"{encoding.name}; choose null (the session's raw frames) or av1",
                "encoding",
            )
        why = video.available()
        if why is not None:
            raise ProtocolError(why, "encoding")

    def want_key(self, encoding: Encoding | None) -> None:
        """The next packet of `encoding`'s stream is a keyframe (a new one starts with one)."""
        stream = self._streams.get(encoding) if encoding is not None else None
        if stream is not None:
            stream.want_key()

    def encode(self, frame: Frame, encodings: frozenset[Encoding]) -> dict[Encoding, Frame]:
        """`frame` in its own encoding and in each of `encodings`; streams no longer asked for
        are closed (a viewer that asks again starts a new one, with a keyframe)."""
        for gone in set(self._streams) - encodings:
            self._drop([gone])
        frames = {frame.header.encoding: frame}
        if not encodings:
            return frames
        pixels = raw_pixels(frame)
        size = (frame.header.width, frame.header.height)
        for encoding in encodings:
            stream = self._streams.get(encoding)
            if stream is None:
                stream = self._streams[encoding] = video.Stream(self.fps)
            packet, seconds = stream.encode(pixels, size)
            header = dataclasses.replace(
                frame.header,
                encoding=encoding,
                keyframe=packet.key,
                server_ms=frame.header.server_ms + seconds * 1e3,
            )
            frames[encoding] = dataclasses.replace(
                frame, header=header, payload=packet.data, encode_seconds=seconds
            )
        return frames
