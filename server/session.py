"""One viewing session: a simulated eye, its scene, its gaze, and the frames it produces.

In split view the session runs two simulators, one per half of the frame, with the same scene,
gaze and steps and a model each, so two models can be compared side by side.

`Session` is synchronous and knows no sockets and no clock: the caller passes the elapsed
time, the control messages that arrived and a clock to time the step with, and gets back an
encoded frame plus the JSON messages to tell the viewers. `gazehdr.live` runs it on a thread at
real time. Its gaze comes through one `gazehdr.gaze.GazeInput`, read when a step starts and,
with `SessionSettings.late_gaze`, again once the step is simulated: the viewer's pointer
(`pointer`, which the caller writes), a tracker, or a track. The simulated eye and its stepping
are `gazehdr.eye.Eye`'s, shared with offline rendering.

The gaze source also sets the parameters `tracker_accuracy_deg` and `tracker_rate_hz` (what the
Sec. 5 foveal blind spot can show depends on them) from its figures (`GazeInput.figures`): the
pointer and synthetic paths are exact (0 deg, the session's frame rate), a tracker gives its
hello's accuracy and its measured rate, a replay its recording's. What a source does not say
is the default (the paper's tracker). A tracker parameter the user set, to anything but its
default (the server's `--params`, or a viewer's change), stays as set; set back to the default
(the panel's paper preset does), it follows the source again.

A session that records keeps a journal of session-log records (drivers/sessionlog/) for its
caller to write: the scene, parameters and models it ran with and every change to them, resets,
and the gaze and eyes it followed, on its simulation clock. Each carries the end time of the
first step it drove, so an offline render at any frame rate (server/render.py) meets each at
the same step the live session did.

Past 600 lines because a session's controls (scene, models, parameters, gaze source, viewport)
each change the same simulators, journal and viewer state, which this one class owns; the
pieces that stand alone already live elsewhere (gaze inputs, the eye, the journal format).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from types import EllipsisType
from typing import Any

from gazehdr.drivers import registry, sessionlog
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.eye import Eye
from gazehdr.gaze import (
    REMOTE,
    REMOTE_PREFIX,
    GazeInput,
    GazeReading,
    LatestGaze,
    PointerGaze,
    Trackers,
    TrackGaze,
    is_tracker_source,
)
from gazehdr.protocol import (
    HEADER_BYTES,
    SIM_OUTPUT,
    Choose,
    Control,
    Encoding,
    FrameHeader,
    ModelChange,
    ModelPick,
    ParamChange,
    ProtocolError,
    Reset,
    SceneMap,
    SceneSettings,
    Viewport,
    frame_buffer,
)
from gazehdr.recordings import RecordingLibrary
from gazehdr.scenes.estimate import KINDS, kind_luminance
from gazehdr.scenes.image import ImageScene
from gazehdr.scenes.library import BUILTIN_INFO, SceneLibrary
from gazehdr.sim import Params, Simulator
from gazehdr.sim.layout import MAX_SIZE, MIN_SIZE
from gazehdr.sim.models import ACUITY_MODELS, AFTERIMAGE_MODELS, Models
from gazehdr.sim.params import OURS, SECTIONS, check_remote_change, param_info
from gazehdr.sim.presets import PRESETS, describe, preset
from gazehdr.warp import pack as pack_warp

#: Tracks a session follows by name alone (a recording is `replay:NAME`, from the server's
#: recordings).
NAMED_TRACKS = tuple(k.name for k in registry.named_tracks())
GAZE_SOURCES = ("mouse", *NAMED_TRACKS, REMOTE)
#: A stalled server steps the eye by at most this much at once (s), so it never leaps.
MAX_FRAME_DT = 1.0
SYNTHETIC_LOOP_S = 600.0  # a named track (the synthetic scan path) repeats after this long
SIZE_STEP = 8  # frame sides are multiples of this when fitted to a viewport
#: The parameters a session takes from its gaze source's figures (`_with_figures`).
TRACKER_PARAMS = ("tracker_accuracy_deg", "tracker_rate_hz")
DEFAULTS = Params()
#: The estimate's scene kinds, as the panel offers them.
SCENE_KINDS = {
    name: {"ev": k.ev, "what": k.what, "luminance": kind_luminance(name)}
    for name, k in KINDS.items()
}
PARAM_INFO_JSON = param_info()
#: Every preset's whole parameters, for the panel's preset chooser.
PRESET_VALUES = {name: preset(name).to_dict() for name in PRESETS}
#: What a session tells its viewers: JSON notes, and binary scene maps (`SceneMap`).
Note = dict[str, Any] | bytes
Arrived = list[tuple[Control, float]]  # control messages and when each arrived


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
    #: Show each frame from the newest gaze, read once the step's simulation is done, rather
    #: than the one the step started with (`Eye.step`'s late_gaze): a pointer or tracker gaze
    #: that comes during a step is in its frame. The eye's own step (adaptation, the retina)
    #: follows the gaze it started with, which is what the session log keeps; offline renders
    #: of the log show frames from that gaze, so they match the live frames exactly only with
    #: this off (`gazehdr serve --no-late-gaze`).
    late_gaze: bool = True


@dataclass(frozen=True)
class Frame:
    header: FrameHeader
    #: The frame's message as `header` has it (no frames dropped before it), its pixels put
    #: there by the device (`protocol.frame_buffer`): most viewers are sent it as it is, and
    #: the event loop copies no pixels under the GIL while the next step needs it. b"" when no
    #: viewer wanted the plain frame.
    plain: bytes | memoryview
    sim_seconds: float
    #: From the step's simulation to its frame's forms (the warp layers' packing: a plain
    #: frame's pixels are encoded by the device, into its message).
    encode_seconds: float
    #: When the gaze this frame is the first to use reached the server (None: no new gaze).
    gaze_received_at: float | None
    #: The same frame as late-warp layers (`gazehdr.warp`), made when a viewer asked for them.
    warp: bytearray | None = None

    @property
    def payload(self) -> memoryview:
        """The frame's pixels as its encoding has them (empty when no plain frame was made)."""
        return memoryview(self.plain)[HEADER_BYTES:]

    def message(self, dropped: int, warp: bool = False) -> bytes | memoryview | None:
        """The frame's message, as late-warp layers if `warp`; None when the step did not make
        that form (the viewer switched between the step and the send: it takes the next)."""
        if warp:
            if self.warp is None:
                return None
            header = dataclasses.replace(self.header, dropped=dropped, encoding=Encoding.warp)
            return header.pack() + self.warp
        if not self.plain:
            return None
        if dropped == 0:
            return self.plain
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
    """One viewing. `clock` (monotonic seconds) times the steps for the metrics and the frame
    header; `trackers` are the server's gaze daemons, which a session may follow."""

    def __init__(
        self,
        session_id: str,
        settings: SessionSettings,
        scenes: SceneLibrary,
        *,
        clock: Callable[[], float],
        trackers: Trackers | None = None,
        recordings: RecordingLibrary | None = None,
    ) -> None:
        self.id = session_id
        self.settings = settings
        self.scenes = scenes
        self.clock = clock
        self.trackers = trackers or Trackers()
        self.recordings = recordings or RecordingLibrary(None)
        self.scene_name = settings.scene
        self._scene_version = scenes.version(settings.scene)
        self.frame = 0
        #: The viewer's pointer; its caller writes it (from any thread: readings are swapped).
        self.pointer = PointerGaze()
        self.gaze_source = settings.gaze_source
        self._input = self._open_gaze(settings.gaze_source, 0.0, GazeReading())
        self.reading = self._input.at(0.0)  # the gaze the last step followed
        # The tracker parameters this session set from its source's figures (`_with_figures`).
        self._applied: dict[str, float] = {}
        params = self._with_figures(settings.params)
        panes = [settings.model] if settings.split is None else [settings.model, settings.split]
        size = (settings.width, settings.height)
        if settings.split is not None:
            _check_split_width(size)
        self.eye = Eye(
            scenes.open(settings.scene), size, params, panes,
            backend=settings.backend, seed=settings.seed, gaze=self.gaze,
            eyes_open=self.reading.eyes_open,
        )  # fmt: skip
        # The last scene map made, and what it showed (`scene_map`).
        self._scene_map: bytes | None = None
        self._mapped: tuple[Eye, int] | None = None
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

    # --- what the eye is doing -------------------------------------------------------------

    @property
    def sim(self) -> Simulator:
        """The simulator of the whole frame, or of the left pane in split view."""
        return self.eye.sims[0]

    @property
    def size(self) -> tuple[int, int]:
        return self.eye.size

    @property
    def params(self) -> Params:
        return self.eye.params

    @property
    def model(self) -> Models:
        return self.eye.panes[0]

    @property
    def split(self) -> Models | None:
        """The right pane's model in split view, else None."""
        return self.eye.panes[1] if len(self.eye.panes) == 2 else None

    @property
    def gaze(self) -> tuple[float, float]:
        """The gaze the last step followed, as fractions of the frame."""
        return (self.reading.x, self.reading.y)

    def newer_gaze_at(self) -> float | None:
        """When the gaze source received a reading the last step did not follow (a pointer or
        tracker that moved since), else None; a track has no such readings. Read between
        steps: the live loop starts the next step early for it (`live.step_start`)."""
        if not isinstance(self._input, LatestGaze):
            return None
        came = self._input.reading.received_at
        read = self.reading.received_at
        return came if came is not None and (read is None or came > read) else None

    # --- what the viewers are told ------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        trackers = self.trackers.describe()
        return {
            "scene": self.scene_name,
            "scenes": self.scenes.names(),
            "scene_info": self._scene_info(),
            "scene_kinds": SCENE_KINDS,
            "model": _names(self.model),
            "split": None if self.split is None else _names(self.split),
            "models": {"afterimage": list(AFTERIMAGE_MODELS), "acuity": list(ACUITY_MODELS)},
            "gaze_source": self.gaze_source,
            "gaze_sources": [
                *GAZE_SOURCES,
                *(REMOTE_PREFIX + t["name"] for t in trackers),
                *(f"replay:{n}" for n in self.recordings.names()),
            ],
            "trackers": trackers,
            "width": self.size[0],
            "height": self.size[1],
            "fps": self.settings.fps,
            "encoding": self.settings.encoding.name,
            "device": self.sim.device,
            "params": self.params.to_dict(),
            "preset": describe(self.params),
            "presets": PRESET_VALUES,
            "defaults": Params().to_dict(),
            "sections": SECTIONS,
            "ours": sorted(OURS),
            "param_info": PARAM_INFO_JSON,
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
        self, dt: float, controls: Arrived, plain: bool = True, warp: bool = False
    ) -> tuple[Frame, list[Note]]:
        """Apply `controls` (each with its arrival time), step by `dt` s, encode the frame:
        in the session's encoding if `plain` (a viewer wants it), as late-warp layers if `warp`.

        Returns the frame and the messages for the viewers: a `state` when something they
        show changed, an `error` for each control refused (the session goes on unchanged), and
        a scene map when what the eye looks at changed.
        """
        notes: list[Note] = []
        changed = False
        dt = min(max(dt, 0.0), MAX_FRAME_DT)
        self._now_ns = round((self.sim.time + dt) * 1e9)
        for control, _received_at in controls:
            try:
                changed |= self.apply(control)
            except (ValueError, TypeError, OSError) as e:  # ProtocolError is a ValueError
                notes.append({"type": "error", "message": str(e), "in": _type_of(control)})
        changed |= self._bind_remote()
        try:
            changed |= self._follow_figures()
        except ValueError as e:  # figures the model refuses: the parameters stay as they were
            notes.append({"type": "error", "message": str(e), "in": "params"})
        try:
            changed |= self._follow_library()
        except (ValueError, OSError) as e:  # the upload went away or became unreadable
            notes.append({"type": "error", "message": str(e), "in": "scene"})
        if changed:
            notes.append({"type": "state", **self.state()})
        return self._advance(dt, plain or not warp, warp), notes

    def scene_map(self) -> bytes:
        """The scene map of what the eye looks at now (`SceneMap`, packed): made again only
        when the scene or the eye changed, so the same object comes back until then. Call it
        where the session steps (it reads the simulator), and only when a viewer wants one."""
        if self._scene_map is None or self._mapped != (self.eye, self.eye.loads):
            self._mapped = (self.eye, self.eye.loads)
            self._scene_map = SceneMap(self.frame, *self.sim.scene_maps()).pack()
        return self._scene_map

    def apply(self, control: Control) -> bool:
        """One control message; True when the viewers' `state` changed. (The pointer and the
        eyes are not controls: they reach the session through `pointer`.)"""
        if isinstance(control, Reset):
            self.eye.reset()
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
            panes = self.eye.panes if size[0] >= 2 * MIN_SIZE else self.eye.panes[:1]
            had = self.eye.panes
            self._rebuild(size=size, panes=panes)
            self._log(sessionlog.Note(self._now_ns, f"frame {size[0]}x{size[1]}"))
            if self.eye.panes != had:
                self._log_models()
            return True
        if isinstance(control, ParamChange):
            return self._set_params(control.values)
        if isinstance(control, ModelChange):
            return self._set_models(control.model, control.split)
        if isinstance(control, Choose):
            return self._choose(control.what, control.name)
        if isinstance(control, SceneSettings):
            self.scenes.configure(self.scene_name, control.values)
            return False  # applied by _follow_library, as any change of the library's is
        raise ProtocolError(f"unhandled control {control!r}")

    # --- internals ----------------------------------------------------------------------------

    def _open_gaze(self, name: str, t: float, holding: GazeReading) -> GazeInput:
        """The input for gaze source `name`: a track starts at simulation time `t`; `remote`
        holds the gaze at `holding` until it is bound. An unknown name is a ValueError listing
        the choices."""
        if name == "mouse":
            return self.pointer
        if is_tracker_source(name):
            return self.trackers.feed(name.removeprefix(REMOTE_PREFIX))
        if name == REMOTE:  # bound to a tracker by `_bind_remote`; until then the gaze holds
            return LatestGaze(holding)
        if name in NAMED_TRACKS:
            track = registry.open_track(name, seed=self.settings.seed, duration=SYNTHETIC_LOOP_S)
            return TrackGaze(track, 0.0, SYNTHETIC_LOOP_S)
        if name.startswith("replay:"):
            track, known = self.recordings.replay(name.removeprefix("replay:"))
            return TrackGaze(track, t, getattr(track, "duration", SYNTHETIC_LOOP_S), known)
        known = ", ".join([*GAZE_SOURCES, REMOTE_PREFIX + "TRACKER", "replay:NAME"])
        raise InputError(f"unknown gaze source {name!r}; available: {known}")

    def _with_figures(self, params: Params) -> Params:
        """`params` with the tracker parameters of the gaze source's figures (the default
        where it gives none), except those the user set: a value that is neither the default
        nor what this session last set."""
        figures = self._input.figures(self.settings.fps)
        changes = {}
        for name, figure in zip(
            TRACKER_PARAMS, (figures.accuracy_deg, figures.rate_hz), strict=True
        ):
            value, default = getattr(params, name), getattr(DEFAULTS, name)
            if value != default and value != self._applied.get(name):
                continue  # the user's
            target = default if figure is None else figure
            self._applied[name] = target
            if value != target:
                changes[name] = target
        return params.replace(**changes) if changes else params

    def _follow_figures(self) -> bool:
        """The gaze source's figures changed (another source, a hello, a measured rate)."""
        params = self._with_figures(self.params)
        if params is self.params:
            return False
        before = self.params
        self._rebuild(params=params)
        self._log_params(before)
        return True

    def _follow_library(self) -> bool:
        """A change of the scene's settings (or file) in the library: seen from now on."""
        version = self.scenes.version(self.scene_name)
        if version == self._scene_version:
            return False
        self._scene_version = version
        self.eye.look_at(self.scenes.refresh(self.scene_name, self.eye.scene))
        return True

    def _scene_info(self) -> dict[str, Any]:
        scene = self.eye.scene
        return scene.describe() if isinstance(scene, ImageScene) else dict(BUILTIN_INFO)

    def _bind_remote(self) -> bool:
        """`remote` follows the tracker once exactly one is connected (see gazehdr.gaze)."""
        if self.gaze_source != REMOTE or (feed := self.trackers.sole_connected()) is None:
            return False
        self.gaze_source, self._input = REMOTE_PREFIX + feed.name, feed
        self._log(sessionlog.Note(self._now_ns, f"gaze source {self.gaze_source}"))
        return True

    def _choose(self, what: str, name: str) -> bool:
        if what == "scene":
            scene = self.scenes.open(name)
            self.eye.look_at(scene)
            self.scene_name = name
            self._scene_version = self.scenes.version(name)
            self._log(sessionlog.SceneChange(self._now_ns, name))
            return True
        self._input = self._open_gaze(name, self.sim.time, self.reading)
        self.gaze_source = name
        self._log(sessionlog.Note(self._now_ns, f"gaze source {name}"))
        return True

    def _set_params(self, values: dict[str, Any]) -> bool:
        merged = {**self.params.to_dict(), **values}
        try:
            check_remote_change(self.params, values)
            params = Params.from_dict(merged)
        except (TypeError, ValueError) as e:
            raise InputError(f"parameters refused: {e}") from None
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
            _check_split_width(self.size)
        panes = (model,) if right is None else (model, right)
        if panes == self.eye.panes:
            return False
        self._rebuild(panes=panes)
        self._log_models()
        return True

    def _rebuild(self, **changes: Any) -> None:
        """A new eye with `changes` (size, params, panes), continuing this one; if it cannot
        be built, nothing changes."""
        self.eye = self.eye.rebuilt(self.gaze, self.reading.eyes_open, **changes)

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

    def _log_gaze(self, t: int) -> None:
        """The gaze and eyes this step follows, when they changed, at `t` ns: the gaze in the
        scene's terms (a pane's, in split view), as a sample in `log_screen` pixels and one
        fixation."""
        if self._journal is None:  # every step: nothing to work out unless it is kept
            return
        (gx, gy), (w, h) = self.eye.pane_gaze(self.gaze), self.eye.pane_size
        point = (
            gx / w * self.log_screen.screen_width_px,
            gy / h * self.log_screen.screen_height_px,
        )
        last_point, last_eyes = self._journaled
        eyes_open = self.reading.eyes_open
        if point != last_point:
            self._fixations += 1
            self._log(GazeSample(t, *point))
            self._log(sessionlog.GazeEvent("fixation_start", self._fixations, t, *point))
        if eyes_open != last_eyes:
            self._blinks += not eyes_open
            kind = "blink_end" if eyes_open else "blink_start"
            self._log(sessionlog.GazeEvent(kind, self._blinks, t))
        self._journaled = (point, eyes_open)

    def _late_gaze(self, t: float) -> tuple[float, float] | None:
        """The gaze source read again at `t` once the step is simulated: its gaze when it has
        a newer one (a pointer that moved meanwhile; a track's is the same at `t`), which the
        frame, its header and the next step take up. The eyes stay as the step had them."""
        reading = self._input.at(t)
        if reading.received_at == self.reading.received_at:
            return None
        self.reading = dataclasses.replace(reading, eyes_open=self.reading.eyes_open)
        # Logged 1 ns after the step's own gaze (at the step's end): an offline render then
        # steps this step from that one, as the eye did, and the next from this one.
        self._log_gaze(self._now_ns + 1)
        return self.gaze

    def _advance(self, dt: float, plain: bool = True, warp: bool = False) -> Frame:
        started = self.clock()
        read_at = self.sim.time
        previous, self.reading = self.reading, self._input.at(read_at)
        self._log_gaze(self._now_ns)
        eyes_open = self.reading.eyes_open
        w, h = self.size
        output, pixels = None, None
        message: bytes | memoryview = b""
        if plain:  # the panes are composed into the message
            output = SIM_OUTPUT[self.settings.encoding]
            message, pixels = frame_buffer(w, h, self.settings.encoding)
        late = functools.partial(self._late_gaze, read_at) if self.settings.late_gaze else None
        self.eye.step(dt, self.gaze, eyes_open, output, late, pixels)
        new_gaze_at = self.reading.received_at  # the step's gaze, or the late one
        if new_gaze_at == previous.received_at:
            new_gaze_at = None
        layers = self.eye.warp_layers() if warp else None
        stepped = self.clock()
        warp_data = None if layers is None else pack_warp(layers, w, self.params)
        encoded = self.clock()
        sim = self.sim
        gx, gy = sim.gaze
        header = FrameHeader(
            frame=self.frame,
            gaze_seq=self.reading.seq,
            time=sim.time,
            gaze_x=gx / w,
            gaze_y=gy / h,
            adaptation=sim.adaptation,
            rho=sim.rho_at_gaze(),
            width=w,
            height=h,
            encoding=self.settings.encoding,
            eyes_open=eyes_open,
            tracker=self._input is not self.pointer,
            server_ms=(encoded - started) * 1e3,
            split=len(self.eye.sims) == 2,
        )
        if message:
            message[:HEADER_BYTES] = header.pack()
        self.frame += 1
        return Frame(header, message, stepped - started, encoded - stepped, new_gaze_at, warp_data)


def _check_split_width(size: tuple[int, int]) -> None:
    if size[0] < 2 * MIN_SIZE:
        raise InputError(f"a frame {size[0]} px wide is too narrow for split view")


def _names(model: Models) -> dict[str, str]:
    return {"afterimage": model.afterimage, "acuity": model.acuity}


def _merge(model: Models, pick: ModelPick) -> Models:
    """`model` with the parts `pick` names; unknown names raise ValueError listing the choices."""
    return Models(pick.afterimage or model.afterimage, pick.acuity or model.acuity)


def _type_of(control: Control) -> str:
    if isinstance(control, Choose):
        return control.what
    return {
        Viewport: "viewport", ModelChange: "model", ParamChange: "params", Reset: "reset",
        SceneSettings: "scene_settings",
    }.get(type(control), "unknown")  # fmt: skip


__all__ = ["GAZE_SOURCES", "Frame", "Session", "SessionSettings"]
