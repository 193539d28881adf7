"""A stand-in for Pupil Capture's Network API, built from Capture's own sources (pupil-labs/pupil
at v3.6-14-g7a3cd9e, paths under `pupil_src/`), for the tests of `gazehdr.drivers.pupil`.

- Pupil Remote: a REP socket (`network_api/controller/pupil_remote_controller.py:235-236`)
  answering `SUB_PORT` and `PUB_PORT` with the bare port (`:268-271`), `t` with
  `repr(pupil time)` (`:298-299`), `T <time>` by moving the timebase (`:289-297`), `v` with the
  version (`:300-301`) and anything else with "Unknown command." (`:303`).
- The IPC backbone's subscriber side: an XPUB socket on a port the OS chooses (`main.py:248-251`),
  so the test can wait until a subscription has arrived instead of sleeping.
- Messages: `[topic, msgpack.packb(payload, use_bin_type=True)]`, the payload holding its topic
  (`shared_modules/zmq_tools.py:164-172`); a surface message as `surface_tracker.py:486-496`
  makes it, each gaze datum as `surface_tracker/surface.py:260-269`.
- Pupil time: the host's monotonic clock minus a timebase (`launchables/world.py:239-240`), here
  made large so that a source that forgets the offset is seconds off.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack
import zmq

IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def gaze_datum(
    x: float, y: float, timestamp: float, confidence: float = 0.95, gaze_topic: str = "gaze.3d.01."
) -> dict[str, Any]:
    """A gaze datum mapped to a surface, field for field as `Surface.map_gaze_and_fixation_events`
    (surface.py:260-268) makes it: `on_surf` from the position, `base_data` the gaze's topic and
    time (a tuple, which msgpack sends as an array)."""
    return {
        "topic": f"{gaze_topic}_on_surface",
        "norm_pos": [x, y],
        "confidence": confidence,
        "on_surf": bool(0 <= x <= 1 and 0 <= y <= 1),
        "base_data": (gaze_topic, timestamp),
        "timestamp": timestamp,
    }


def surface_message(name: str, gaze: Sequence[dict[str, Any]], timestamp: float) -> dict[str, Any]:
    """A surface event as `SurfaceTracker._create_surface_events` (surface_tracker.py:486-496)
    makes it; `timestamp` is the world frame's."""
    return {
        "topic": f"surfaces.{name}",
        "name": name,
        "surf_to_img_trans": IDENTITY,
        "img_to_surf_trans": IDENTITY,
        "surf_to_dist_img_trans": IDENTITY,
        "dist_img_to_surf_trans": IDENTITY,
        "gaze_on_surfaces": list(gaze),
        "fixations_on_surfaces": [],
        "timestamp": timestamp,
    }


def frames(payload: dict[str, Any]) -> list[bytes]:
    """The two frames `Msg_Streamer.send` (zmq_tools.py:170-172) sends for `payload`."""
    return [payload["topic"].encode("utf-8"), msgpack.packb(payload, use_bin_type=True)]


