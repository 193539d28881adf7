"""The gaze wire protocol of `/ws/gaze`: typed, versioned JSON messages, validated on parse.

Shared by the daemon (which sends) and the server (which receives), so both ends apply the
same rules. No I/O here. Positions are fractions of the tracker's calibrated screen (0..1,
top-left origin), timestamps monotonic nanoseconds on the sender's clock.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from gazehdr.drivers.errors import InputError

PROTOCOL = 1
MAX_MESSAGE_BYTES = 1024 * 1024
MAX_BATCH = 1000  # samples per `samples` message
#: The `hello` screen fields (`ScreenGeometry`'s) that are sizes, so positive; others a later
#: version may add need only be finite numbers.
SCREEN_SIZES = (
    "screen_diagonal_m",
    "screen_width_px",
    "screen_height_px",
    "viewing_distance_m",
)
#: The optional `hello` screen field giving the tracker's accuracy in degrees of visual angle
#: (its calibration's, or its data sheet's), >= 0; the server sets the session's
#: `tracker_accuracy_deg` from it (gazehdr.gaze).
ACCURACY = "accuracy_deg"
EVENT_KINDS = (
    "fixation_start",
    "fixation_update",
    "fixation_end",
    "blink_start",
    "blink_end",
)


class WireError(InputError):
    """A gaze message that does not follow the protocol; the text says which field."""


@dataclass(frozen=True)
class Hello:
    protocol: int
    tracker: str
    screen: dict[str, float]

    @property
    def accuracy_deg(self) -> float | None:
        """The tracker's accuracy the hello gives (`screen.accuracy_deg`), else None."""
        value = self.screen.get(ACCURACY)
        return None if value is None else float(value)


@dataclass(frozen=True)
class Sample:
    t_ns: int
    x: float
    y: float
    valid: bool


@dataclass(frozen=True)
class Samples:
    samples: tuple[Sample, ...]


@dataclass(frozen=True)
class Event:
    kind: str
    id: int
    t_ns: int
    x: float
    y: float


@dataclass(frozen=True)
class Echo:
    """Clock echo: the sender's `t0`; the server answers with its own clock added."""

    t0_ns: int


Message = Hello | Samples | Event | Echo


# --- server -> daemon replies (the daemon validates what it receives, too) --------------------


@dataclass(frozen=True)
class Welcome:
    """The server's answer to `hello`."""

    protocol: int


@dataclass(frozen=True)
class EchoReply:
    """The server's answer to `echo`: the sender's `t0` and the server clock when it answered."""

    t0_ns: int
    server_ns: int


@dataclass(frozen=True)
class Notice:
    """An `error` from the server: a refused message or a rate-limit note; the link goes on."""

    message: str


Reply = Welcome | EchoReply | Notice


def _refuse_constant(name: str) -> float:
    raise InputError(f"{name} is not a number JSON allows")


def load_typed_json(data: str | bytes, limit: int) -> dict[str, Any]:
    """A JSON object with a string `type`, at most `limit` bytes, strictly JSON (no NaN or
    Infinity, which Python's json would accept). Raises ValueError saying what is wrong; each
    protocol turns it into its own error type."""
    if len(data) > limit:
        raise InputError(f"message of {len(data)} bytes; the limit is {limit}")
    try:
        msg = json.loads(data, parse_constant=_refuse_constant)
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"malformed JSON: {e}") from None
    except RecursionError:  # Python's parser recurses once per level of nesting
        raise InputError("malformed JSON: nested too deeply") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise InputError("a message is a JSON object with a string 'type'")
    return msg


def excerpt(value: object, limit: int = 40) -> str:
    """`value` as an error message quotes what a client sent: its repr, cut to `limit`
    characters and saying how long it was, so that an error is never as long as its input."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text)} characters)"


def as_float(value: int | float) -> float:
    """A JSON number as a float; an integer too large for one is ±inf (json gives any size
    of integer, and float() of a huge one raises OverflowError)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _int(obj: dict[str, Any], key: str, where: str) -> int:
    value = obj.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 2**63:
        raise WireError(f"{where}: '{key}' must be a non-negative integer")
    return value


def _coord(obj: dict[str, Any], key: str, where: str) -> float:
    value = obj.get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise WireError(f"{where}: '{key}' must be a number")
    if not (math.isfinite(as_float(value)) and -3.0 <= value <= 4.0):
        raise WireError(f"{where}: '{key}' must be finite and within [-3, 4] screens")
    return float(value)


def _sample(obj: Any, where: str) -> Sample:
    if not isinstance(obj, dict):
        raise WireError(f"{where}: a sample is an object")
    valid = obj.get("valid", True)
    if not isinstance(valid, bool):
        raise WireError(f"{where}: 'valid' must be true or false")
    t = _int(obj, "t", where)
    if not valid:  # position of an invalid sample is meaningless (blink, lost track)
        return Sample(t, math.nan, math.nan, False)
    return Sample(t, _coord(obj, "x", where), _coord(obj, "y", where), True)


