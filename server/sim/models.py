"""The interchangeable stages of the simulation, by name: afterimage models and acuity models.

Jacobs et al. 2015 is the default of both. The baselines the paper compares against plug in
beside it, so every model sees the same scene, gaze and clock (see docs/baselines/):

- afterimage: `jacobs` (Sec. 2.2), `ritschel` (Ritschel & Eisemann 2012), `mikamo` (Mikamo et
  al. 2012);
- acuity: `stochastic` (Sec. 2.3.3), `none`, `gaussian` (Ferwerda et al. 1996), `bilateral`
  (Jensen et al. 2000), `thompson` (Thompson et al. 2002).

A stage is built as `Stage(backend, seed)` and works on the backend's maps, through what the
backend's protocol declares (`ReferenceStageBackend`, `OpenCLStageBackend`) and nothing else:

- an afterimage stage advances its state on the retina grid in `retina(gaze, dt, reset)` and
  writes the six `maps` that `compose` reads at `x - gaze`: a multiplicative gain per cone
  (L, M, S) and an additive term in linear RGB (display units, 1 = white); `prepared()` is
  called after every scene (or eyelid) change;
- an acuity stage writes `G`, the scene as the eye resolves it, in `acuity(noise, gaze, t)`.

Stages are found by dotted path, so a model's code (NumPy reference, OpenCL stage, kernel file)
lives in its own modules and is imported only when chosen.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.layout import Layout, NoiseFrame
from gazehdr.sim.params import Params

if TYPE_CHECKING:  # annotations only: a reference simulator never loads pyopencl
    import pyopencl as cl

    from gazehdr.sim.cl_program import Launch

    Taps = tuple[cl.Buffer, int]  # normalised Gaussian taps on the device, and their radius

Gaze = tuple[float, float]


class AfterimageStage(Protocol):
    state_channels: int

    def prepared(self) -> None: ...

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None: ...


class AcuityStage(Protocol):
    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None: ...


# --- what a stage may ask of its backend ---------------------------------------------------------
# tests/test_sim_interfaces.py runs every stage against a proxy that has only these members.


class StageBackend(Protocol):
    """What every backend gives every stage."""

    name: str  # "reference" or "opencl": picks the stage's implementation
    lay: Layout  # sizes of every map (screen, low-res, retina grid) and pixels per degree
    p: Params

    def get(self, name: str) -> np.ndarray:
        """A copy of map `name` on the host, e.g. "down" (L, M, S, Y_P, Y_S per cell) or "rho"."""
        ...

    def put(self, name: str, value: np.ndarray) -> None:
        """Replace map `name` from the host (the `none` afterimage stage's constant maps)."""
        ...

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        """Sec. 2.2 on the backend's own state and maps (the `jacobs` stage)."""
        ...

    def acuity(self, noise: NoiseFrame) -> None:
        """Sec. 2.3.3 into G (the `stochastic` stage)."""
        ...


class ReferenceStageBackend(StageBackend, Protocol):
    """The NumPy reference: stages read and replace its float64 arrays."""

    #: Every map by name, as `get` lists them: "scene" (3, H, W), "down", "rho", "surround"
    #: (L, M, S the retina sees off the screen, at the nearest cell: `retina_input` reads it),
    #: "A", "state" (the afterimage stage's planes on the retina grid), "maps" (6 planes it
    #: writes), "G".
    a: dict[str, np.ndarray]


class OpenCLStageBackend(StageBackend, Protocol):
    """The OpenCL backend: stages enqueue their own kernels on its queue, on its buffers."""

    ctx: cl.Context  # to make a stage's own buffers
    #: The queue a stage's kernels and copies go on, in order. Read it at each use: the acuity
    #: stage runs on a second queue, beside the afterimage stage's (`alongside`).
    queue: cl.CommandQueue
    P: cl.Buffer  # the parameter block params_t (kernel_params.py), the kernels' first argument
    #: Device maps by name, planar float32 (G: 16-bit codes, lum16.py, written by `store_G`),
    #: shaped as `ReferenceStageBackend.a`, plus the scratch plane set "grid_a" (STATE_PLANES
    #: planes of the retina grid). A stage that writes "maps" writes all of the grid (the
    #: backend completes only maps its own `retina` left partial).
    buf: dict[str, cl.Buffer]
    vec: int  # pixels per work-item of the per-pixel kernels (VEC in common.cl, 8 or 16)

    def kernels(self, files: tuple[str, ...]) -> dict[str, Launch]:
        """Own kernels (arguments are state) of the program built from `files` in kernels/,
        once per process, common.cl first; each starts on the device as it is enqueued."""
        ...

    def taps_for(self, sigma: float) -> Taps:
        """Gaussian taps of `sigma` (px) on the device, cached for the sigmas in use."""
        ...

    def blur(self, src: cl.Buffer, dst: cl.Buffer, tmp: cl.Buffer, taps: Taps, w: int, h: int,
             channels: int) -> None:  # fmt: skip
        """Separable blur of `channels` planes of w x h from `src` into `dst` (through `tmp`),
        edges clamped: the blur the reference's blur2d mirrors."""
        ...

    def rho_full(self) -> cl.Buffer:
        """rho (Eq. 13, unclamped) at every screen pixel, bilinear from the low-res map; remade
        after a scene change."""
        ...

    def store_G(self, src: cl.Buffer) -> None:
        """G (an acuity stage's output) from three float planes of the screen."""
        ...

    def rows_v(self) -> tuple[int, int]:
        """Global size of a per-pixel kernel that makes `vec` neighbouring pixels of a row per
        work-item (VEC in common.cl)."""
        ...

    def grid_args(self, gaze: Gaze) -> tuple[np.int32 | np.float32, ...]:
        """The kernels' retina-grid arguments: low_w, low_h, cell, grid_w, grid_h, gaze x, y."""
        ...


#: The backend of a stage base both implementations share (Generic[StageBackendT]); each
#: implementation names its protocol, e.g. RitschelStage[OpenCLStageBackend].
StageBackendT = TypeVar("StageBackendT", bound=StageBackend)


class JacobsAfterimage:
    """Sec. 2.2: bleaching and calcium per cone, as the backends implement them natively, and
    the light each cone is adapted to, in linear units (ours: the calcium gain's direction)."""

    state_channels = 9

    def __init__(self, backend: StageBackend, seed: int) -> None:
        self.backend = backend

    def prepared(self) -> None:
        pass

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        self.backend.retina(gaze, dt, reset)


class NoAfterimage:
    """No afterimage of either kind: gains 1, nothing added, so the frame is the tone curve at
    the eye's (global) adaptation. The viewer's "plain" comparison pane runs it with acuity
    `none` (docs/server.md)."""

    state_channels = 1  # the backends keep at least one plane; it is never read

    def __init__(self, backend: StageBackend, seed: int) -> None:
        self.backend = backend
        self._written = False

    def prepared(self) -> None:
        pass

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        if self._written and not reset:  # the maps never change
            return
        b = self.backend
        maps = np.zeros((6, b.lay.grid_h, b.lay.grid_w))
        maps[:3] = 1.0
        b.put("maps", maps)
        self._written = True


class StochasticAcuity:
    """Sec. 2.3.3: the Gaussian bank with bands kept where rho + g X exceeds their threshold."""

    def __init__(self, backend: StageBackend, seed: int) -> None:
        self.backend = backend

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        self.backend.acuity(noise)


_HERE = "gazehdr.sim.models"
#: name -> {backend name -> "module:Class"}
AFTERIMAGE_MODELS: dict[str, dict[str, str]] = {
    "jacobs": {"reference": f"{_HERE}:JacobsAfterimage", "opencl": f"{_HERE}:JacobsAfterimage"},
    "ritschel": {
        "reference": "gazehdr.sim.baselines.ritschel:RitschelReference",
        "opencl": "gazehdr.sim.baselines.ritschel_cl:RitschelOpenCL",
    },
    "mikamo": {
        "reference": "gazehdr.sim.baselines.mikamo:MikamoReference",
        "opencl": "gazehdr.sim.baselines.mikamo_cl:MikamoOpenCL",
    },
    "none": {"reference": f"{_HERE}:NoAfterimage", "opencl": f"{_HERE}:NoAfterimage"},
}
ACUITY_MODELS: dict[str, dict[str, str]] = {
    "stochastic": {"reference": f"{_HERE}:StochasticAcuity", "opencl": f"{_HERE}:StochasticAcuity"},
    **{
        name: {
            "reference": f"gazehdr.sim.baselines.acuity:{cls}Reference",
            "opencl": f"gazehdr.sim.baselines.acuity_cl:{cls}OpenCL",
        }
        for name, cls in (
            ("none", "NoAcuity"),
            ("gaussian", "GaussianAcuity"),
            ("bilateral", "BilateralAcuity"),
            ("thompson", "ThompsonAcuity"),
        )
    },
}


@dataclass(frozen=True)
class Models:
    """Which afterimage and which acuity model a simulator runs."""

    afterimage: str = "jacobs"
    acuity: str = "stochastic"

    def __post_init__(self) -> None:
        for kind, name, table in (
            ("afterimage", self.afterimage, AFTERIMAGE_MODELS),
            ("acuity", self.acuity, ACUITY_MODELS),
        ):
            if name not in table:
                raise InputError(f"unknown {kind} model {name!r}; choose one of {', '.join(table)}")

    @classmethod
    def parse(cls, text: str) -> Models:
        """`AFTERIMAGE[+ACUITY]`, e.g. `ritschel` or `jacobs+thompson`; also `+ACUITY` alone."""
        afterimage, _, acuity = str(text).strip().partition("+")
        return cls(afterimage or "jacobs", acuity or "stochastic")

    def __str__(self) -> str:
        return f"{self.afterimage}+{self.acuity}"


def each_beside_default() -> list[Models]:
    """The default, then every other model of each stage with the other stage at its default:
    the set that comparisons (tests, benchmarks) run."""
    return (
        [Models()]
        + [Models(a, "stochastic") for a in AFTERIMAGE_MODELS if a != "jacobs"]
        + [Models("jacobs", q) for q in ACUITY_MODELS if q != "stochastic"]
    )


def _load(path: str) -> type:
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def make_stages(
    models: Models, backend: StageBackend, seed: int
) -> tuple[AfterimageStage, AcuityStage]:
    """Build the chosen stages for `backend` (its `name` picks the implementation); `seed`
    fixes any random field a stage draws."""
    afterimage = _load(AFTERIMAGE_MODELS[models.afterimage][backend.name])(backend, seed)
    acuity = _load(ACUITY_MODELS[models.acuity][backend.name])(backend, seed)
    return afterimage, acuity
