"""The simulated eye of one viewing, and the one stepping loop live and offline rendering share.

An `Eye` is a simulator per pane (the whole frame, or two halves side by side in split view,
one model each, with the same scene, gaze and steps), the scene they look at, and how they step
together: a step is split where the scene changes, so a flash shorter than a frame is seen for
exactly its duration, never skipped nor stretched to a whole frame. A live session
(`gazehdr.session`) and an offline render (`gazehdr.render`) drive the same `Eye`, so a recorded
session renders to the frames it showed.

Gaze is given as fractions of the frame; in split view the gaze over either half looks at the
same point of the scene (the right half maps onto the left pane).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.scenes import Scene
from gazehdr.sim import Geometry, Params, Simulator
from gazehdr.sim.models import Models
from gazehdr.sim.simulator import WarpLayers


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


class Eye:
    """Simulators for `panes` (one or two models) over a frame of `size` px, settled on `scene`
    at `gaze` (frame fractions), or continuing `continue_from` (its time, adaptation, and its
    retina where the model and pane size stay)."""

    def __init__(
        self,
        scene: Scene,
        size: tuple[int, int],
        params: Params,
        panes: Sequence[Models],
        *,
        backend: str,
        seed: int,
        gaze: tuple[float, float],
        eyes_open: bool,
        continue_from: Eye | None = None,
    ) -> None:
        if len(panes) not in (1, 2):
            raise InputError(f"an eye has one or two panes, not {len(panes)}")
        self.scene, self.size, self.params = scene, size, params
        self.panes = tuple(panes)
        self.backend, self.seed = backend, seed
        w, h = self.pane_size
        t = continue_from.time if continue_from else 0.0
        frame = scene.render(t, w, h)
        old = continue_from.sims if continue_from else ()
        self.sims: list[Simulator] = []
        for i, model in enumerate(self.panes):
            try:
                sim = Simulator(
                    w, h, params=pane_params(params, size[0], w), backend=backend, seed=seed,
                    afterimage=model.afterimage, acuity=model.acuity,
                )  # fmt: skip
            except ImportError as e:  # a baseline that is not part of this installation
                raise InputError(f"model {model} is not available: {e}") from None
            previous = old[min(i, len(old) - 1)] if old else None  # a new right pane: the left's
            sim.start(frame, self.pane_gaze(gaze), eyes_open, continue_from=previous)
            self.sims.append(sim)
        self._loaded = scene.state_at(t)
        self.loads = 0  # scene loads since built: what the panes see changed

    def rebuilt(self, gaze: tuple[float, float], eyes_open: bool, **changes: Any) -> Eye:
        """A new eye with `changes` (size, params, panes) continuing this one; this one is left
        as it is if the new one cannot be built."""
        kept = {"size": self.size, "params": self.params, "panes": self.panes}
        kept.update(changes)
        return Eye(
            self.scene, **kept, backend=self.backend, seed=self.seed, gaze=gaze,
            eyes_open=eyes_open, continue_from=self,
        )  # fmt: skip

    @property
    def time(self) -> float:
        return self.sims[0].time

    @property
    def pane_size(self) -> tuple[int, int]:
        """Pixels of one pane: the frame, or half of it (an odd last column stays black)."""
        return (self.size[0] // len(self.panes), self.size[1])

    def pane_gaze(self, gaze: tuple[float, float]) -> tuple[float, float]:
        """The gaze in one pane's pixels. In split view the pointer (or tracker) over either
        half looks at the same point of the scene: x - pane width over the right half; a gaze
        left or right of the screen stays off the pane on that side."""
        w, h = self.pane_size
        x = gaze[0] * self.size[0]
        return (x - w if len(self.panes) == 2 and x >= w else x, gaze[1] * h)

    def look_at(self, scene: Scene) -> None:
        """A new scene, seen from now on; the eye starts settled on it."""
        self.scene = scene
        self._load(reset=True)

    def reset(self) -> None:
        for sim in self.sims:
            sim.reset()

    def step(
        self,
        dt: float,
        gaze: tuple[float, float],
        eyes_open: bool,
        output: str | None = "float32",
        late_gaze: Callable[[], tuple[float, float] | None] | None = None,
        out: np.ndarray | None = None,
    ) -> list[np.ndarray]:
        """Advance every pane by `dt` s looking at `gaze`; each pane's frame, in `output`
        (`Simulator.step`'s encodings; None: no frame, for a late gaze warp only, see
        `warp_layers`). The step is split where the scene changes, and each part sees the
        scene as it is at the part's start. With `out` (the whole frame, in `output`'s dtype)
        the panes are made into it side by side, from the left; what they leave is made 0.

        `late_gaze`, when given, is asked once the panes have advanced (their device work
        done) for a gaze newer than `gaze`, or None: the frames are seen from it
        (`Simulator.frame`), so a gaze that came during the step is in them."""
        pane_gaze = self.pane_gaze(gaze)
        start = self.time
        end = start + dt
        # Before the first part too: a step that starts on a change (the last one ended there)
        # sees the scene as it is from then on, not as the last step left it.
        self._follow_scene()
        while (change := self.scene.next_change(self.time)) is not None and change < end:
            part = change - self.time
            for sim in self.sims:  # no frame for a part: only the last one is shown
                sim.advance(part, gaze=pane_gaze, eyes_open=eyes_open)
            self._follow_scene()
        rest = dt if self.time == start else max(0.0, end - self.time)
        for sim in self.sims:
            sim.advance(rest, gaze=pane_gaze, eyes_open=eyes_open)
        if output is None:
            return []
        newer = None
        if late_gaze is not None:
            for sim in self.sims:
                sim.wait()
            newer = late_gaze()
        seen = None if newer is None else self.pane_gaze(newer)
        if out is None:
            return [sim.frame(output, seen) for sim in self.sims]
        w = self.sims[0].width
        out[:, len(self.sims) * w :] = 0  # black right of the panes (a split frame's odd column)
        panes = (out[:, i * w : (i + 1) * w] for i in range(len(self.sims)))
        return [sim.frame(output, seen, pane) for sim, pane in zip(self.sims, panes, strict=True)]

    def warp_layers(self) -> list[WarpLayers]:
        """Each pane's last step as a late gaze warp sends it (`Simulator.warp_layers`)."""
        return [sim.warp_layers() for sim in self.sims]

    def _follow_scene(self) -> None:
        """Load the scene as it is now, if that differs from what the panes see."""
        if self.scene.animated and self.scene.state_at(self.time) != self._loaded:
            self._load(reset=False)

    def _load(self, reset: bool) -> None:
        t = self.time
        self.loads += 1
        self._loaded = self.scene.state_at(t)
        frame = self.scene.render(t, *self.pane_size)
        for sim in self.sims:
            sim.load_scene(frame, reset=reset)
