"""Offline rendering: a scene seen along a gaze track, written as numbered frames.

A pure loop (scene → simulator → dither) with the file writing at its edge. The output depends
only on the arguments: the simulator's noise and the dither both derive from `seed`, and time
advances by exactly `1/fps` per frame, never by the wall clock.

A recorded viewing session (`gazehdr serve --record`) also changed its scene, parameters and
models and reset the eye as it ran; `recorded_changes` reads those from its log and `render`
makes each before the first step that ends at or after its time, as the live session did.
The eye steps exactly as a live session's does (`gazehdr.eye.Eye`, one pane), so a recorded
session renders to the frames it showed.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from tqdm import tqdm

from gazehdr.apng import ApngWriter
from gazehdr.dither import dither8
from gazehdr.drivers import registry
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.samples import GazeTrack
from gazehdr.drivers.sessionlog import SessionLog, read_session_log
from gazehdr.eye import Eye
from gazehdr.scenes import Scene, open_scene
from gazehdr.scenes.exr import write_exr
from gazehdr.scenes.library import SceneLibrary
from gazehdr.sim import Params
from gazehdr.sim.layout import check_frame_size
from gazehdr.sim.models import Models
from gazehdr.sim.presets import DEFAULT_PRESET, load_params

#: The animation `video` writes beside the frames.
VIDEO_NAME = "render.apng"
#: Files this module writes; `overwrite` removes exactly these and nothing else.
FRAME_PATTERNS = ("frame_*.png", "frame_*.exr", VIDEO_NAME)
#: zlib level for the PNGs: dithered frames barely compress, and level 1 writes them about 4x
#: faster than Pillow's default 6 for files about a quarter larger (they are intermediates).
PNG_COMPRESS_LEVEL = 1


@dataclass(frozen=True)
class Change:
    """One thing a recorded session changed, `t_ns` into the render (whole nanoseconds, as
    the log and its gaze track count): a scene, some parameters (the values that changed),
    the models, or a reset of the eye."""

    t_ns: int
    scene: Scene | None = None
    params: dict[str, Any] | None = None
    models: Models | None = None
    reset: bool = False


def recorded_changes(
    log: SessionLog,
    t0_ns: int,
    scenes: SceneLibrary,
    *,
    scene: bool = True,
    params: bool = True,
    models: bool = True,
) -> list[Change]:
    """The changes of `log` in time order, on a time line starting at `t0_ns` (the gaze
    track's); leave out the kinds the caller sets itself. A scene, model or parameter the log
    names that does not exist here is a ValueError now, before anything is rendered."""
    changes = [Change(r.t_ns - t0_ns, reset=True) for r in log.resets]
    if scene:
        changes += [Change(r.t_ns - t0_ns, scene=scenes.open(r.name)) for r in log.scenes]
    if models:
        changes += [Change(r.t_ns - t0_ns, models=Models.parse(r.model)) for r in log.models]
    if params:
        merged = Params().to_dict()
        for r in log.params:
            merged |= r.values
            Params.from_dict(merged)  # each step of the way must be valid
            changes.append(Change(r.t_ns - t0_ns, params=r.values))
    return sorted(changes, key=lambda c: c.t_ns)  # stable: at equal times, kinds in this order


@dataclass(frozen=True)
class RenderSummary:
    frames: int
    out_dir: Path
    wall_seconds: float


def frame_count(seconds: float, fps: float) -> int:
    """Frames at t = i/fps that start before `seconds` (a tiny tolerance absorbs float error)."""
    return max(1, math.ceil(seconds * fps - 1e-9))


def _check(seconds: float, fps: float, width: int, height: int, seed: int) -> None:
    if seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed}")
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a finite positive number, got {fps}")
    if not (math.isfinite(seconds) and seconds > 0):
        raise InputError(f"seconds must be a finite positive number, got {seconds}")
    try:
        check_frame_size(width, height)
    except ValueError as exc:
        raise InputError(f"frame size {width}x{height} is out of range: {exc}") from None


def _prepare_out_dir(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output {out_dir} exists and is not a directory")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create output directory {out_dir}: {e.strerror}") from None
    old = sorted(p for pattern in FRAME_PATTERNS for p in out_dir.glob(pattern))
    if old and not overwrite:
        raise InputError(
            f"output directory {out_dir} already holds frames ({old[0].name}, ...); "
            f"choose another --out, or pass --overwrite (overwrite=True) to replace them"
        )
    for path in old:
        path.unlink()


def render(
    scene: Scene,
    track: GazeTrack,
    *,
    seconds: float,
    fps: float,
    width: int,
    height: int,
    seed: int,
    backend: str,
    out_dir: str | Path,
    afterimage: str = "jacobs",
    acuity: str = "stochastic",
    exr: bool = False,
    video: bool = False,
    progress: bool = True,
    params: Params | None = None,
    overwrite: bool = False,
    changes: Sequence[Change] = (),
) -> RenderSummary:
    """Simulate `seconds` of viewing; write `frame_NNNNN.png`, the dithered 8-bit display values.

    With `exr`, also `frame_NNNNN.exr`: the undithered display values as float32, for analysis
    and figures. With `video`, also `render.apng`: the PNG frames as one lossless animation at
    `fps` that browsers play (gazehdr.apng). Frame i shows the eye at t = i/fps: frame 0 is the
    equilibrium for the scene and the first gaze, each later frame steps 1/fps towards the gaze
    and scene at its own t.
    With `overwrite`, frames left in `out_dir` by an earlier render are removed first, so the
    directory holds one clean sequence. `afterimage` and `acuity` name the models
    (`gazehdr.sim.models`). `changes` are a recorded session's (`recorded_changes`), each made
    before the first step that ends at or after its time; those at or before 0 set the start.
    """
    started = time.perf_counter()
    _check(seconds, fps, width, height, seed)
    pending = deque(sorted(changes, key=lambda c: c.t_ns))
    params, models = params or Params(), Models(afterimage, acuity)
    while pending and pending[0].t_ns <= 0:
        first = pending.popleft()
        scene = first.scene or scene
        params = Params.from_dict(params.to_dict() | first.params) if first.params else params
        models = first.models or models
    # Before touching the directory: a model or backend that cannot be built leaves it alone.
    x, y, eyes_open = track.at(0.0)
    eye = Eye(
        scene, (width, height), params, [models], backend=backend, seed=seed, gaze=(x, y),
        eyes_open=eyes_open,
    )  # fmt: skip
    out_dir = Path(out_dir)
    _prepare_out_dir(out_dir, overwrite)
    dither_rng = np.random.default_rng([seed, 1])
    n = frame_count(seconds, fps)
    digits = max(5, len(str(n - 1)))
    dt = 1.0 / fps

    with contextlib.ExitStack() as stack:
        movie = None
        if video:
            movie = stack.enter_context(
                ApngWriter(out_dir / VIDEO_NAME, n, fps, compress_level=PNG_COMPRESS_LEVEL)
            )
        for i in tqdm(range(n), desc=scene.name, unit="frame", disable=not progress):
            t = i / fps
            x, y, eyes_open = track.at(t)
            while pending and pending[0].t_ns <= round(t * 1e9):  # as SessionTrack.at counts
                eye = _make(pending.popleft(), eye, (x, y), eyes_open)  # before the step it drives
            (v,) = eye.step(dt if i else 0.0, (x, y), eyes_open)
            stem = out_dir / f"frame_{i:0{digits}d}"
            rgb = dither8(v, dither_rng)
            Image.fromarray(rgb).save(stem.with_suffix(".png"), compress_level=PNG_COMPRESS_LEVEL)
            if movie is not None:
                movie.add(rgb)
            if exr:
                write_exr(stem.with_suffix(".exr"), v)
    return RenderSummary(n, out_dir, time.perf_counter() - started)


@dataclass(frozen=True)
class RenderRequest:
    """What `gazehdr render` was asked for, as plain values (a batch job's, too): resolved by
    `render_request` into a scene, a track and recorded changes and rendered by `render`.
    None takes the default: from a session log given as `gaze`, its scenes, seed, length,
    models and parameters; else the paper's models, seed 0 and 6 s."""

    gaze: str = "synthetic"
    scene: str | None = None
    seconds: float | None = None
    fps: float = 30.0
    width: int = 640
    height: int = 360
    seed: int | None = None
    backend: str = "opencl"
    afterimage: str | None = None
    acuity: str | None = None
    preset: str | None = None  # a named preset (gazehdr.sim.presets); None: the log's, or paper
    params: str | None = None  # a parameter file over the preset (partial is fine)
    data_dir: str | None = None  # where a recorded session's uploaded scenes are
    scale: float | None = None
    exr: bool = False
    video: bool = False


def render_request(
    request: RenderRequest,
    out_dir: str | Path,
    *,
    progress: bool = True,
    overwrite: bool = False,
    note: Any = None,
) -> RenderSummary:
    """Render `request` into `out_dir`: the one path of `gazehdr render`, one log or many.
    Mistakes in the request are ValueErrors before anything is written; `note(text)` hears
    what the user should know (default: printed to stderr)."""
    note = note or (lambda text: print(f"gazehdr: note: {text}", file=sys.stderr))
    r = request
    given_models = r.afterimage is not None or r.acuity is not None
    models = Models(r.afterimage or "jacobs", r.acuity or "stochastic")  # checks the names
    params = None
    if r.preset or r.params:
        params = load_params(r.preset or DEFAULT_PRESET, r.params)
    log, changes = None, []
    if Path(r.gaze).suffix.lower() == ".jsonl":
        if not Path(r.gaze).exists():  # a named pipe is fine
            raise InputError(f"gaze file {r.gaze!r} not found")
        log = read_session_log(r.gaze)
        track = log.fixation_track()
        changes = recorded_changes(
            log, track.t0_ns, SceneLibrary(Path(r.data_dir) if r.data_dir else None),
            scene=r.scene is None, params=params is None, models=not given_models,
        )  # fmt: skip
        if not given_models and any(m.split for m in log.models):
            note(
                "the session ran in split view at times; this renders its left pane (name the "
                "right pane's models with --afterimage/--acuity)"
            )
    seed = r.seed
    if seed is None:
        recorded = log.header.tracker.get("seed") if log else None
        seed = recorded if isinstance(recorded, int) and recorded >= 0 else 0
    seconds = r.seconds
    fps_ok = math.isfinite(r.fps) and r.fps > 0  # else render says what is wrong with it
    if seconds is None and log is not None and fps_ok:  # to its last record, of any kind
        seconds = (max(x.t_ns for x in log.records()) - track.t0_ns) / 1e9 + 1 / r.fps
    seconds = 6.0 if seconds is None else seconds
    if log is None:
        track = registry.open_track(r.gaze, seed=seed, duration=seconds)
    if r.scene is not None:
        scene = open_scene(r.scene, scale=r.scale)
    elif not any(c.scene for c in changes):
        raise InputError("SCENE is needed: the gaze given is not a session log naming its scene")
    else:  # the log's first scene; render takes it from the changes
        scene = next(c.scene for c in changes if c.scene)
    return render(
        scene, track, seconds=seconds, fps=r.fps, width=r.width, height=r.height, seed=seed,
        backend=r.backend, afterimage=models.afterimage, acuity=models.acuity, out_dir=out_dir,
        exr=r.exr, video=r.video, progress=progress, params=params, overwrite=overwrite,
        changes=changes,
    )  # fmt: skip


def _make(change: Change, eye: Eye, gaze: tuple[float, float], eyes_open: bool) -> Eye:
    """`eye` after a recorded `change`, made as the live session made it."""
    if change.scene is not None:
        eye.look_at(change.scene)
    if change.params is not None or change.models is not None:
        params = eye.params
        if change.params is not None:
            params = Params.from_dict(params.to_dict() | change.params)
        panes = [change.models] if change.models is not None else eye.panes
        eye = eye.rebuilt(gaze, eyes_open, params=params, panes=panes)
    if change.reset:
        eye.reset()
    return eye
