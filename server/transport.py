"""What each viewer's frames travel as: the session's raw encoding, or a stream made from it.

A session's simulator writes one raw encoding (`f16` or `rgb10a2`, the server's `--encoding`);
a viewer may ask for a stream instead (`h264`, `av1`, gazehdr.video: for viewers on another
machine, docs/deployment.md). `Streams` holds one encoder per stream in use and encodes each
frame once for all the viewers that chose it, on a thread of its own, so that encoding frame N
overlaps simulating frame N+1, and the session simulates no further ahead of its encoder than
that.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import logging
from collections.abc import Callable, Iterable
from typing import Any, Protocol

import numpy as np

from gazehdr import video
from gazehdr.metrics import Metrics
from gazehdr.protocol import RAW, STREAMS, Encoding, ProtocolError
from gazehdr.session import Frame

log = logging.getLogger("gazehdr.transport")


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
        #: A frame made while the last was being encoded: it goes next (`encode_waiting`).
        self._waiting: tuple[Frame, frozenset[Encoding], Done] | None = None
        self._dropping = False  # `idle` has sent the streams' end to their thread

    @property
    def backlogged(self) -> bool:
        """A frame waits for the encoder: a frame made now could only take its place."""
        return self._waiting is not None

    @property
    def waiting_for(self) -> frozenset[Encoding]:
        """The streams the waiting frame is for (none: no frame waits)."""
        return frozenset() if self._waiting is None else self._waiting[1]

    def leave_out_waiting(self) -> None:
        """The waiting frame is not encoded after all (its viewers could not take it now)."""
        self._waiting = None

    def idle(self) -> None:
        """Nobody watches a stream: end them (on their thread, where one may be encoding), so
        that a new viewer starts a new stream; once, not at every frame until that is done."""
        self._waiting = None
        if self._streams and self._thread is not None and not self._dropping:
            self._dropping = True
            self._thread.submit(self._drop_all)

    def _drop_all(self) -> None:
        self._drop(list(self._streams))
        self._dropping = False

    def submit(self, frame: Frame, encodings: frozenset[Encoding], done: Done) -> bool:
        """Encode `frame` for `encodings` on the streams' thread, then call `done` (there) with
        the future of `encode`'s result. While the last frame is still being encoded, `frame`
        waits, to go as soon as the encoder is free (`encode_waiting`). True where this left a
        frame that was waiting out (this one is newer)."""
        left_out = self._waiting is not None
        self._waiting = (frame, encodings, done)
        self.encode_waiting()
        return left_out

    def encode_waiting(self) -> None:
        """Start encoding the frame that waits, if the encoder is free (the event loop calls
        this once the last frame's encoding has ended, its packets out or its error told)."""
        if self._waiting is None or (self._busy is not None and not self._busy.done()):
            return
        (frame, encodings, done), self._waiting = self._waiting, None
        if self._thread is None:
            self._thread = concurrent.futures.ThreadPoolExecutor(1, "gazehdr-encode")
        self._busy = self._thread.submit(self.encode, frame, encodings)
        self._busy.add_done_callback(done)

    def close(self) -> None:
        """The session ended: no more frames; one being encoded finishes on its own thread,
        which then ends the streams."""
        self._waiting = None
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
                f"{encoding.name}; choose null (the session's raw frames), h264 or av1",
                "encoding",
            )
        why = video.available(encoding.name)
        if why is not None:
            raise ProtocolError(why, "encoding")

    def want_key(self, encoding: Encoding | None) -> None:
        """The next packet of `encoding`'s stream is a keyframe (a new one starts with one)."""
        stream = self._streams.get(encoding) if encoding is not None else None
        if stream is not None:
            stream.want_key()

    def encode(self, frame: Frame, encodings: frozenset[Encoding]) -> dict[Encoding, Frame]:
        """`frame` in each of `encodings` (streams); streams no longer asked for are closed (a
        viewer that asks again starts a new one, with a keyframe)."""
        for gone in set(self._streams) - encodings:
            self._drop([gone])
        frames: dict[Encoding, Frame] = {}
        pixels = raw_pixels(frame)
        size = (frame.header.width, frame.header.height)
        for encoding in encodings:
            stream = self._streams.get(encoding)
            if stream is None:
                stream = self._streams[encoding] = video.Stream(self.fps, encoding.name)
            packet, seconds = stream.encode(pixels, size)
            header = dataclasses.replace(
                frame.header,
                encoding=encoding,
                keyframe=packet.key,
                server_ms=frame.header.server_ms + seconds * 1e3,
            )
            frames[encoding] = dataclasses.replace(
                frame, header=header, plain=header.pack() + packet.data, encode_seconds=seconds
            )
        return frames


class Viewer(Protocol):
    """What this module needs of a viewer (gazehdr.live.Viewer, which imports this module)."""

    encoding: Encoding | None
    keyed: bool
    warp: bool  # the late gaze warp (gazehdr.warp): raw frames of their own, never a stream
    mailbox: Any  # gazehdr.live.Mailbox: `frame`, `dropped`, `put`

    def has_credit(self) -> bool: ...

    def wants_frame(self) -> bool: ...


