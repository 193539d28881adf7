"""The interchangeable stages of the simulation, by name: afterimage models and acuity models.

Jacobs et al. 2015 is the default of both. The baselines the paper compares against plug in
beside it, so every model sees the same scene, gaze and clock (see docs/baselines/):

- afterimage: `jacobs` (Sec. 2.2), `ritschel` (Ritschel & Eisemann 2012), `mikamo` (Mikamo et
  al. 2012);
- acuity: `stochastic` (Sec. 2.3.3), `none`, `gaussian` (Ferwerda et al. 1996), `bilateral`
  (Jensen et al. 2000), `thompson` (Thompson et al. 2002).

A stage is built as `Stage(backend, seed)` and works on the backend's maps:

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
from typing import Any, Protocol

from gazehdr.sim.layout import NoiseFrame


class AfterimageStage(Protocol):
    state_channels: int

    def prepared(self) -> None: ...

    def retina(self, gaze: tuple[float, float], dt: float, reset: bool) -> None: ...


class AcuityStage(Protocol):
    def acuity(self, noise: NoiseFrame, gaze: tuple[float, float], t: float) -> None: ...


class JacobsAfterimage:
    """Sec. 2.2: bleaching and calcium per cone, as the backends implement them natively."""

    state_channels = 6

    def __init__(self, backend: Any, seed: int) -> None:
        self.backend = backend

    def prepared(self) -> None:
        pass

    def retina(self, gaze: tuple[float, float], dt: float, reset: bool) -> None:
        self.backend.retina(gaze, dt, reset)


class StochasticAcuity:
    """Sec. 2.3.3: the Gaussian bank with bands kept where rho + g X exceeds their threshold."""

    def __init__(self, backend: Any, seed: int) -> None:
        self.backend = backend

    def acuity(self, noise: NoiseFrame, gaze: tuple[float, float], t: float) -> None:
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
                raise ValueError(f"unknown {kind} model {name!r}; choose one of {', '.join(table)}")

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


def make_stages(models: Models, backend: Any, seed: int) -> tuple[AfterimageStage, AcuityStage]:
    """Build the chosen stages for `backend` (its `name` picks the implementation); `seed`
    fixes any random field a stage draws."""
    afterimage = _load(AFTERIMAGE_MODELS[models.afterimage][backend.name])(backend, seed)
    acuity = _load(ACUITY_MODELS[models.acuity][backend.name])(backend, seed)
    return afterimage, acuity
