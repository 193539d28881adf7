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

from gazehdr.drivers.wire import load_typed_json
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


class Encoding(IntEnum):
    """Pixel payloads. Both keep at least 10 bits of `v` everywhere (SPEC §2.4)."""

    f16 = 1  # RGB half floats: 11 significant bits, finer still in the darks
    rgb10a2 = 2  # 10 bits per channel packed in a u32, as WebGL2's RGB10_A2 texture takes it


#: The `Simulator.step` output that is each encoding's payload.
SIM_OUTPUT = {Encoding.f16: "float16", Encoding.rgb10a2: "rgb10a2"}


class ProtocolError(ValueError):
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

    def pack(self) -> bytes:
        flags = (
            (FLAG_EYES_OPEN if self.eyes_open else 0)
            | (FLAG_TRACKER if self.tracker else 0)
            | (FLAG_SPLIT if self.split else 0)
        )
        return _HEADER.pack(
            MAGIC, VERSION, HEADER_BYTES, self.frame & 0xFFFFFFFF, self.gaze_seq & 0xFFFFFFFF,
            self.time, self.gaze_x, self.gaze_y, self.adaptation, self.rho,
            self.width, self.height, int(self.encoding), flags, 0,
            self.server_ms, min(self.dropped, 0xFFFFFFFF),
        )  # fmt: skip


def encode_pixels(v: np.ndarray, encoding: Encoding) -> bytes:
    """H×W×3 display values in [0, 1] → the payload bytes of `encoding`."""
    return payload(encode_output(v, SIM_OUTPUT[encoding]))


def payload(encoded: np.ndarray) -> bytes:
    """Bytes of an array `Simulator.step(output=...)` returned, little-endian as on the wire."""
    return encoded.astype(encoded.dtype.newbyteorder("<"), copy=False).tobytes()


def decode_frame(data: bytes) -> tuple[FrameHeader, np.ndarray]:
    """The inverse of a frame message: header and H×W×3 float32 `v` (tests and tools)."""
    if len(data) < HEADER_BYTES or data[:4] != MAGIC:
        raise ProtocolError("not a gazehdr frame (bad magic or too short)")
    fields = _HEADER.unpack_from(data)
    _, version, header_bytes, frame, seq, t, gx, gy, A, rho, w, h, enc, flags, _, ms, dropped = (
        fields
    )
    if version != VERSION:
        raise ProtocolError(f"frame version {version}, this reader knows {VERSION}")
    header = FrameHeader(
        frame, seq, t, gx, gy, A, rho, w, h, Encoding(enc),
        bool(flags & FLAG_EYES_OPEN), bool(flags & FLAG_TRACKER), ms, dropped,
        bool(flags & FLAG_SPLIT),
    )  # fmt: skip
    payload = memoryview(data)[header_bytes:]
    if header.encoding is Encoding.f16:
        v = np.frombuffer(payload, "<f2", count=w * h * 3).reshape(h, w, 3)
        return header, v.astype(np.float32)
    packed = np.frombuffer(payload, "<u4", count=w * h).reshape(h, w)
    v = np.stack([(packed >> s) & 1023 for s in (0, 10, 20)], axis=-1)
    return header, v.astype(np.float32) / 1023.0


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
class Reset:
    pass


@dataclass(frozen=True)
class Ack:
    """The viewer took frame `frame`: flow control, handled per viewer, not by the session."""

    frame: int


Control = Viewport | Gaze | Eyes | Choose | ModelChange | ParamChange | Reset | Ack
CHOICES = ("scene", "gaze_source")
MODEL_PARTS = ("afterimage", "acuity")


def _field(msg: dict[str, Any], key: str, kind: type | tuple[type, ...], what: str) -> Any:
    value = msg.get(key)
    # bool is an int in Python, but never a valid number or size on this wire.
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise ProtocolError(f"'{key}' must be {what}", msg["type"])
    return value


def _number(msg: dict[str, Any], key: str, lo: float, hi: float) -> float:
    value = float(_field(msg, key, (int, float), "a number"))
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
    if kind == "reset":
        return Reset()
    if kind == "ack":
        return Ack(_field(msg, "frame", int, "an integer"))
    known = "viewport, gaze, eyes, scene, model, gaze_source, params, reset, ack"
    raise ProtocolError(f"unknown message type {kind!r}; known: {known}", kind)