class StreamViewers:
    """A session's viewers that chose a stream: their choice, what they are sent and when.

    A packet is of use to a viewer only after every one since its last keyframe, so a stream's
    packets are never dropped as raw frames are: a frame is left out of a stream (its viewers
    miss a frame, the stream stays whole) while a viewer of the stream could not take a packet
    now (its window is full, or a packet waits unsent), and when a newer frame takes its place
    while it waits for the encoder: a stream runs at the pace of its slowest viewer, so a slow
    link gets fewer frames, not gaps and the keyframes they would cost. A viewer that lost its
    stream anyway (it asked, after a corrupt packet) gets nothing until the keyframe that is
    then made.
    """

    def __init__(self, raw: Encoding, fps: float, metrics: Metrics) -> None:
        self.raw = raw
        self.metrics = metrics
        self.streams = Streams(fps)

    def takes(self, viewer: Viewer) -> bool:
        """Whether `viewer` gets a stream rather than the raw frames."""
        return viewer.encoding is not None and self.streams.is_stream(viewer.encoding)

    def wants_frame(self, viewer: Viewer) -> bool:
        """`viewer.wants_frame()`, and for a stream's viewer, no frame waiting for the encoder
        already: the session makes no frame that could only take that one's place, so the
        encoder, sharing the CPU with the simulation, gets the time such frames would cost."""
        return viewer.wants_frame() and not (self.takes(viewer) and self.streams.backlogged)

    def choose(self, viewer: Viewer, encoding: Encoding | None) -> None:
        """`viewer` gets frames in `encoding` from the next one on (a stream: from a keyframe);
        a ProtocolError, and nothing changes, when it cannot be served."""
        if encoding is not None and encoding is not self.raw:
            self.streams.check(encoding)
        if viewer.warp and self.streams.is_stream(encoding):
            raise ProtocolError(
                f"this viewer has the late gaze warp on, whose frames are not {encoding.name}: "
                'send {"type": "warp", "on": false} first',
                "encoding",
            )
        viewer.encoding, viewer.keyed = encoding, False
        self.streams.want_key(encoding)

    def warp(self, viewer: Viewer, on: bool) -> None:
        """The late gaze warp on or off for `viewer` (gazehdr.warp); a ProtocolError, and
        nothing changes, for a viewer that takes a stream: warp frames are raw."""
        if on and self.takes(viewer):
            raise ProtocolError(
                f"the late gaze warp sends raw frames, not {viewer.encoding.name}: "
                'send {"type": "encoding", "name": null} first',
                "warp",
            )
        viewer.warp = on

    def want_key(self, viewer: Viewer) -> None:
        """`viewer` lost its stream: nothing more until a keyframe, which comes next."""
        viewer.keyed = False
        self.streams.want_key(viewer.encoding)

    def publish(self, frame: Frame, viewers: Iterable[Viewer]) -> None:
        """Encode `frame` for the streams `viewers` chose, on the streams' thread while the
        next step runs; each packet then goes to their mailboxes, on the event loop."""
        viewers = list(viewers)
        encodings = frozenset(v.encoding for v in viewers if self.takes(v))
        if not encodings:
            self.streams.idle()
            return
        if self._blocked(viewers, encodings):
            self._missed(viewers, encodings)
            return
        loop = asyncio.get_running_loop()

        def done(work: concurrent.futures.Future[dict[Encoding, Frame]]) -> None:
            with contextlib.suppress(RuntimeError):  # the loop closed: the server stopped
                if work.cancelled():
                    return
                if (error := work.exception()) is not None:
                    loop.call_soon_threadsafe(self._failed, viewers, error)
                else:
                    loop.call_soon_threadsafe(self._deliver, viewers, work.result())

        if self.streams.submit(frame, encodings, done):
            self._missed(viewers, encodings)

    def close(self) -> None:
        self.streams.close()

    @staticmethod
    def _blocked(viewers: list[Viewer], encodings: frozenset[Encoding]) -> bool:
        """Whether a viewer of these streams could not take a packet now (its window is full, or
        a packet waits unsent): the frame is then left out, not its packet out of the stream."""
        return any(v.encoding in encodings and v.keyed and not v.wants_frame() for v in viewers)

    def _deliver(self, viewers: list[Viewer], frames: dict[Encoding, Frame]) -> None:
        m = self.metrics
        for frame in frames.values():
            m.stream_encode_seconds.observe(frame.encode_seconds)
        for viewer in viewers:
            frame = frames.get(viewer.encoding) if self.takes(viewer) else None
            if frame is not None:
                m.frames_dropped.inc(self._offer(viewer, frame))
        self._encode_waiting(viewers)

    def _encode_waiting(self, viewers: list[Viewer]) -> None:
        """The last frame's encoding has ended: the frame that waited goes now, unless, with that
        one's packet offered, a viewer of its streams could not take another (`publish`'s check,
        made again): then it is left out."""
        encodings = self.streams.waiting_for
        if encodings and self._blocked(viewers, encodings):
            self.streams.leave_out_waiting()
            self._missed(viewers, encodings)
            return
        self.streams.encode_waiting()

    def _offer(self, viewer: Viewer, frame: Frame) -> int:
        """Put a packet in the viewer's mailbox, never in place of one still waiting (the next
        packet needs it); how many frames it missed (0 or 1)."""
        key = frame.header.keyframe
        if (key or (viewer.keyed and viewer.mailbox.frame is None)) and viewer.has_credit():
            viewer.keyed = True
            return viewer.mailbox.put(frame)
        if viewer.keyed or key:
            self.want_key(viewer)
        viewer.mailbox.dropped += 1
        return 1

    def _failed(self, viewers: list[Viewer], error: BaseException) -> None:
        self._encode_waiting(viewers)  # the frame that waited goes on, as after a success
        log.error("encoding a stream failed: %s", error)
        note = {"type": "error", "message": f"encoding failed: {error}", "in": "encoding"}
        for viewer in viewers:
            if self.takes(viewer):
                viewer.mailbox.put(None, [note])

    def _missed(self, viewers: list[Viewer], encodings: frozenset[Encoding]) -> None:
        """A frame left out of `encodings`' streams: a dropped frame for each of their viewers."""
        for viewer in viewers:
            if viewer.encoding in encodings:
                viewer.mailbox.dropped += 1
                self.metrics.frames_dropped.inc()
