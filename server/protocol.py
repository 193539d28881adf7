"""The viewer protocol of `/ws/view`, without any I/O (see docs/protocol.md).

Bytes in, typed messages out, and back: the session and the WebSocket endpoint only move what
these functions produce, so every rule about the wire is tested here without a socket.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum
from types import EllipsisType
from typing import Any

import numpy as np

from gazehdr import warp
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.wire import as_float, excerpt, load_typed_json
from gazehdr.sim.layout import encode_output

MAGIC = b"GZHF"
VERSION = 1
#: '<' little-endian; see the table in docs/protocol.md. 56 bytes, so the payload is 8-aligned.
_HEADER = struct.Struct("<4sHHIIdffffHHBBHfI")
HEADER_BYTES = _HEADER.size
MAX_CONTROL_BYTES = 64 * 1024
#: Gaze coordinates are fractions of the frame; the simulator clamps to this range anyway.
GAZE_RANGE = (-3.0, 4.0)
FLAG_EYES_OPEN = 1
FLAG_TRACKER = 2
FLAG_SPLIT = 4
FLAG_KEYFRAME = 8  # a stream's: the packet starts the stream again (it needs no earlier one)


class Encoding(IntEnum):
    """Pixel payloads. The raw ones keep at least 10 bits of `v` everywhere (SPEC §2.4); the
    streams (`h264`, `av1`) are lossy, 10-bit Y'CbCr 4:2:0, for viewers on another machine
    (gazehdr.video)."""

    f16 = 1  # RGB half floats: 11 significant bits, finer still in the darks
    rgb10a2 = 2  # 10 bits per channel packed in a u32, as WebGL2's RGB10_A2 texture takes it
    av1 = 3  # one AV1 packet of a stream: needs the ones since the last keyframe
    h264 = 4  # one H.264 High 10 packet of a stream (Annex B), likewise
    #: The late gaze warp (gazehdr.warp): what compose makes before Eq. 12 and the afterimage
    #: maps, composed by the viewer at its newest gaze. Per viewer (`Warp`), never a session's.
    warp = 16


#: Encodings a session's simulator writes (the others are made from one of these per viewer).
RAW = (Encoding.f16, Encoding.rgb10a2)


#: Encodings made from a raw frame by a video encoder, once for all the viewers that chose one.
STREAMS = (Encoding.h264, Encoding.av1)


#: The `Simulator.step` output that is each encoding's payload.
SIM_OUTPUT = {Encoding.f16: "float16", Encoding.rgb10a2: "rgb10a2"}


class ProtocolError(InputError):
    """A message the peer sent that we refuse; `in_type` is its `type` when known."""

    def __init__(self, message: str, in_type: str | None = None) -> None:
        super().__init__(message)
        self.in_type = in_type


@dataclass(frozen=True)
class FrameHeader:
    frame: int
    gaze_seq: int
    time: float
    gaze_x: float
    gaze_y: float
    adaptation: float
    rho: float
    width: int
    height: int
    encoding: Encoding
    eyes_open: bool = True
    tracker: bool = False
    server_ms: float = 0.0
    dropped: int = 0
    #: Two panes side by side, each `width // 2` px wide (see docs/protocol.md).
    split: bool = False
    #: `av1`: this packet is a keyframe.
    keyframe: bool = False

    def pack(self) -> bytes:
        flags = (
            (FLAG_EYES_OPEN if self.eyes_open else 0)
            | (FLAG_TRACKER if self.tracker else 0)
            | (FLAG_SPLIT if self.split else 0)
            | (FLAG_KEYFRAME if self.keyframe else 0)
        )
        return _HEADER.pack(
            MAGIC, VERSION, HEADER_BYTES, self.frame & 0xFFFFFFFF, self.gaze_seq & 0xFFFFFFFF,
            self.time, self.gaze_x, self.gaze_y, self.adaptation, self.rho,
            self.width, self.height, int(self.encoding), flags, 0,
            self.server_ms, min(self.dropped, 0xFFFFFFFF),
        )  # fmt: skip


#: The scene map: what the pane's simulator sees, for the viewer's inspection tools.
SCENE_MAGIC = b"GZHS"
_SCENE_HEADER = struct.Struct("<4sHHIHHhHI")
SCENE_HEADER_BYTES = 24


@dataclass(frozen=True)
class SceneMap:
    """The radiance (cd/m^2, H×W×3) and mesopic ρ (H×W) of one pane, as the simulator holds
    them; `seq` counts the session's maps. On the wire the radiance is float16 times
    2^`exponent`, the exponent chosen so the brightest value fits (docs/protocol.md)."""

    seq: int
    radiance: np.ndarray
    rho: np.ndarray

    def pack(self) -> bytes:
        h, w = self.rho.shape
        top = float(np.max(self.radiance, initial=0.0))
        exponent = int(np.clip(math.ceil(math.log2(top / _HALF_MAX)), -30, 60)) if top > 0 else 0
        halves = np.ldexp(self.radiance.astype(np.float64), -exponent).astype("<f2")
        head = _SCENE_HEADER.pack(
            SCENE_MAGIC, 1, SCENE_HEADER_BYTES, self.seq & 0xFFFFFFFF, w, h, exponent, 0, 0
        )
        return head + halves.tobytes() + self.rho.astype("<f4").tobytes()


_HALF_MAX = float(np.finfo(np.float16).max)


def decode_scene_map(data: bytes) -> SceneMap:
    """The inverse of `SceneMap.pack` (tests and tools); radiance as float32."""
    if len(data) < SCENE_HEADER_BYTES or data[:4] != SCENE_MAGIC:
        raise ProtocolError("not a gazehdr scene map (bad magic or too short)")
    _, version, header_bytes, seq, w, h, exponent, _, _ = _SCENE_HEADER.unpack_from(data)
    if version != 1:
        raise ProtocolError(f"scene map version {version}, this reader knows 1")
    halves = np.frombuffer(data, "<f2", count=w * h * 3, offset=header_bytes)
    radiance = np.ldexp(halves.astype(np.float32), exponent).reshape(h, w, 3)
    rho = np.frombuffer(data, "<f4", count=w * h, offset=header_bytes + 6 * w * h)
    return SceneMap(seq, radiance, rho.reshape(h, w))


def encode_pixels(v: np.ndarray, encoding: Encoding) -> bytes:
    """H×W×3 display values in [0, 1] → the payload bytes of `encoding`."""
    return payload(encode_output(v, SIM_OUTPUT[encoding]))


def payload(encoded: np.ndarray) -> bytes:
    """Bytes of an array `Simulator.step(output=...)` returned, little-endian as on the wire.
    A copy, not a view of the array: measured, a view that keeps each step's array alive until
    its frame is sent cost more (fresh pages for every step's array) than the copy saves."""
    return _little_endian(encoded).tobytes()


#: Each raw encoding's pixels as `Simulator.step` makes them: per pixel, the array's trailing
#: shape and its dtype as on the wire.
PIXELS = {Encoding.f16: ((3,), np.dtype("<f2")), Encoding.rgb10a2: ((), np.dtype("<u4"))}


def frame_buffer(width: int, height: int, encoding: Encoding) -> tuple[memoryview, np.ndarray]:
    """A frame message still to be filled: its bytes, and its pixels as the array a step
    composes into (as `payload` lays them out). Its header goes in its first HEADER_BYTES
    (`FrameHeader.pack`). The pixels come from the device into the message, with no copy on
    the host between (a message made after the step took one more: 0.3 ms at 1280x720). Not
    cleared (a 720p message's clearing took 0.17 ms): every byte is to be written."""
    trailing, dtype = PIXELS[encoding]
    shape = (height, width, *trailing)
    message = np.empty(HEADER_BYTES + math.prod(shape) * dtype.itemsize, np.uint8)
    return memoryview(message), message[HEADER_BYTES:].view(dtype).reshape(shape)


def _little_endian(encoded: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(encoded.astype(encoded.dtype.newbyteorder("<"), copy=False))


def decode_frame(data: bytes) -> tuple[FrameHeader, np.ndarray]:
    """The inverse of a frame message: header and H×W×3 float32 `v` (tests and tools); a warp
    frame composed at its own gaze."""
    header, payload = split_frame(data)
    w, h = header.width, header.height
    if header.encoding in STREAMS:
        raise ProtocolError(
            f"an {header.encoding.name} frame is a packet of a stream: decode it with gazehdr.video"
        )
    if header.encoding is Encoding.warp:  # as the viewer shows it at the frame's own gaze
        return header, warp.compose(warp.unpack(payload, w, h)).astype(np.float32)
    if header.encoding is Encoding.f16:
        v = np.frombuffer(payload, "<f2", count=w * h * 3).reshape(h, w, 3)
        return header, v.astype(np.float32)
    packed = np.frombuffer(payload, "<u4", count=w * h).reshape(h, w)
    v = np.stack([(packed >> s) & 1023 for s in (0, 10, 20)], axis=-1)
    return header, v.astype(np.float32) / 1023.0


def split_frame(data: bytes) -> tuple[FrameHeader, memoryview]:
    """A frame message's header and its payload, undecoded (any encoding)."""
    if len(data) < HEADER_BYTES or data[:4] != MAGIC:
        raise ProtocolError("not a gazehdr frame (bad magic or too short)")
    fields = _HEADER.unpack_from(data)
    _, version, header_bytes, frame, seq, t, gx, gy, A, rho, w, h, enc, flags, _, ms, dropped = (
        fields
    )
    if version != VERSION:
        raise ProtocolError(f"frame version {version}, this reader knows {VERSION}")
    try:
        encoding = Encoding(enc)
    except ValueError:
        raise ProtocolError(f"unknown frame encoding {enc}") from None
    header = FrameHeader(
        frame, seq, t, gx, gy, A, rho, w, h, encoding,
        bool(flags & FLAG_EYES_OPEN), bool(flags & FLAG_TRACKER), ms, dropped,
        bool(flags & FLAG_SPLIT), bool(flags & FLAG_KEYFRAME),
    )  # fmt: skip
    return header, memoryview(data)[header_bytes:]


# --- browser → server control messages ------------------------------------------------------


@dataclass(frozen=True)
class Viewport:
    width: int
    height: int


@dataclass(frozen=True)
class Gaze:
    x: float
    y: float
    seq: int


@dataclass(frozen=True)
class Eyes:
    open: bool


@dataclass(frozen=True)
class Choose:
    """Switch `what` (scene or gaze_source) to `name`."""

    what: str
    name: str


@dataclass(frozen=True)
class ModelPick:
    """Model names asked for; None keeps that part as it is."""

    afterimage: str | None = None
    acuity: str | None = None


@dataclass(frozen=True)
class ModelChange:
    """Switch the frame's model (the left pane in split view) and the split: `split` is the
    right pane's model, None turns split view off, `...` leaves it as it is."""

    model: ModelPick
    split: ModelPick | EllipsisType | None = ...


@dataclass(frozen=True)
class ParamChange:
    values: dict[str, Any]


@dataclass(frozen=True)
class SceneSettings:
    """Settings of the session's current scene (`scale`, `kind`, `layer`; None: the default),
    kept by the server's scene library for every session showing it."""

    values: dict[str, Any]


@dataclass(frozen=True)
class Reset:
    pass


@dataclass(frozen=True)
class SceneMaps:
    """Whether this viewer wants the binary scene maps (off until asked: a client that takes
    every binary message for a frame keeps working). Handled per viewer."""

    send: bool


@dataclass(frozen=True)
class Warp:
    """Whether this viewer wants late-warp frames (encoding `warp`) instead of the session's
    encoding. Handled per viewer."""

    on: bool


@dataclass(frozen=True)
class EncodingChoice:
    """The encoding this viewer wants (None: the session's); handled per viewer."""

    encoding: Encoding | None


@dataclass(frozen=True)
class KeyframeRequest:
    """A stream's viewer lost it (a corrupt packet, a decoder error): the next packet it
    gets is a keyframe. Handled per viewer."""


@dataclass(frozen=True)
class Ack:
    """The viewer took frame `frame`: flow control, handled per viewer, not by the session."""

    frame: int


Control = (
    Viewport | Gaze | Eyes | Choose | ModelChange | ParamChange | SceneSettings | SceneMaps
    | Warp | Reset | Ack | EncodingChoice | KeyframeRequest
)  # fmt: skip
#: The controls that make a session (or a viewer's encoder) do work: a reset settles the retina,
#: the others rebuild the eye, load a scene or start a keyframe. `fair_share` paces them.
WORK_CONTROLS = (Reset, ParamChange, ModelChange, Choose, SceneSettings, Viewport,
                 EncodingChoice, KeyframeRequest)  # fmt: skip
SCENE_SETTINGS = {"scale": ((int, float), "a number"), "kind": (str, "a string"),
                  "layer": (str, "a string")}  # fmt: skip
CHOICES = ("scene", "gaze_source")
MODEL_PARTS = ("afterimage", "acuity")


def _field(msg: dict[str, Any], key: str, kind: type | tuple[type, ...], what: str) -> Any:
    value = msg.get(key)
    # bool is an int in Python, but never a valid number or size on this wire.
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise ProtocolError(f"'{key}' must be {what}", msg["type"])
    return value


def _number(msg: dict[str, Any], key: str, lo: float, hi: float) -> float:
    value = as_float(_field(msg, key, (int, float), "a number"))
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ProtocolError(f"'{key}' must be a finite number in [{lo}, {hi}]", msg["type"])
    return value


def _model_pick(obj: dict[str, Any], where: str = "") -> ModelPick:
    for key in MODEL_PARTS:
        if obj.get(key) is not None and not isinstance(obj[key], str):
            raise ProtocolError(f"'{where}{key}' must be a model name (a string)", "model")
    return ModelPick(obj.get("afterimage"), obj.get("acuity"))


def _model_change(msg: dict[str, Any]) -> ModelChange:
    """`{"type": "model", "afterimage"?, "acuity"?, "split"?: {...} | null}`."""
    if not any(key in msg for key in (*MODEL_PARTS, "split")):
        raise ProtocolError("'model' needs 'afterimage', 'acuity' or 'split'", "model")
    split: ModelPick | EllipsisType | None = ...
    if "split" in msg:
        if msg["split"] is not None and not isinstance(msg["split"], dict):
            raise ProtocolError("'split' must be an object of model names or null", "model")
        split = None if msg["split"] is None else _model_pick(msg["split"], "split.")
    return ModelChange(_model_pick(msg), split)


def _scene_settings(msg: dict[str, Any]) -> SceneSettings:
    """`{"type": "scene_settings", "scale"?: N | null, "kind"?: K | null, "layer"?: L | null}`."""
    values = {k: msg[k] for k in SCENE_SETTINGS if k in msg}
    if not values:
        raise ProtocolError("'scene_settings' needs 'scale', 'kind' or 'layer'", msg["type"])
    for key, value in values.items():
        if value is not None:
            _field(msg, key, *SCENE_SETTINGS[key])
    return SceneSettings(values)


def _encoding_choice(msg: dict[str, Any]) -> EncodingChoice:
    """`{"type": "encoding", "name": "f16" | "rgb10a2" | "av1" | "h264" | null}`."""
    name = msg.get("name")
    if name is None:
        return EncodingChoice(None)
    if name == Encoding.warp.name:
        raise ProtocolError(
            'the late gaze warp has a control of its own: {"type": "warp", "on": true}', "encoding"
        )
    names = ", ".join(e.name for e in Encoding if e is not Encoding.warp)
    if not isinstance(name, str) or name not in Encoding.__members__:
        raise ProtocolError(f"'name' must be one of {names} or null", "encoding")
    return EncodingChoice(Encoding[name])


def parse_control(data: str | bytes) -> Control:
    """One text message from the viewer → a typed control, or `ProtocolError` saying why not."""
    try:
        msg = load_typed_json(data, MAX_CONTROL_BYTES)
    except ValueError as e:
        raise ProtocolError(str(e)) from None
    kind = msg["type"]
    if kind == "viewport":
        w, h = (int(_number(msg, k, 1, 16384)) for k in ("width", "height"))
        return Viewport(w, h)
    if kind == "gaze":
        x, y = (_number(msg, k, *GAZE_RANGE) for k in ("x", "y"))
        seq = _field(msg, "seq", int, "an integer")
        if not 0 <= seq < 2**32:
            raise ProtocolError("'seq' must be in [0, 2^32)", kind)
        return Gaze(x, y, seq)
    if kind == "eyes":
        return Eyes(_field(msg, "open", bool, "true or false"))
    if kind in CHOICES:
        return Choose(kind, _field(msg, "name", str, "a string"))
    if kind == "model":
        return _model_change(msg)
    if kind == "params":
        return ParamChange(_field(msg, "values", dict, "an object of parameter values"))
    if kind == "scene_settings":
        return _scene_settings(msg)
    if kind == "scene_maps":
        return SceneMaps(_field(msg, "send", bool, "true or false"))
    if kind == "warp":
        return Warp(_field(msg, "on", bool, "true or false"))
    if kind == "reset":
        return Reset()
    if kind == "ack":
        return Ack(_field(msg, "frame", int, "an integer"))
    if kind == "encoding":
        return _encoding_choice(msg)
    if kind == "keyframe":
        return KeyframeRequest()
    known = (
        "viewport, gaze, eyes, scene, model, gaze_source, params, scene_settings, scene_maps, "
        "warp, reset, ack, encoding, keyframe"
    )
    raise ProtocolError(f"unknown message type {excerpt(kind)}; known: {known}", kind[:40])
