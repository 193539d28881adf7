"""The stream encodings, `h264` and `av1`: frames as a 10-bit video stream, for viewers on
another machine.

A raw frame is 4-6 bytes per pixel (2 Gbit/s at 1080p and 30 fps); a real network gives far
less, so a remote viewer gets a lossy stream that keeps 10 bits where the dither needs them: the
display values `v` go to Y'CbCr 4:2:0 with 10 bits per sample (BT.709 coefficients, full range,
so a grey ramp keeps all 1024 levels of `rgb10a2`), the encoder codes them in a low-delay mode
(no B-frames, no look-ahead: one frame in, one packet out), and the browser decodes them with
WebCodecs (`web/video.js`), converting back to RGB in the dither shader. The conversion both
ways is ours (gazehdr.yuv; `web/renderer.js` for the way back), not a library's, so the two ends
agree to the last bit. Two codecs (`CODECS`):

- `h264`: H.264 High 10 by x264 (ultrafast, zero latency). At 1080p on two cores it encodes a
  frame in 9 ms where `av1` takes 28, with a tenth of its error (docs/performance.md, "The
  streams"), in 25-50 KiB a frame (6-12 Mbit/s at 30 fps). Chromium decodes it; Firefox and Safari
  do not decode 10-bit H.264.
- `av1`: AV1 by SVT-AV1 in its real-time mode: fewer bytes (1 KiB a frame), slower to encode;
  Chromium (with dav1d) and Firefox decode it, Safari where the hardware does.

PyAV (FFmpeg's libraries, the `video` extra) is imported only when a stream is opened: a server
without it serves the raw encodings and refuses a stream with a message saying what to install.
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

__all__ = ["CODECS", "Codec", "Decoder", "Encoder", "Packet", "Stream", "available", "to_rgb"]

log = logging.getLogger("gazehdr.video")


@dataclass(frozen=True)
class Codec:
    """One stream encoding: its encoder and options (FFmpeg's names; `{threads}` in a value
    is the encoder's thread count), the decoder that stands for the browser's, and WebCodecs'
    name for it (`web/video.js` keeps the same)."""

    name: str  # the encoding's (protocol.Encoding)
    webcodecs: str
    encoder: str
    options: dict[str, str]
    decoder: str
    decoder_options: dict[str, str]


CODECS = {
    c.name: c
    for c in (
        # H.264 High 10 (profile_idc 110 = 0x6E), level 4.0 (1080p at 30 fps). ultrafast with
        # its intra partitions and 8x8 transform back, CRF 6, against SVT-AV1 at preset 10,
        # CRF 8, on 1080p simulated frames alone on two cores: 9.3 against 28 ms a frame, luma
        # error mean 0.11 against 1.6 levels of 1023 (p99 1 against 8), 25 against 1 KiB a
        # frame. superfast takes 12.1 ms for the same error; ultrafast alone (16x16 blocks)
        # breaks a dark ramp into steps that go back a level. aq-mode=0: x264's adaptive
        # quantisation takes bits from flat darks, where the 10 bits matter most (a dark ramp's
        # grey was off by up to 10 levels with it, 1 without). zerolatency: no look-ahead, no
        # B-frames, slices for threads; forced-idr: a keyframe asked for starts the stream
        # again (SPS and PPS come with it, in band).
        Codec("h264", "avc1.6E0028", "libx264",
              {"preset": "ultrafast", "tune": "zerolatency", "crf": "6", "profile": "high10",
               "x264-params": "aq-mode=0:partitions=i8x8,i4x4:8x8dct=1", "forced-idr": "1"},
              "h264", {}),
        # AV1 main profile, level 4.0, main tier, 10 bits. SVT-AV1's real-time mode (rtc=1) at
        # preset 10 kept the luma error of moving simulated frames at half the 99th percentile
        # of its default low-delay mode's at preset 12, for fewer bytes (tests/test_video.py's
        # frames). Low delay (pred-struct=1) has no bit-rate cap in SVT-AV1 ("max bit rate
        # only with tpl"): what 1080p costs is measured (`gazehdr bench-live --link-mbit`).
        Codec("av1", "av01.0.08M.10", "libsvtav1",
              {"preset": "10", "crf": "8", "svtav1-params": "lp={threads}:pred-struct=1:rtc=1"},
              "libdav1d", {"max_frame_delay": "1"}),
    )
}  # fmt: skip
#: Keyframes asked for (a new viewer, a lost or corrupt packet) come at most this often: each
#: costs every viewer of the stream a large packet.
MIN_KEY_INTERVAL_S = 0.25


class VideoUnavailableError(GazehdrError, RuntimeError):
    """PyAV (or a codec's encoder or decoder) is missing; the message says what to install."""


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise VideoUnavailableError(
            "the stream encodings (h264, av1) need PyAV: pip install 'gazehdr[video]'"
        ) from None
    return av


def available(name: str) -> str | None:
    """None when stream encoding `name` can be served, else why not."""
    try:
        av = _av()
    except VideoUnavailableError as e:
        return str(e)
    codec = CODECS[name]
    for lib, mode in ((codec.encoder, "w"), (codec.decoder, "r")):
        try:
            av.codec.Codec(lib, mode)
        except ValueError:  # UnknownCodecError
            return f"this PyAV build has no {lib}, which the {name} encoding uses"
    return None


@dataclass(frozen=True)
class Packet:
    data: bytes
    key: bool


class Encoder:
    """One stream of frames of one size in codec `name` (`CODECS`): `encode` takes a raw
    frame, returns its packet. `options` change the codec's (benchmarks of presets)."""

    def __init__(
        self, size: tuple[int, int], fps: float, name: str = "av1", *, threads: int = 2,
        options: dict[str, str] | None = None,
    ) -> None:  # fmt: skip
        av = _av()
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 logs its configuration otherwise
        self.size = size
        self.name = name
        codec = CODECS[name]
        w, h = size
        c = av.CodecContext.create(codec.encoder, "w")
        c.width, c.height, c.pix_fmt = w + w % 2, h + h % 2, "yuv420p10le"
        c.time_base = fractions.Fraction(1, 1000)
        c.framerate = fractions.Fraction(round(fps * 1000), 1000)
        c.max_b_frames = 0
        c.gop_size = 1 << 30  # keyframes only when asked for (`key=True`)
        c.color_range = 2  # full (AVCOL_RANGE_JPEG), as `to_yuv420p10` writes it
        c.colorspace = 1  # BT.709
        c.thread_count = threads
        c.options = {
            k: v.format(threads=threads) for k, v in {**codec.options, **(options or {})}.items()
        }
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
                    log.warning("%s: converting on the host (%s)", self.name, e)
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
            raise RuntimeError(f"the {self.name} encoder gave {len(packets)} packets for a frame")
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
    """The viewer's decoder in Python (dav1d and FFmpeg's h264, as Chromium's): tests, tools
    and the benchmark's socket client. A packet it cannot decode raises ValueError saying so;
    the next keyframe starts it again."""

    def __init__(self, name: str = "av1") -> None:
        self._av = _av()
        self.name = name
        self._codec = self._open()
        self.keyed = False

    def _open(self) -> Any:
        codec = CODECS[self.name]
        c = self._av.CodecContext.create(codec.decoder, "r")
        # A frame out for each packet in, as a viewer's: dav1d is told so; FFmpeg's h264
        # gives one for a stream without B-frames.
        c.options = codec.decoder_options
        return c

    def planes(self, packet: bytes, key: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The decoded Y, Cb, Cr (uint16, the coded size) of one packet."""
        name = self.name
        if not (key or self.keyed):
            raise InputError(f"an {name} delta packet before any keyframe: ask for a keyframe")
        try:
            frames = self._codec.decode(self._av.Packet(packet))
        except self._av.FFmpegError as e:
            self.keyed = False
            self._codec = self._open()
            raise InputError(f"corrupt {name} packet ({e}): ask for a keyframe") from None
        if len(frames) != 1:
            self.keyed = False
            raise InputError(
                f"an {name} packet gave {len(frames)} frames, not 1: ask for a keyframe"
            )
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
    """One stream encoding (`CODECS`) of one session, shared by all its viewers that chose it:
    each frame is encoded once whatever the number of viewers. A new size starts a new stream
    (keyframe); `want_key` asks for a keyframe (a viewer joined or lost a packet) from any
    thread."""

    def __init__(self, fps: float, name: str = "av1") -> None:
        self.fps = fps
        self.name = name
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
            self._encoder = Encoder(size, self.fps, self.name)
            self._want_key.set()
        key = self._want_key.is_set() and started - self._last_key >= MIN_KEY_INTERVAL_S
        packet = self._encoder.encode(frame, key)
        if packet.key:  # asked for or not (a new encoder starts with one): what was asked
            self._want_key.clear()
            self._last_key = started
        return packet, time.perf_counter() - started
