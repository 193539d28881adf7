"""One interval of a trial, rendered by the simulator on its own clock, and shown at an intensity.

An interval is a clip: the eye, settled in the dark, sees the stimulus image for `on` s, then
black for `off` s (the afterimage shows there), in fixed steps of 1/fps looking at the fixation
target. Each phase lasts a whole number of steps (`Design.frames`: a duration that is not a
multiple of the step is rounded to the nearest one, at least one, and the simulation sees the
rounded duration, so what is simulated is what is shown; the measured durations say so).

A clip depends on the condition's look (parameters, models), not on the intensity: as the paper's
stimuli, the intensity scales the image on the display ("before intensity scaling", Sec. 4.2),
and the afterimage of the black phase is the look's. So a run renders each look once, and
clips are kept per process (`clip`), which makes the headless path fast.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.experiment.design import Design, Look, make_scene
from gazehdr.eye import Eye
from gazehdr.sim import Params
from gazehdr.sim.display import PAPER_DISPLAY
from gazehdr.sim.layout import encode_output
from gazehdr.sim.models import Models

PHASES = ("on", "off")
_CLIPS_KEPT = 8


@dataclass(frozen=True)
class Timeline:
    """The scene of one clip: black until `start`, `image` until `end`, black after. Its
    boundaries are the simulation times that whole steps reach, so no step is split."""

    image: np.ndarray
    start: float
    end: float
    name: str = "experiment-stimulus"
    animated: bool = True

    def state_at(self, t: float) -> int:
        return int(t >= self.start) + int(t >= self.end)

    def next_change(self, t: float) -> float | None:
        return self.start if t < self.start else self.end if t < self.end else None

    def render(self, t: float, width: int, height: int) -> np.ndarray:
        if self.state_at(t) == 1:
            return self.image.copy()
        return np.zeros_like(self.image)


@dataclass(frozen=True)
class Clip:
    """Display values `v` (float16, H×W×3, the simulator's output) of every frame, the
    simulation time each frame starts at (from the first frame of the stimulus), and its phase;
    `end` is when the last frame ends. `gamma` undoes v = J^gamma: J, linear light with 1 the
    model's monitor's white (`PAPER_DISPLAY`)."""

    frames: np.ndarray
    times: np.ndarray
    phases: tuple[str, ...]
    end: float
    gamma: float
    w_P: tuple[float, float, float]

    def measured(self) -> dict[str, float]:
        """Each phase's duration from the frames' times: the first frame of the next phase (or
        the clip's end) minus the first frame of the phase."""
        firsts = [self.times[self.phases.index(p)] for p in PHASES]
        return {"on": float(firsts[1] - firsts[0]), "off": float(self.end - firsts[1])}

    def luminance(self, i: int) -> np.ndarray:
        """Linear luminance of frame `i` as rendered (J = 1: the monitor's white)."""
        J = np.power(self.frames[i].astype(np.float32), 1.0 / self.gamma)
        return J @ np.asarray(self.w_P, np.float32)

    def mean_over_peak(self) -> np.ndarray:
        """Per stimulus frame, its mean luminance over its peak: what `mean` scaling matches."""
        ratios = [float(Y.mean() / max(float(Y.max()), 1e-30))
                  for Y in map(self.luminance, range(self.phases.count("on")))]  # fmt: skip
        return np.asarray(ratios)

    def shown(self, intensity: float, design: Design, like: Clip | None = None) -> np.ndarray:
        """The frames at `intensity` (cd/m^2) on the design's monitor, as float16 `v` for it.
        Each stimulus frame is scaled in linear light: `peak`, so that its brightest pixel has
        the intensity; `mean`, so that its mean luminance is that of `like` (the standard's
        rendering: default this one) scaled to that peak: a manipulated test at the mean pixel
        value of the standard's rendering at the same intensity. The black phase shows the
        model's afterimage at the cd/m^2 it has on the model's monitor (`PAPER_DISPLAY`: J = 1
        is 100 cd/m^2), so any lab's monitor, its white and gamma entered in the design, shows
        the paper's luminances. Half floats, not 10-bit words: 4.2's stimuli sit in the
        lowest 0.1 % of the monitor's light, where 10 bits would move a mean by several per
        cent; the page dithers them to the display's depth (Sec. 2.4)."""
        J = np.power(self.frames.astype(np.float64), 1.0 / self.gamma)
        cd_m2 = J * PAPER_DISPLAY.white_cd_m2  # what the model's monitor shows
        ratios = (like or self).mean_over_peak() if design.scale == "mean" else None
        for i, phase in enumerate(self.phases):
            if phase != "on":
                continue
            Y = self.luminance(i)
            want = intensity
            if ratios is None:
                have = float(Y.max())
            else:
                have, want = float(Y.mean()), want * ratios[min(i, len(ratios) - 1)]
            if not have > 0:  # nothing to scale: the gain would be infinite
                raise InputError(
                    f"stimulus frame {i} is black: it cannot be scaled to {intensity:g} cd/m^2 "
                    "(its look shows no light while the flash is on)"
                )
            cd_m2[i] = J[i] * (want / have)
        return encode_output(design.display.values(cd_m2).astype(np.float32), "float16")


_cache: OrderedDict[tuple[Any, ...], Clip] = OrderedDict()
_lock = threading.Lock()


def clip(design: Design, look: Look, size: tuple[int, int], backend: str) -> Clip:
    """The clip of `look` (rendered once per process for the same design, size and backend)."""
    key = (
        design.scene, repr(sorted(design.scene_options.items())), design.at,
        design.frames(design.on), design.frames(design.off), design.fps, design.fixation,
        design.render_seed, look.key(), tuple(size), backend,
    )  # fmt: skip
    with _lock:  # one render at a time: a second caller of a clip waits for it, not again
        if key in _cache:
            _cache.move_to_end(key)
            return _cache[key]
        made = _cache[key] = render_clip(design, look, size, backend)
        while len(_cache) > _CLIPS_KEPT:
            _cache.popitem(last=False)
    return made


def palette_images(design: Design, size: tuple[int, int], backend: str) -> list[np.ndarray]:
    """Each palette option's image (Fig. 15): the first frame of black after its flash, the
    afterimage's initial appearance, as display values, cropped to a square of `palette_crop`
    frame heights around its brightest point, then given the option's colour transform (in
    linear light, `gazehdr.experiment.transforms`). Each flash and look is rendered once, up
    to that frame only (the frames after it cannot change it), however many options transform
    it. Not kept: its caller keeps them."""
    first_black = replace(design, off=design.dt)  # one frame of black: the one shown
    rendered: dict[tuple[Any, ...], tuple[np.ndarray, float]] = {}
    images = []
    for choice in design.palette:
        look = design.flash_look(choice.look, choice.flash)
        if look.key() not in rendered:
            c = render_clip(first_black, look, size, backend)
            i = c.phases.index("off")
            Y = c.luminance(i)
            y, x = np.unravel_index(np.argmax(Y), Y.shape)
            h, w = c.frames.shape[1:3]
            side = max(1, min(h, w, round(design.palette_crop * h)))
            y0, x0 = min(max(y - side // 2, 0), h - side), min(max(x - side // 2, 0), w - side)
            crop = c.frames[i, y0 : y0 + side, x0 : x0 + side].astype(np.float32)
            rendered[look.key()] = crop, c.gamma
        crop, gamma = rendered[look.key()]
        images.append(choice.transform.apply(crop, gamma))
    return images


def trial_looks(design: Design) -> list[Look]:
    """Every look a run of `design` renders a clip of, once each."""
    looks: dict[tuple[Any, ...], Look] = {}
    for block in design.blocks:
        for name in block.repeats:
            condition = design.conditions[name]
            if name == "palette":
                found = [design.flash_look(condition.test, test) for test in block.tests]
            else:
                found = [condition.test, condition.standard]
            looks.update((look.key(), look) for look in found)
    return list(looks.values())


def render_clip(design: Design, look: Look, size: tuple[int, int], backend: str) -> Clip:
    """Step the eye through one interval. It starts settled on black; the first step (black)
    is not shown, so the stimulus starts at a time whole steps reach, as does the black."""
    w, h = size
    params = Params.from_dict(look.params)
    options = {**design.scene_options, **look.scene_options}
    image = make_scene(design.scene, options).render(design.at, w, h)
    n_on, n_off, dt = design.frames(design.on), design.frames(design.off), design.dt
    ticks = [0.0]
    for _ in range(1 + n_on + n_off):
        ticks.append(ticks[-1] + dt)  # the times the eye's clock reaches, bit for bit
    scene = Timeline(image, ticks[1], ticks[1 + n_on])
    eye = Eye(
        scene, (w, h), params, [Models.parse(look.model)], backend=backend,
        seed=design.render_seed, gaze=design.fixation, eyes_open=True,
    )  # fmt: skip
    eye.step(dt, design.fixation, True)  # settled on black: the lead step, not shown
    frames, times, phases = [], [], []
    for _ in range(n_on + n_off):
        t = eye.time
        phases.append(PHASES[scene.state_at(t) - 1])
        times.append(t - ticks[1])
        (v,) = eye.step(dt, design.fixation, True)
        frames.append(v.astype(np.float16))
    return Clip(
        frames=np.stack(frames), times=np.asarray(times), phases=tuple(phases),
        end=eye.time - ticks[1], gamma=params.gamma, w_P=params.w_P,
    )  # fmt: skip