def parse(data: str | bytes) -> Message:
    """One text message → a typed message, or `WireError` naming what is wrong."""
    try:
        msg = load_typed_json(data, MAX_MESSAGE_BYTES)
    except ValueError as e:
        raise WireError(str(e)) from None
    kind = msg["type"]
    if kind == "hello":
        if msg.get("protocol") != PROTOCOL:
            raise WireError(f"hello: protocol {excerpt(msg.get('protocol'))}; this server speaks 1")
        tracker, screen = msg.get("tracker", ""), msg.get("screen", {})
        if not isinstance(tracker, str) or not isinstance(screen, dict):
            raise WireError("hello: 'tracker' is a string and 'screen' an object")
        for key, value in screen.items():
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise WireError(f"hello: 'screen.{key}' must be a number")
            if not math.isfinite(as_float(value)) or (key in SCREEN_SIZES and value <= 0):
                what = "a positive" if key in SCREEN_SIZES else "a finite"
                raise WireError(f"hello: 'screen.{key}' must be {what} number, got {value}")
            if key == ACCURACY and value < 0:
                raise WireError(f"hello: 'screen.{key}' must be a number >= 0, got {value}")
        return Hello(PROTOCOL, tracker[:200], screen)
    if kind == "samples":
        batch = msg.get("samples")
        if not isinstance(batch, list) or len(batch) > MAX_BATCH:
            raise WireError(f"samples: 'samples' must be a list of at most {MAX_BATCH}")
        return Samples(tuple(_sample(s, f"samples[{i}]") for i, s in enumerate(batch)))
    if kind == "event":
        if msg.get("kind") not in EVENT_KINDS:
            raise WireError(f"event: 'kind' must be one of {', '.join(EVENT_KINDS)}")
        if msg["kind"].startswith("fixation"):
            x, y = _coord(msg, "x", "event"), _coord(msg, "y", "event")
        else:  # a blink has no position; one it carries anyway must still be a valid one
            for key in ("x", "y"):
                if key in msg:
                    _coord(msg, key, "event")
            x, y = math.nan, math.nan
        return Event(msg["kind"], _int(msg, "id", "event"), _int(msg, "t", "event"), x, y)
    if kind == "echo":
        if "server_ns" in msg:  # what tells a request from the server's reply (the schema's rule)
            raise WireError("echo: a request has no 'server_ns'; that is the server's reply")
        return Echo(_int(msg, "t0", "echo"))
    raise WireError(f"unknown message type {excerpt(kind)}; known: hello, samples, event, echo")


def parse_reply(data: str | bytes) -> Reply:
    """One text message from the server → a typed reply, or `WireError` naming what is wrong."""
    try:
        msg = load_typed_json(data, MAX_MESSAGE_BYTES)
    except ValueError as e:
        raise WireError(str(e)) from None
    kind = msg["type"]
    if kind == "welcome":
        if msg.get("protocol") != PROTOCOL:
            raise WireError(
                f"welcome: protocol {excerpt(msg.get('protocol'))}; this daemon speaks 1"
            )
        return Welcome(PROTOCOL)
    if kind == "echo":
        return EchoReply(_int(msg, "t0", "echo"), _int(msg, "server_ns", "echo"))
    if kind == "error":
        text = msg.get("message")
        if not isinstance(text, str):
            raise WireError("error: 'message' must be a string")
        return Notice(text)
    raise WireError(f"unknown reply type {excerpt(kind)}; known: welcome, echo, error")


def dumps(message: Message | Reply) -> str:
    """The JSON text of a message (the daemon's side of `parse`; replies: of `parse_reply`)."""
    if isinstance(message, Welcome):
        return json.dumps({"type": "welcome", "protocol": message.protocol})
    if isinstance(message, EchoReply):
        return json.dumps({"type": "echo", "t0": message.t0_ns, "server_ns": message.server_ns})
    if isinstance(message, Notice):
        return json.dumps({"type": "error", "message": message.message})
    if isinstance(message, Hello):
        body = {"protocol": message.protocol, "tracker": message.tracker, "screen": message.screen}
        return json.dumps({"type": "hello", **body})
    if isinstance(message, Samples):
        rows = [
            {"t": s.t_ns, "x": s.x, "y": s.y, "valid": True}
            if s.valid
            else {"t": s.t_ns, "valid": False}
            for s in message.samples
        ]
        return json.dumps({"type": "samples", "samples": rows})
    if isinstance(message, Event):
        body = {"kind": message.kind, "id": message.id, "t": message.t_ns}
        if message.kind.startswith("fixation"):
            body |= {"x": message.x, "y": message.y}
        return json.dumps({"type": "event", **body})
    return json.dumps({"type": "echo", "t0": message.t0_ns})
