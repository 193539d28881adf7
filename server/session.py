"""One viewing session: a simulated eye, its scene, its gaze, and the frames it produces.

`Session` is synchronous and knows no sockets and no clock: the caller passes the elapsed
time and the control messages that arrived, and gets back an encoded frame plus the JSON
messages to tell the viewers. `server.live` runs it on a thread at real time.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

from drivers.synthetic import FixationView
from drivers.tracks import open_track
from server.protocol import (
    SIM_OUTPUT,
    Choose,
    Control,
    Encoding,
    Eyes,
    FrameHeader,
    Gaze,
    ParamChange,
    ProtocolError,
    Reset,
    Viewport,
    payload,
)
from server.recordings import RecordingLibrary
from server.scenes import Scene
from server.scenes.library import SceneLibrary
from server.sim import Params, Simulator
from server.sim.layout import MAX_SIZE, MIN_SIZE
from server.sim.params import OURS, SECTIONS

MODELS = ("jacobs",)
GAZE_SOURCES = ("mouse", "synthetic", "remote")
#: A stalled server steps the eye by at most this much at once (s), so it never leaps.
MAX_FRAME_DT = 1.0
SYNTHETIC_LOOP_S = 600.0  # the synthetic scan path repeats after this long
SIZE_STEP = 8  # frame sides are multiples of this when fitted to a viewport


@dataclass(frozen=True)
class SessionSettings:
    """What a new session starts with (the server's configuration)."""

    width: int = 640
    height: int = 360
    fps: float = 30.0
    scene: str = "flash"
    gaze_source: str = "mouse"
    model: str = "jacobs"
    params: Params = field(default_factory=Params)
    seed: int = 0
    backend: str = "opencl"
    encoding: Encoding = Encoding.f16
    #: Take the viewer's aspect ratio for the frame, keeping width·height as the pixel budget.
    fit_viewport: bool = True


@dataclass
class RemoteGaze:
    """The latest gaze from the gaze daemons, shared by every session that follows them."""

    x: float = 0.5
    y: float = 0.5
    eyes_open: bool = True
    seq: int = 0  # bumps on every update, so a session can tell a new one
    received_at: float = 0.0  # time.monotonic() of the update
    tracker: str | None = None
    connections: int = 0
    samples: int = 0

    def update(self, x: float | None, y: float | None, eyes_open: bool, now: float) -> None:
        if x is not None and y is not None:
            self.x, self.y = x, y
        self.eyes_open = eyes_open
        self.seq += 1
        self.received_at = now


@dataclass(frozen=True)
class Frame:
    header: FrameHeader
    payload: bytes
    sim_seconds: float
    encode_seconds: float
    #: When the gaze this frame is the first to use reached the server (None: no new gaze).
    gaze_received_at: float | None

    def message(self, dropped: int) -> bytes:
        return dataclasses.replace(self.header, dropped=dropped).pack() + self.payload


def fit_size(budget: tuple[int, int], viewport: tuple[int, int]) -> tuple[int, int]:
    """Frame size with the viewport's aspect ratio and about `budget`'s number of pixels."""
    aspect = viewport[0] / viewport[1]
    if abs(aspect / (budget[0] / budget[1]) - 1) < 0.01:  # the budget's own shape: keep it exact
        return budget
    pixels = budget[0] * budget[1]
    w = round(math.sqrt(pixels * aspect) / SIZE_STEP) * SIZE_STEP
    h = round(math.sqrt(pixels / aspect) / SIZE_STEP) * SIZE_STEP
    return (min(max(w, MIN_SIZE), MAX_SIZE[0]), min(max(h, MIN_SIZE), MAX_SIZE[1]))


class Session:
    def __init__(
        self,
        session_id: str,
        settings: SessionSettings,
        scenes: SceneLibrary,
        remote: RemoteGaze,
        recordings: RecordingLibrary | None = None,
    ) -> None:
        self.id = session_id
        self.settings = settings
        self.scenes = scenes
        self.remote = remote
        self.recordings = recordings or RecordingLibrary(None)
        self.size = (settings.width, settings.height)
        self.params = settings.params
        self.gaze_source = settings.gaze_source
        self.model = settings.model
        self.scene_name = settings.scene
        self.scene: Scene = scenes.open(settings.scene)
        self.frame = 0
        self.gaze = (0.5, 0.5)  # fractions of the frame
        self.gaze_seq = 0
        self.eyes_open = True
        self._new_gaze_at: float | None = None
        self._remote_seq = -1
        self._track = None
        self._track_start = 0.0
        self.sim = self._new_simulator()

    # --- what the viewers are told ------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        return {
            "scene": self.scene_name,
            "scenes": self.scenes.names(),
            "model": self.model,
            "models": list(MODELS),
            "gaze_source": self.gaze_source,
            "gaze_sources": [*GAZE_SOURCES, *(f"replay:{n}" for n in self.recordings.names())],
            "width": self.size[0],
            "height": self.size[1],
            "fps": self.settings.fps,
            "encoding": self.settings.encoding.name,
            "device": self.sim.device,
            "params": self.params.to_dict(),
            "defaults": Params().to_dict(),
            "sections": SECTIONS,
            "ours": sorted(OURS),
        }

    # --- the step -----------------------------------------------------------------------------

    def tick(
        self, dt: float, controls: list[tuple[Control, float]]
    ) -> tuple[Frame, list[dict[str, Any]]]:
        """Apply `controls` (each with its arrival time), step by `dt` s, encode the frame.

        Returns the frame and the messages for the viewers: a `state` when something they
        show changed, an `error` for each control refused (the session goes on unchanged).
        """
        notes: list[dict[str, Any]] = []
        changed = False
        for control, received_at in controls:
            try:
                changed |= self.apply(control, received_at)
            except (ValueError, TypeError, OSError) as e:  # ProtocolError is a ValueError
                notes.append({"type": "error", "message": str(e), "in": _type_of(control)})
        if changed:
            notes.append({"type": "state", **self.state()})
        return self._advance(min(max(dt, 0.0), MAX_FRAME_DT)), notes

    def apply(self, control: Control, received_at: float = 0.0) -> bool:
        """One control message; True when the viewers' `state` changed."""
        if isinstance(control, Gaze):
            if self.gaze_source == "mouse":
                self.gaze, self.gaze_seq = (control.x, control.y), control.seq
                self._new_gaze_at = received_at
            return False
        if isinstance(control, Eyes):
            self.eyes_open = control.open
            return False
        if isinstance(control, Reset):
            self.sim.reset()
            return False
        if isinstance(control, Viewport):
            if not self.settings.fit_viewport:
                return False
            budget = (self.settings.width, self.settings.height)
            size = fit_size(budget, (control.width, control.height))
            if size == self.size:
                return False
            self.size = size
            self.sim = self._new_simulator(keep_from=self.sim)
            return True
        if isinstance(control, ParamChange):
            return self._set_params(control.values)
        if isinstance(control, Choose):
            return self._choose(control.what, control.name)
        raise ProtocolError(f"unhandled control {control!r}")

    # --- internals ----------------------------------------------------------------------------

    def _choose(self, what: str, name: str) -> bool:
        if what == "scene":
            self.scene = self.scenes.open(name)
            self.scene_name = name
            self._load_scene(reset=True)
        elif what == "model":
            if name not in MODELS:
                raise ValueError(f"unknown model {name!r}; available: {', '.join(MODELS)}")
            self.model = name
        elif name.startswith("replay:"):
            self._track = self.recordings.track(name.removeprefix("replay:"))
            self._track_start = self.sim.time
            self.gaze_source = name
        else:
            if name not in GAZE_SOURCES:
                known = ", ".join([*GAZE_SOURCES, "replay:NAME"])
                raise ValueError(f"unknown gaze source {name!r}; available: {known}")
            self.gaze_source = name
            self._track = None
        return True

    def _set_params(self, values: dict[str, Any]) -> bool:
        merged = {**self.params.to_dict(), **values}
        try:
            params = Params.from_dict(merged)
        except (TypeError, ValueError) as e:
            raise ValueError(f"parameters refused: {e}") from None
        if params == self.params:
            return False
        old = self.sim
        self.params = params
        self.sim = self._new_simulator(keep_from=old)
        return True

    def _new_simulator(self, keep_from: Simulator | None = None) -> Simulator:
        w, h = self.size
        s = self.settings
        sim = Simulator(w, h, params=self.params, backend=s.backend, seed=s.seed)
        sim.step(0.0, gaze=(self.gaze[0] * w, self.gaze[1] * h), eyes_open=self.eyes_open)
        self.sim = sim
        self._load_scene(reset=True)
        if keep_from is not None:
            sim.carry_state_from(keep_from)
        return sim

    def _load_scene(self, reset: bool) -> None:
        t = self.sim.time
        self._loaded = self.scene.state_at(t)
        self.sim.load_scene(self.scene.render(t, *self.size), reset=reset)

    def _sync_scene(self) -> None:
        """Load the scene as it is at the simulator's time, if that differs from what it sees."""
        t = self.sim.time
        if self.scene.animated and self.scene.state_at(t) != self._loaded:
            self._loaded = self.scene.state_at(t)
            self.sim.load_scene(self.scene.render(t, *self.size), reset=False)

    def _current_gaze(self) -> bool:
        """Update gaze and eyes from the session's source; True when it came from a tracker."""
        if self.gaze_source == "remote":
            r = self.remote
            self.gaze, self.eyes_open = (r.x, r.y), r.eyes_open
            if r.seq != self._remote_seq:
                self._remote_seq, self._new_gaze_at = r.seq, r.received_at
            return True
        if self.gaze_source == "synthetic" and self._track is None:
            seed = self.settings.seed
            path = open_track("synthetic", seed=seed, duration=SYNTHETIC_LOOP_S)
            self._track = FixationView(path)  # follow fixations, not saccades
            self._track_start = 0.0
        if self._track is None:
            return False
        # Tracks loop: a recording replays from where it was chosen, over and over.
        length = max(getattr(self._track, "duration", SYNTHETIC_LOOP_S), 1e-3)
        x, y, self.eyes_open = self._track.at((self.sim.time - self._track_start) % length)
        self.gaze = (x, y)
        return True

    def _advance(self, dt: float) -> Frame:
        started = time.perf_counter()
        tracker = self._current_gaze()
        sim, (w, h) = self.sim, self.size
        gaze = (self.gaze[0] * w, self.gaze[1] * h)
        # Split the step where the scene changes: a flash shorter than a frame is seen for
        # exactly its duration, never skipped nor stretched to the whole frame.
        end = sim.time + dt
        while (change := self.scene.next_change(sim.time)) is not None and change < end:
            sim.step(change - sim.time, gaze=gaze, eyes_open=self.eyes_open)
            self._sync_scene()
        self._sync_scene()
        encoding = self.settings.encoding
        out = sim.step(
            max(0.0, end - sim.time), gaze=gaze, eyes_open=self.eyes_open,
            output=SIM_OUTPUT[encoding],
        )  # fmt: skip
        stepped = time.perf_counter()
        data = payload(out)  # the device already encoded it: this is a copy
        encoded = time.perf_counter()
        gx, gy = sim.gaze
        header = FrameHeader(
            frame=self.frame,
            gaze_seq=self.gaze_seq,
            time=sim.time,
            gaze_x=gx / w,
            gaze_y=gy / h,
            adaptation=sim.adaptation,
            rho=sim.rho_at_gaze(),
            width=w,
            height=h,
            encoding=self.settings.encoding,
            eyes_open=self.eyes_open,
            tracker=tracker,
            server_ms=(encoded - started) * 1e3,
        )
        self.frame += 1
        new_gaze_at, self._new_gaze_at = self._new_gaze_at, None
        return Frame(header, data, stepped - started, encoded - stepped, new_gaze_at)


def _type_of(control: Control) -> str:
    if isinstance(control, Choose):
        return control.what
    return {
        Viewport: "viewport", Gaze: "gaze", Eyes: "eyes", ParamChange: "params", Reset: "reset"
    }.get(type(control), "unknown")  # fmt: skip


__all__ = ["GAZE_SOURCES", "MODELS", "Frame", "RemoteGaze", "Session", "SessionSettings"]