class FakeCapture:
    """Pupil Remote and the backbone on 127.0.0.1. `remote_port` 0 lets the OS choose (then
    `remote_port` says which); give the old one to come back where a stopped one was.
    `timebase` (s) is what Pupil time lags the host's monotonic clock by; `mute` makes Pupil
    Remote stop answering (a hung Capture). `requests` lists what Pupil Remote was asked."""

    def __init__(self, remote_port: int = 0, *, timebase: float = -5000.0) -> None:
        self.timebase = timebase
        self.mute = False
        self.requests: list[str] = []
        self.version = "3.6.0"
        self._ctx = zmq.Context()
        self._rep = self._ctx.socket(zmq.REP)
        self._rep.setsockopt(zmq.LINGER, 0)
        self._rep.bind(f"tcp://127.0.0.1:{remote_port or '*'}")
        self.remote_port = _port(self._rep)
        self._xpub = self._ctx.socket(zmq.XPUB)
        self._xpub.setsockopt(zmq.LINGER, 0)
        self._xpub.bind("tcp://127.0.0.1:*")
        self.sub_port = _port(self._xpub)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="fake-pupil-remote", daemon=True)
        self._thread.start()

    @property
    def spec(self) -> str:
        return f"pupil:127.0.0.1:{self.remote_port}/screen"

    def pupil_time(self) -> float:
        return time.monotonic() - self.timebase

    def _answer(self, msg: str) -> str:
        if msg == "SUB_PORT":
            return str(self.sub_port)
        if msg == "PUB_PORT":
            return "0"  # no PUB side here; nothing asks for it
        if msg.startswith("T"):
            self.timebase = time.monotonic() - float(msg[2:])
            return "Timesync successful."
        if msg.startswith("t"):
            return repr(self.pupil_time())
        if msg.startswith("v"):
            return self.version
        return "Unknown command."

    def _serve(self) -> None:
        while not self._stop.is_set():
            if not self._rep.poll(20, zmq.POLLIN):
                continue
            msg = self._rep.recv_string()
            self.requests.append(msg)
            if self.mute:
                return  # never answers again
            self._rep.send_string(self._answer(msg))

    def wait_subscribed(self, topic: str = "surfaces.screen", timeout_s: float = 10.0) -> None:
        """Until a subscriber has subscribed to `topic` (XPUB passes subscriptions up)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._xpub.poll(50, zmq.POLLIN) and self._xpub.recv() == b"\x01" + topic.encode():
                return
        raise AssertionError(f"no subscription to {topic!r} within {timeout_s} s")

    def send(self, frames: Sequence[bytes]) -> None:
        """Frames as they are, good or bad."""
        self._xpub.send_multipart(list(frames))

    def publish(self, payload: dict[str, Any]) -> None:
        self.send(frames(payload))

    def stop(self) -> None:
        """Capture quits: its sockets close."""
        self._stop.set()
        self._thread.join(5)
        self._rep.close(linger=0)
        self._xpub.close(linger=0)
        self._ctx.term()


def _port(sock: Any) -> int:
    return int(sock.getsockopt(zmq.LAST_ENDPOINT).decode().rsplit(":", 1)[1])


@dataclass(frozen=True)
class Fixation:
    """Gaze held at surface-normalised (x, y) (origin bottom-left) for `duration_s`, at
    `confidence` (below 0.6 Pupil's detector has lost the pupil: a blink)."""

    x: float
    y: float
    duration_s: float
    confidence: float = 0.95


def play(
    capture: FakeCapture,
    fixations: Iterable[Fixation],
    *,
    surface: str = "screen",
    rate_hz: float = 200.0,
    frame_hz: float = 30.0,
) -> list[dict[str, Any]]:
    """Publish gaze held at each fixation in turn, in real time, as Capture does: gaze datums at
    `rate_hz` stamped when they were taken, sent in one surface message per world frame
    (`frame_hz`). Returns the datums sent."""
    sent: list[dict[str, Any]] = []
    pending: list[dict[str, Any]] = []
    start = capture.pupil_time()
    t, next_frame = 0.0, 1.0 / frame_hz
    for fixation in fixations:
        end = t + fixation.duration_s
        while t < end:
            pending.append(gaze_datum(fixation.x, fixation.y, start + t, fixation.confidence))
            t += 1.0 / rate_hz
            if t >= next_frame:
                _sleep_until(capture, start + t)
                capture.publish(surface_message(surface, pending, start + t))
                sent += pending
                pending = []
                next_frame += 1.0 / frame_hz
    if pending:
        capture.publish(surface_message(surface, pending, start + t))
        sent += pending
    return sent


def _sleep_until(capture: FakeCapture, pupil_time: float) -> None:
    time.sleep(max(0.0, pupil_time - capture.pupil_time()))
