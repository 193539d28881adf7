"""The `av1` encoding: frames as a 10-bit AV1 stream, for viewers on another machine.

A raw frame is 4-6 bytes per pixel (2 Gbit/s at 1080p and 30 fps); a real network gives far
less, so a remote viewer gets a lossy stream that keeps 10 bits where the dither needs them: the
display values `v` go to Y'CbCr 4:2:0 with 10 bits per sample (BT.709 coefficients, full range,
so a grey ramp keeps all 1024 levels of `rgb10a2`), SVT-AV1 codes them in its low-delay
real-time mode (no B-frames: one frame in, one packet out), and the browser decodes them with
WebCodecs (`web/video.js`), converting back to RGB in the dither shader. The conversion both
ways is ours (gazehdr.yuv; `web/renderer.js` for the way back), not a library's, so the two ends
agree to the last bit.

PyAV (FFmpeg's libraries, the `video` extra) is imported only when a stream is opened: a server
without it serves the raw encodings and refuses `av1` with a message saying what to install.
"""

from __future__ import annotations

import contextlib
import fractions
import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from gazehdr.drivers.errors import GazehdrError, InputError
from gazehdr.yuv import Converter, to_rgb, to_yuv420p10

__all__ = ["CODEC", "Decoder", "Encoder", "Packet", "Stream", "available", "to_rgb"]

#: WebCodecs' name for the stream: AV1 main profile, level 4.0 (1080p at 30 fps), main tier,
#: 10 bits. Chromium decodes it in software (dav1d).
CODEC = "av01.0.08M.10"
log = logging.getLogger("gazehdr.video")
#: The stream's quality: SVT-AV1's constant rate factor (lower is better; 63 the worst). Its
#: real-time mode (rtc=1) at preset 10 kept the luma error of moving simulated frames at half
#: the 99th percentile of its default low-delay mode's at preset 12, for fewer bytes (measured on
#: tests/test_video.py's frames). Low delay has no bit-rate cap in SVT-AV1 ("max bit rate only
#: with tpl"), so what 1080p costs is measured (`gazehdr bench-live --link-mbit`).
CRF = 8
PRESET = 10
#: Keyframes asked for (a new viewer, a lost or corrupt packet) come at most this often: each
#: costs every viewer of the stream a large packet.
MIN_KEY_INTERVAL_S = 0.25


class VideoUnavailableError(GazehdrError, RuntimeError):
    """PyAV (or its SVT-AV1 encoder, or dav1d) is missing; the message says what to install."""


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise VideoUnavailableError(
            "the av1 encoding needs PyAV: pip install 'gazehdr[video]'"
        ) from None
    return av


def available() -> str | None:
    """None when `av1` can be served, else why not."""
    try:
        av = _av()
    except VideoUnavailableError as e:
        return str(e)
    try:
        av.codec.Codec("libsvtav1", "w")
    except ValueError:  # UnknownCodecError
        return "this PyAV build has no SVT-AV1 encoder (libsvtav1), which the av1 encoding uses"
    return None


@dataclass(frozen=True)
class Packet:
    data: bytes
    key: bool


