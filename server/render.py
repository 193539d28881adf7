"""Offline rendering: a scene seen along a gaze track, written as numbered frames.

A pure loop (scene → simulator → dither) with the file writing at its edge. The output depends
only on the arguments: the simulator's noise and the dither both derive from `seed`, and time
advances by exactly `1/fps` per frame, never by the wall clock.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from drivers.samples import GazeTrack
from server.apng import ApngWriter
from server.dither import dither8
from server.scenes import Scene
from server.scenes.exr import write_exr
from server.sim import Params, Simulator
from server.sim.layout import check_frame_size

#: The animation `video` writes beside the frames.
VIDEO_NAME = "render.apng"
#: Files this module writes; `overwrite` removes exactly these and nothing else.
FRAME_PATTERNS = ("frame_*.png", "frame_*.exr", VIDEO_NAME)
#: zlib level for the PNGs: dithered frames barely compress, and level 1 writes them about 4x
#: faster than Pillow's default 6 for files about a quarter larger (they are intermediates).
PNG_COMPRESS_LEVEL = 1


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
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a finite positive number, got {fps}")
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a finite positive number, got {seconds}")
    try:
        check_frame_size(width, height)
    except ValueError as exc:
        raise ValueError(f"frame size {width}x{height} is out of range: {exc}") from None


def _prepare_out_dir(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"output {out_dir} exists and is not a directory")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"cannot create output directory {out_dir}: {e.strerror}") from None
    old = sorted(p for pattern in FRAME_PATTERNS for p in out_dir.glob(pattern))
    if old and not overwrite:
        raise ValueError(
            f"output directory {out_dir} already holds frames ({old[0].name}, ...); "
            f"choose another or allow overwriting"
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
) -> RenderSummary:
    """Simulate `seconds` of viewing; write `frame_NNNNN.png`, the dithered 8-bit display values.

    With `exr`, also `frame_NNNNN.exr`: the undithered display values as float32, for analysis
    and figures. With `video`, also `render.apng`: the PNG frames as one lossless animation at
    `fps` that browsers play (server.apng). Frame i shows the eye at t = i/fps: frame 0 is the
    equilibrium for the scene and the first gaze, each later frame steps 1/fps towards the gaze
    and scene at its own t.
    With `overwrite`, frames left in `out_dir` by an earlier render are removed first, so the
    directory holds one clean sequence. `afterimage` and `acuity` name the models
    (`server.sim.models`).
    """
    started = time.perf_counter()
    _check(seconds, fps, width, height, seed)
    # Before touching the directory: a model or backend that cannot be built leaves it alone.
    sim = Simulator(
        width, height, params=params or Params(), backend=backend, seed=seed,
        afterimage=afterimage, acuity=acuity,
    )  # fmt: skip
    out_dir = Path(out_dir)
    _prepare_out_dir(out_dir, overwrite)
    dither_rng = np.random.default_rng([seed, 1])
    n = frame_count(seconds, fps)
    digits = max(5, len(str(n - 1)))
    dt = 1.0 / fps

    loaded: object = None
    with contextlib.ExitStack() as stack:
        movie = None
        if video:
            movie = stack.enter_context(
                ApngWriter(out_dir / VIDEO_NAME, n, fps, compress_level=PNG_COMPRESS_LEVEL)
            )
        for i in tqdm(range(n), desc=scene.name, unit="frame", disable=not progress):
            t = i / fps
            x, y, eyes_open = track.at(t)
            gaze = (x * width, y * height)
            if i == 0:
                # Settle the gaze before loading, so the eye starts in equilibrium where it looks.
                sim.step(0.0, gaze=gaze, eyes_open=eyes_open)
                sim.load_scene(scene.render(t, width, height), reset=True)
                loaded = scene.state_at(t)
            elif scene.animated and scene.state_at(t) != loaded:
                sim.load_scene(scene.render(t, width, height), reset=False)
                loaded = scene.state_at(t)
            v = sim.step(dt if i else 0.0, gaze=gaze, eyes_open=eyes_open)
            stem = out_dir / f"frame_{i:0{digits}d}"
            rgb = dither8(v, dither_rng)
            Image.fromarray(rgb).save(stem.with_suffix(".png"), compress_level=PNG_COMPRESS_LEVEL)
            if movie is not None:
                movie.add(rgb)
            if exr:
                write_exr(stem.with_suffix(".exr"), v)
    return RenderSummary(n, out_dir, time.perf_counter() - started)
