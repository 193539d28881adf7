"""Pupil Capture's Network API as data: the spec, Pupil Remote's replies, the backbone's surface
messages and their gaze datums. Bytes in, values or `MessageError` out; no sockets.

Written from Pupil's own sources (pupil-labs/pupil at v3.6-14-g7a3cd9e; paths under
`pupil_src/`):

- Pupil Remote is a REP socket, port 50020 by default (`main.py:30`); it answers `SUB_PORT`
  with the IPC backbone's SUB port alone, `ipc_sub_url.split(":")[-1]`, and `t` with
  `repr(g_pool.get_timestamp())`, a float in seconds of Pupil time
  (`shared_modules/network_api/controller/pupil_remote_controller.py:268-269, 298-299`); `v`
  with the version (`:300-301`); "Unknown command." otherwise (`:303`). The backbone's ports are
  chosen by the OS at each start (`main.py:235-250`), so they are asked for at every connect.
- Every backbone message is at least two frames: the topic as UTF-8, then the payload as
  `msgpack.packb(payload, use_bin_type=True)`, a map that holds its `topic` too; any further
  frames carry raw data, as video frames do, which surface messages have none of
  (`shared_modules/zmq_tools.py:164-181`, `Msg_Streamer.send`; pupil-docs
  `core/developer/network-api`, "IPC Backbone Message Format").
- The surface tracker publishes one message per detected surface and world frame, topic
  `surfaces.NAME`, with `name`, four homographies, `gaze_on_surfaces`, `fixations_on_surfaces`
  and the frame's `timestamp` (`shared_modules/surface_tracker/surface_tracker.py:486-496`,
  sent by `launchables/world.py:765-768`). Nothing is sent for a frame where the surface is not
  detected (`surface_tracker.py:478`).
- Each gaze datum on a surface is `{"topic": "gaze.…_on_surface", "norm_pos": [x, y],
  "confidence", "on_surf", "base_data": [gaze topic, timestamp], "timestamp"}`, `timestamp` the
  gaze datum's own, in Pupil time (`shared_modules/surface_tracker/surface.py:260-269`).
  `norm_pos` is surface-normalised, origin bottom-left (pupil-docs `core/terminology`,
  "Surface (AOI) Coordinate System"); `on_surf` is `0 <= x <= 1 and 0 <= y <= 1` of it.

A SUB socket filters by topic *prefix*: `surfaces.screen` also brings `surfaces.screen 2`, which
`decode` answers with None (another surface, not an error).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

try:
    import msgpack
except ModuleNotFoundError as e:  # pragma: no cover - depends on the installation
    raise ModuleNotFoundError(
        "the Pupil Capture source needs pyzmq and msgpack: install gazehdr[pupil]", name=e.name
    ) from None

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.pupil import MIN_CONFIDENCE, gaze_sample
from gazehdr.drivers.samples import GazeSample, ScreenGeometry

DEFAULT_PORT = 50020
DEFAULT_SURFACE = "screen"
#: Where a surface's messages are published: this plus the surface's name.
TOPIC_PREFIX = "surfaces."


class MessageError(InputError):
    """A reply or message that does not follow the Network API; the text says what is wrong."""


# --- the spec ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class PupilAddress:
    """Where Pupil Remote listens, and the surface (the screen) whose gaze is wanted."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    surface: str = DEFAULT_SURFACE

    @property
    def remote_url(self) -> str:
        return self.url(self.port)

    def url(self, port: int) -> str:
        """A ZeroMQ endpoint on this host (an IPv6 address in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{port}"

    @property
    def topic(self) -> str:
        return TOPIC_PREFIX + self.surface

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}/{self.surface}"


_SPEC = re.compile(
    r"(?:\[(?P<v6>[^\]/]+)\]|(?P<host>[^:/\[\]]+))?(?::(?P<port>[^/]*))?(?:/(?P<surface>.*))?",
    re.DOTALL,
)


def parse_address(arg: str) -> PupilAddress:
    """`HOST[:PORT][/SURFACE]` (all optional; an IPv6 host in brackets) → `PupilAddress`;
    ValueError naming what is wrong."""
    m = _SPEC.fullmatch(arg)
    if m is None:
        raise InputError(f"pupil:{arg}: expected pupil:HOST[:PORT][/SURFACE]")
    host = m["v6"] or m["host"] or PupilAddress.host
    port = PupilAddress.port
    if m["port"] is not None:
        if not m["port"].isdigit() or not 0 < int(m["port"]) < 65536:
            raise InputError(f"pupil:{arg}: the port must be a number from 1 to 65535")
        port = int(m["port"])
    surface = m["surface"] if m["surface"] is not None else PupilAddress.surface
    if not surface:
        raise InputError(f"pupil:{arg}: the surface name after '/' is empty")
    return PupilAddress(host, port, surface)


# --- Pupil Remote's replies -------------------------------------------------------------------


def _text(reply: bytes, command: str) -> str:
    try:
        return reply.decode("utf-8")
    except UnicodeDecodeError:
        raise MessageError(
            f"Pupil Remote answered {command!r} with bytes that are not UTF-8"
        ) from None


def parse_port(reply: bytes) -> int:
    """Pupil Remote's answer to `SUB_PORT`: a port number."""
    text = _text(reply, "SUB_PORT").strip()
    if not text.isdigit() or not 0 < int(text) < 65536:
        raise MessageError(f"Pupil Remote answered 'SUB_PORT' with {text[:80]!r}, not a port")
    return int(text)