class Encoder:
    """One AV1 stream of frames of one size: `encode` takes a raw frame, returns its packet."""

    def __init__(
        self, size: tuple[int, int], fps: float, *, crf: int = CRF, preset: int = PRESET,
        threads: int = 2,
    ) -> None:  # fmt: skip
        av = _av()
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 logs its configuration otherwise
        self.size = size
        w, h = size
        c = av.CodecContext.create("libsvtav1", "w")
        c.width, c.height, c.pix_fmt = w + w % 2, h + h % 2, "yuv420p10le"
        c.time_base = fractions.Fraction(1, 1000)
        c.framerate = fractions.Fraction(round(fps * 1000), 1000)
        c.max_b_frames = 0
        c.gop_size = 1 << 30  # keyframes only when asked for (`key=True`)
        c.color_range = 2  # full (AVCOL_RANGE_JPEG), as `to_yuv420p10` writes it
        c.colorspace = 1  # BT.709
        # Low delay (pred-struct=1): no look-ahead, no reordering, a packet per frame.
        params = f"lp={threads}:pred-struct=1:rtc=1"
        c.options = {"preset": str(preset), "crf": str(crf), "svtav1-params": params}
        self._codec = c
        self._threads_checked = False
        self._pts = 0
        self._av = av
        self._convert: tuple[np.dtype, Any] | None = None

    def _planes(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame's planes: on the OpenCL device for the simulator's outputs (rgb10a2,
        float16), else (no device, float32 `v`) with numpy; the same bits either way."""
        if self._convert is None or self._convert[0] != frame.dtype:
            convert: Any = to_yuv420p10
            if frame.dtype in (np.uint32, np.float16):
                try:
                    convert = Converter(self.size, frame.dtype)
                except Exception as e:  # no pyopencl or no device: the reference, slower
                    log.warning("av1: converting on the host (%s)", e)
            self._convert = (frame.dtype, convert)
        convert = self._convert[1]
        return convert(frame)

    def encode(self, frame: np.ndarray, key: bool = False) -> Packet:
        """One raw frame (see `to_yuv420p10`) → its packet; `key` forces a keyframe."""
        planes = self._planes(frame)
        f = self._av.VideoFrame(self._codec.width, self._codec.height, "yuv420p10le")
        for plane, values in zip(f.planes, planes, strict=True):
            rows = np.frombuffer(plane, np.uint16).reshape(-1, plane.line_size // 2)
            rows[: values.shape[0], : values.shape[1]] = values
        f.pts = self._pts
        self._pts += 1
        if key:
            f.pict_type = self._av.video.frame.PictureType.I
        packets = self._codec.encode(f)
        if not self._threads_checked:  # SVT-AV1 makes its threads on the first frame
            no_realtime_threads()
            self._threads_checked = True
        if len(packets) != 1:  # low delay gives exactly one; anything else breaks the stream
            raise RuntimeError(f"the AV1 encoder gave {len(packets)} packets for one frame")
        return Packet(bytes(packets[0]), packets[0].is_keyframe)

    def close(self) -> None:
        """End the stream (SVT-AV1 complains of an encoder dropped without its end)."""
        if self._codec is not None:
            with contextlib.suppress(self._av.FFmpegError):
                self._codec.encode(None)
            self._codec = None


def no_realtime_threads() -> int:
    """Put this process's realtime threads back to normal scheduling; how many there were.

    Run as root (a container, CI), SVT-AV1 makes the thread that starts an encoder, and every
    thread it makes, SCHED_FIFO at priority 99; what that thread starts later inherits it. On
    a 2-core machine two such threads that spin (a Chromium renderer waiting on its GPU
    process, started from there) shut every other process out, the kernel threads apart: the
    whole machine hangs. Nothing here wants realtime scheduling."""
    tasks = "/proc/self/task"
    if not hasattr(os, "sched_setscheduler") or not os.path.isdir(tasks):
        return 0  # not Linux: nothing to undo
    changed = 0
    for task in os.listdir(tasks):
        tid = int(task)
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            if os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR):
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                changed += 1
    return changed


class Decoder:
    """The viewer's decoder in Python (dav1d, as Chromium's): tests, tools and the benchmark's
    socket client. A packet it cannot decode raises ValueError saying so; the next keyframe
    starts it again."""

    def __init__(self) -> None:
        self._av = _av()
        self._codec = self._open()
        self.keyed = False

    def _open(self) -> Any:
        c = self._av.CodecContext.create("libdav1d", "r")
        c.options = {"max_frame_delay": "1"}  # a frame out for each packet in, as a viewer's
        return c

    def planes(self, packet: bytes, key: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The decoded Y, Cb, Cr (uint16, the coded size) of one packet."""
        if not (key or self.keyed):
            raise InputError("an AV1 delta packet before any keyframe: ask for a keyframe")
        try:
            frames = self._codec.decode(self._av.Packet(packet))
        except self._av.FFmpegError as e:
            self.keyed = False
            self._codec = self._open()
            raise InputError(f"corrupt AV1 packet ({e}): ask for a keyframe") from None
        if len(frames) != 1:
            self.keyed = False
            raise InputError(f"an AV1 packet gave {len(frames)} frames, not 1: ask for a keyframe")
        self.keyed = True
        f = frames[0]
        out = []
        for plane in f.planes:
            rows = np.frombuffer(plane, np.uint16).reshape(-1, plane.line_size // 2)
            out.append(rows[: plane.height, : plane.width].copy())
        return out[0], out[1], out[2]

    def decode(self, packet: bytes, key: bool, size: tuple[int, int]) -> np.ndarray:
        """H×W×3 float32 `v` of one packet (`to_rgb` of its planes)."""
        return to_rgb(*self.planes(packet, key), size)


class Stream:
    """The `av1` stream of one session, shared by all its viewers that chose it: each frame is
    encoded once whatever the number of viewers. A new size starts a new stream (keyframe);
    `want_key` asks for a keyframe (a viewer joined or lost a packet) from any thread."""

    def __init__(self, fps: float) -> None:
        self.fps = fps
        self._encoder: Encoder | None = None
        self._want_key = threading.Event()
        self._last_key = -float("inf")

    def close(self) -> None:
        if self._encoder is not None:
            self._encoder.close()
            self._encoder = None

    def want_key(self) -> None:
        self._want_key.set()

    def encode(self, frame: np.ndarray, size: tuple[int, int]) -> tuple[Packet, float]:
        """The packet of one raw frame and the seconds it took."""
        started = time.perf_counter()
        if self._encoder is None or self._encoder.size != size:
            self.close()
            self._encoder = Encoder(size, self.fps)
            self._want_key.set()
        key = self._want_key.is_set() and started - self._last_key >= MIN_KEY_INTERVAL_S
        packet = self._encoder.encode(frame, key)
        if packet.key:  # asked for or not (a new encoder starts with one): what was asked
            self._want_key.clear()
            self._last_key = started
        return packet, time.perf_counter() - started
