"""One viewing session: a simulated eye, its scene, its gaze, and the frames it produces.

In split view the session runs two simulators, one per half of the frame, with the same scene,
gaze and steps and a model each, so two models can be compared side by side.

`Session` is synchronous and knows no sockets and no clock: the caller passes the elapsed
time and the control messages that arrived, and gets back an encoded frame plus the JSON
messages to tell the viewers. `gazehdr.live` runs it on a thread at real time.

A session that records keeps a journal of session-log records (drivers/sessionlog.py) for its
caller to write: the scene, parameters and models it ran with and every change to them, resets,
and the gaze and eyes it followed, on its simulation clock. Each carries the end time of the
first step it drove, so an offline render at any frame rate (server/render.py) meets each at
the same step the live session did.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from types import EllipsisType
from typing import Any

import numpy as np

from gazehdr.drivers import sessionlog
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.drivers.tracks import open_track
from gazehdr.protocol import (
    SIM_OUTPUT,
    Choose,
    Control,
    Encoding,
    Eyes,
    FrameHeader,
    Gaze,
    ModelChange,
    ModelPick,
    ParamChange,
    ProtocolError,
    Reset,
    Viewport,
    payload,
)
from gazehdr.recordings import RecordingLibrary
from gazehdr.scenes import Scene
from gazehdr.scenes.library import SceneLibrary
from gazehdr.sim import Geometry, Params, Simulator
from gazehdr.sim.layout import MAX_SIZE, MIN_SIZE
from gazehdr.sim.models import ACUITY_MODELS, AFTERIMAGE_MODELS, Models
from gazehdr.sim.params import OURS, SECTIONS, check_remote_change

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
    model: Models = field(default_factory=Models)
    #: The right pane's model in split view; None: one model over the whole frame.
    split: Models | None = None
    params: Params = field(default_factory=Params)
    seed: int = 0
    backend: str = "opencl"
    encoding: Encoding = Encoding.f16
    #: Take the viewer's aspect ratio for the frame, keeping width·height as the pixel budget.
    fit_viewport: bool = True
    #: Keep a journal of session-log records (`Session.take_journal`).
    record: bool = False


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


def pane_params(params: Params, width: int, pane_width: int) -> Params:
    """`params` for a pane `pane_width` px wide of a frame `width` px wide. A pane is that part
    of the screen, not a whole screen: its pixels keep their size and so the frame's pixels per
    degree (blurs, the fovea and the retina's cells cover the angles the viewer sees), and two
    half-width panes cost what one whole frame does."""
    g = params.geometry
    pitch = g.screen_diagonal_m / math.hypot(g.screen_width_px, g.screen_height_px)
    covered = max(1, round(g.screen_width_px * pane_width / width))  # screen px of the pane
    diagonal = pitch * math.hypot(covered, g.screen_height_px)
    geometry = Geometry(diagonal, covered, g.screen_height_px, g.viewing_distance_m)
    return dataclasses.replace(params, geometry=geometry)


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
        self.split = settings.split
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
        if self.split is not None:
            self._check_split_width(self.size)
        #: One simulator per pane: the whole frame, or the left and right halves in split view.
        self.sims = self._new_simulators(self._pane_models())
        # The journal: records not yet taken, the time the next ones carry (ns, the end of the
        # coming step), and what it last said of the gaze and eyes.
        self._journal: list[sessionlog.Record] | None = [] if settings.record else None
        self._now_ns = 0
        self._journaled: tuple[tuple[float, float] | None, bool] = (None, True)
        self._fixations = self._blinks = 0
        self.log_screen = ScreenGeometry(**dataclasses.asdict(self.params.geometry))
        self._log(sessionlog.SceneChange(0, self.scene_name))
        self._log_models()
        self._log_params(Params())
        self._log(sessionlog.Note(0, f"gaze source {self.gaze_source}"))

    @property
    def sim(self) -> Simulator:
        """The simulator of the whole frame, or of the left pane in split view."""
        return self.sims[0]

    # --- what the viewers are told ------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        return {
            "scene": self.scene_name,
            "scenes": self.scenes.names(),
            "model": _names(self.model),
            "split": None if self.split is None else _names(self.split),
            "models": {"afterimage": list(AFTERIMAGE_MODELS), "acuity": list(ACUITY_MODELS)},
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

    def log_header(self) -> sessionlog.SessionHeader:
        """The header of this session's log: its journal's times are simulation nanoseconds."""
        s = self.settings
        tracker = {
            "name": "gazehdr serve", "session": self.id, "gaze_source": self.gaze_source,
            "frame": list(self.size), "seed": s.seed, "backend": s.backend,
        }  # fmt: skip
        return sessionlog.SessionHeader(
            tracker, self.log_screen, sessionlog.ClockInfo("simulation_ns")
        )

    @property
    def recording(self) -> bool:
        return self._journal is not None

    def end_journal(self) -> list[sessionlog.Record]:
        """The journal's last records, when the session ends: the gaze as it was held until
        now (so its log spans the whole session, and a replay holds that gaze as long)."""
        t = max(round(self.sim.time * 1e9), self._now_ns)
        point, _ = self._journaled
        if self._journal is None or point is None:
            return self.take_journal()
        self._log(GazeSample(t, *point))
        self._log(sessionlog.Note(t, "session ended"))
        return self.take_journal()

    def take_journal(self) -> list[sessionlog.Record]:
        """The records made since the last call (none when the session does not record)."""
        if self._journal is None:
            return []
        records, self._journal = self._journal, []
        return records

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
        dt = min(max(dt, 0.0), MAX_FRAME_DT)
        self._now_ns = round((self.sim.time + dt) * 1e9)
        for control, received_at in controls:
            try:
                changed |= self.apply(control, received_at)
            except (ValueError, TypeError, OSError) as e:  # ProtocolError is a ValueError
                notes.append({"type": "error", "message": str(e), "in": _type_of(control)})
        if changed:
            notes.append({"type": "state", **self.state()})
        return self._advance(dt), notes

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
            for sim in self.sims:
                sim.reset()
            self._log(sessionlog.EyeReset(self._now_ns))
            return False
        if isinstance(control, Viewport):
            if not self.settings.fit_viewport:
                return False
            budget = (self.settings.width, self.settings.height)
            size = fit_size(budget, (control.width, control.height))
            if size == self.size:
                return False
            # Too narrow for two panes: one model again, and the state tells the viewers.
            split = self.split if size[0] >= 2 * MIN_SIZE else None
            had = (self.model, self.split)
            self._rebuild(size=size, split=split)
            self._log(sessionlog.Note(self._now_ns, f"frame {size[0]}x{size[1]}"))
            if (self.model, self.split) != had:
                self._log_models()
            return True
        if isinstance(control, ParamChange):
            return self._set_params(control.values)
        if isinstance(control, ModelChange):
            return self._set_models(control.model, control.split)
        if isinstance(control, Choose):
            return self._choose(control.what, control.name)
        raise ProtocolError(f"unhandled control {control!r}")

    # --- internals ----------------------------------------------------------------------------

    def _choose(self, what: str, name: str) -> bool:
        if what == "scene":
            self.scene = self.scenes.open(name)
            self.scene_name = name
            self._load_scene(reset=True)
            self._log(sessionlog.SceneChange(self._now_ns, name))
            return True
        if name.startswith("replay:"):
            self._track = self.recordings.track(name.removeprefix("replay:"))
            self._track_start = self.sim.time
        elif name in GAZE_SOURCES:
            self._track = None
        else:
            known = ", ".join([*GAZE_SOURCES, "replay:NAME"])
            raise ValueError(f"unknown gaze source {name!r}; available: {known}")
        self.gaze_source = name
        self._log(sessionlog.Note(self._now_ns, f"gaze source {name}"))
        return True

    def _set_params(self, values: dict[str, Any]) -> bool:
        merged = {**self.params.to_dict(), **values}
        try:
            check_remote_change(self.params, values)
            params = Params.from_dict(merged)
        except (TypeError, ValueError) as e:
            raise ValueError(f"parameters refused: {e}") from None
        if params == self.params:
            return False
        before = self.params
        self._rebuild(params=params)
        self._log_params(before)
        return True

    def _set_models(self, pick: ModelPick, split: ModelPick | EllipsisType | None) -> bool:
        """Switch models; the new simulators continue the eye's time and adaptation (and its
        retina where the afterimage model and pane size stay), else the retina starts settled.
        Nothing changes unless every simulator could be built."""
        model = _merge(self.model, pick)
        if split is ...:
            right = self.split
        elif split is None:
            right = None
        else:  # a part not named follows the pane's current model, or the left one's
            right = _merge(self.split or model, split)
        if right is not None:
            self._check_split_width(self.size)
        if (model, right) == (self.model, self.split):
            return False
        self._rebuild(model=model, split=right)
        self._log_models()
        return True

    def _rebuild(self, **changes: Any) -> None:
        """Set `changes` (size, params, model, split) and new simulators for them, continuing
        the eye; if a simulator cannot be built, nothing changes."""
        before = {name: getattr(self, name) for name in changes}
        for name, value in changes.items():
            setattr(self, name, value)
        try:
            self.sims = self._new_simulators(self._pane_models(), keep_from=self.sims)
        except Exception:
            for name, value in before.items():
                setattr(self, name, value)
            raise

    def _log(self, record: sessionlog.Record) -> None:
        if self._journal is not None:
            self._journal.append(record)

    def _log_models(self) -> None:
        split = None if self.split is None else str(self.split)
        self._log(sessionlog.ModelChange(self._now_ns, str(self.model), split))

    def _log_params(self, before: Params) -> None:
        """The parameters that differ from `before` (at the start: from the defaults)."""
        if self._journal is None:
            return
        old, new = before.to_dict(), self.params.to_dict()
        changed = {name: value for name, value in new.items() if old[name] != value}
        if changed:
            self._log(sessionlog.ParamsChange(self._now_ns, changed))

    def _log_gaze(self) -> None:
        """The gaze and eyes this step follows, when they changed: the gaze in the scene's
        terms (a pane's, in split view), as a sample in `log_screen` pixels and one fixation."""
        if self._journal is None:  # every step: nothing to work out unless it is kept
            return
        panes = len(self.sims)
        (gx, gy), (w, h) = self._pane_gaze(panes), self._pane_size(panes)
        point = (
            gx / w * self.log_screen.screen_width_px,
            gy / h * self.log_screen.screen_height_px,
        )
        last_point, last_eyes = self._journaled
        t = self._now_ns
        if point != last_point:
            self._fixations += 1
            self._log(GazeSample(t, *point))
            self._log(sessionlog.GazeEvent("fixation_start", self._fixations, t, *point))
        if self.eyes_open != last_eyes:
            self._blinks += not self.eyes_open
            kind = "blink_end" if self.eyes_open else "blink_start"
            self._log(sessionlog.GazeEvent(kind, self._blinks, t))
        self._journaled = (point, self.eyes_open)

    def _pane_models(self) -> list[Models]:
        return [self.model] if self.split is None else [self.model, self.split]

    @staticmethod
    def _check_split_width(size: tuple[int, int]) -> None:
        if size[0] < 2 * MIN_SIZE:
            raise ValueError(f"a frame {size[0]} px wide is too narrow for split view")

    def _pane_size(self, panes: int) -> tuple[int, int]:
        """Pixels of one pane: the frame, or half of it (an odd last column stays black)."""
        return (self.size[0] // panes, self.size[1])

    def _pane_gaze(self, panes: int) -> tuple[float, float]:
        """The gaze in one pane's pixels. In split view the pointer (or tracker) over either
        half looks at the same point of the scene: x - pane width over the right half; a gaze
        left or right of the screen stays off the pane on that side."""
        w, h = self._pane_size(panes)
        x = self.gaze[0] * self.size[0]
        return (x - w if panes == 2 and x >= w else x, self.gaze[1] * h)

    def _new_simulators(
        self, panes: list[Models], keep_from: list[Simulator] | None = None
    ) -> list[Simulator]:
        """A settled simulator per pane, each continuing the eye of the old pane at its place
        (a new right pane continues the left one); the scene as it is at that time."""
        s = self.settings
        w, h = self._pane_size(len(panes))
        params = pane_params(self.params, self.size[0], w)
        gaze = self._pane_gaze(len(panes))
        t = keep_from[0].time if keep_from else 0.0
        frame = self.scene.render(t, w, h)
        sims = []
        for i, model in enumerate(panes):
            try:
                sim = Simulator(
                    w, h, params=params, backend=s.backend, seed=s.seed,
                    afterimage=model.afterimage, acuity=model.acuity,
                )  # fmt: skip
            except ImportError as e:  # a baseline that is not part of this installation
                raise ValueError(f"model {model} is not available: {e}") from None
            old = keep_from[min(i, len(keep_from) - 1)] if keep_from else None
            sim.start(frame, gaze, self.eyes_open, continue_from=old)
            sims.append(sim)
        self._loaded = self.scene.state_at(t)
        return sims

    def _load_scene(self, reset: bool) -> None:
        t = self.sim.time
        self._loaded = self.scene.state_at(t)
        frame = self.scene.render(t, *self._pane_size(len(self.sims)))
        for sim in self.sims:
            sim.load_scene(frame, reset=reset)

    def _sync_scene(self) -> None:
        """Load the scene as it is at the simulators' time, if that differs from what they see."""
        if self.scene.animated and self.scene.state_at(self.sim.time) != self._loaded:
            self._load_scene(reset=False)

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
            self._track = open_track("synthetic", seed=seed, duration=SYNTHETIC_LOOP_S)
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
        self._log_gaze()
        sim, (w, h) = self.sim, self.size
        gaze = self._pane_gaze(len(self.sims))
        # Split the step where the scene changes: a flash shorter than a frame is seen for
        # exactly its duration, never skipped nor stretched to the whole frame. All panes
        # take the same steps.
        end = sim.time + dt
        while (change := self.scene.next_change(sim.time)) is not None and change < end:
            step = change - sim.time
            for pane in self.sims:
                pane.step(step, gaze=gaze, eyes_open=self.eyes_open)
            self._sync_scene()
        self._sync_scene()
        encoding = self.settings.encoding
        step = max(0.0, end - sim.time)
        outs = [
            pane.step(step, gaze=gaze, eyes_open=self.eyes_open, output=SIM_OUTPUT[encoding])
            for pane in self.sims
        ]
        stepped = time.perf_counter()
        data = payload(_side_by_side(outs, w))  # the device already encoded each pane
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
            split=len(self.sims) == 2,
        )
        self.frame += 1
        new_gaze_at, self._new_gaze_at = self._new_gaze_at, None
        return Frame(header, data, stepped - started, encoded - stepped, new_gaze_at)


def _names(model: Models) -> dict[str, str]:
    return {"afterimage": model.afterimage, "acuity": model.acuity}


def _merge(model: Models, pick: ModelPick) -> Models:
    """`model` with the parts `pick` names; unknown names raise ValueError listing the choices."""
    return Models(pick.afterimage or model.afterimage, pick.acuity or model.acuity)


def _side_by_side(panes: list[np.ndarray], width: int) -> np.ndarray:
    """The encoded panes next to each other in a frame `width` px wide (one pane: as it is)."""
    if len(panes) == 1:
        return panes[0]
    first = panes[0]
    frame = np.zeros((first.shape[0], width, *first.shape[2:]), first.dtype)  # 0 is black
    w = first.shape[1]
    for i, pane in enumerate(panes):
        frame[:, i * w : (i + 1) * w] = pane
    return frame


def _type_of(control: Control) -> str:
    if isinstance(control, Choose):
        return control.what
    return {
        Viewport: "viewport", Gaze: "gaze", Eyes: "eyes", ModelChange: "model",
        ParamChange: "params", Reset: "reset",
    }.get(type(control), "unknown")  # fmt: skip


__all__ = ["GAZE_SOURCES", "Frame", "RemoteGaze", "Session", "SessionSettings", "pane_params"]