def parse_time(reply: bytes) -> float:
    """Pupil Remote's answer to `t`: Pupil time in seconds."""
    text = _text(reply, "t").strip()
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise MessageError(f"Pupil Remote answered 't' with {text[:80]!r}, not a time")
    return value


# --- the surface messages ---------------------------------------------------------------------


@dataclass(frozen=True)
class GazeOnSurface:
    """One gaze datum mapped to the surface: Pupil time (s), surface-normalised position
    (origin bottom-left), and the gaze's confidence."""

    timestamp: float
    x: float
    y: float
    confidence: float

    def sample(
        self, t_ns: int, screen: ScreenGeometry, min_confidence: float = MIN_CONFIDENCE
    ) -> GazeSample:
        """The sample at host time `t_ns` on `screen`, which the surface is: pixels from the top
        left; invalid below `min_confidence`. Off the surface (`on_surf` false) is a valid
        sample off the screen: the eye is open and tracked, where it looks is known, and an
        invalid run would read as a blink."""
        return gaze_sample(t_ns, self.x, self.y, self.confidence, screen, min_confidence)


@dataclass(frozen=True)
class SurfaceMessage:
    """One message of the surface: its gaze datums in Pupil-time order, and what was wrong with
    those left out (each text names the datum and the field)."""

    gaze: tuple[GazeOnSurface, ...]
    problems: tuple[str, ...] = ()


def _kind(value: Any) -> str:
    return "missing" if value is None else type(value).__name__


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MessageError(f"{what} is {_kind(value)}, not a number")
    return float(value)


def _datum(datum: Any) -> GazeOnSurface:
    if not isinstance(datum, Mapping):
        raise MessageError(f"a {_kind(datum)}, not a map")
    timestamp = _number(datum.get("timestamp"), "'timestamp'")
    if not math.isfinite(timestamp):
        raise MessageError(f"'timestamp' is {timestamp}")
    confidence = _number(datum.get("confidence"), "'confidence'")
    if not 0 <= confidence <= 1:
        raise MessageError(f"'confidence' {confidence} is not in [0, 1]")
    pos = datum.get("norm_pos")
    if not isinstance(pos, list) or len(pos) != 2:
        raise MessageError(f"'norm_pos' is {_kind(pos)}, not a pair of numbers")
    return GazeOnSurface(
        timestamp, _number(pos[0], "'norm_pos'[0]"), _number(pos[1], "'norm_pos'[1]"), confidence
    )


def decode(frames: Sequence[bytes], surface: str) -> SurfaceMessage | None:
    """One backbone message, as received, for the surface named `surface`: its gaze, or None
    for another surface whose name begins with this one's. MessageError names what is wrong
    with the message as a whole; a bad datum is left out and said in `problems`."""
    if len(frames) < 2:
        raise MessageError(f"{len(frames)} frames; a message is [topic, msgpack payload, ...]")
    raw_topic, payload = frames[:2]  # frames after these are raw data (`__raw_data__`)
    try:
        topic = bytes(raw_topic).decode("utf-8")
    except UnicodeDecodeError:
        raise MessageError(f"the topic frame {bytes(raw_topic[:40])!r} is not UTF-8") from None
    wanted = TOPIC_PREFIX + surface
    if topic != wanted:
        if topic.startswith(wanted):
            return None
        raise MessageError(f"topic {topic[:80]!r}, not {wanted!r}")
    try:
        body = msgpack.unpackb(payload, raw=False)
    except Exception as e:  # msgpack raises ValueError, TypeError and its own for bad bytes
        raise MessageError(
            f"{topic}: the payload is not msgpack ({type(e).__name__}: {e})"
        ) from None
    if not isinstance(body, Mapping):
        raise MessageError(f"{topic}: the payload is a {_kind(body)}, not a map")
    for key, expected in (("topic", topic), ("name", surface)):
        if key in body and body[key] != expected:
            raise MessageError(f"{topic}: the payload's {key!r} is {body[key]!r}")
    gaze = body.get("gaze_on_surfaces")
    if not isinstance(gaze, list):
        raise MessageError(f"{topic}: 'gaze_on_surfaces' is {_kind(gaze)}, not a list")
    datums, problems = [], []
    for i, datum in enumerate(gaze):
        try:
            datums.append(_datum(datum))
        except MessageError as e:
            problems.append(f"{topic}: gaze_on_surfaces[{i}]: {e}")
    datums.sort(key=lambda d: d.timestamp)
    return SurfaceMessage(tuple(datums), tuple(problems))
