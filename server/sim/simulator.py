"""The public simulator: one object per viewer, pure (no clocks, no I/O).

It owns the order of the stages; the backends (NumPy reference or OpenCL) own the arrays and
the arithmetic. Time only enters through `dt`, randomness only through `seed`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.layout import (
    OUTPUTS,
    SETTLE_MIN_DT,
    Layout,
    NoiseField,
    bilinear,
    bilinear_at,
    blind_spot_strength,
    encode_output,
    fit_to_frame,
    sanitize_radiance,
)
from gazehdr.sim.models import Models, make_stages
from gazehdr.sim.params import Params

BACKENDS = ("opencl", "reference")


@dataclass(frozen=True)
class WarpLayers:
    """One pane's frame as a late gaze warp sends it (`Simulator.warp_layers`)."""

    rgb: np.ndarray  # H×W×3 float16: linear RGB before Eq. 12 (reference.compose_base)
    #: 2×grid_h×grid_w×3 float16, the afterimage maps centred on `gaze`: gain - 1 (Eq. 11's
    #: per cone), then the additive linear RGB term
    maps: np.ndarray
    gaze: tuple[float, float]  # the step's gaze, pane px
    visibility: float  # Sec. 5's boost: the foveal fall-off's peak
    cell: int  # screen px per retina cell
    fovea_sigma_px: float  # the foveal fall-off's sigma, screen px


#: The dtype of each encoded output a step returns (`step(output=...)`).
OUTPUT_DTYPES = {"float16": np.float16, "rgb10a2": np.uint32}


def _check_output(output: str) -> None:
    if output not in OUTPUTS:
        raise InputError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")


MAX_DT = 60.0  # seconds; a longer gap should be stepped in pieces (it is no longer a frame)


def _make_backend(name: str, layout: Layout, params: Params):
    if name == "reference":
        from gazehdr.sim.reference import ReferenceBackend

        return ReferenceBackend(layout, params)
    if name == "opencl":
        from gazehdr.sim.opencl import OpenCLBackend

        return OpenCLBackend(layout, params)
    raise InputError(f"unknown backend {name!r}; choose one of {', '.join(BACKENDS)}")


class Simulator:
    """Advances the simulated eye over an HDR scene and returns display values in [0, 1]."""

    def __init__(
        self,
        width: int = 640,
        height: int = 360,
        params: Params | None = None,
        backend: str = "opencl",
        seed: int = 0,
        afterimage: str = "jacobs",
        acuity: str = "stochastic",
    ) -> None:
        self.params = params or Params()
        self.models = Models(afterimage, acuity)
        self.layout = Layout.for_frame(width, height, self.params)
        self.seed = int(seed)
        self.time = 0.0
        self._backend = _make_backend(backend, self.layout, self.params)
        self._afterimage, self._acuity = make_stages(self.models, self._backend, self.seed)
        self._backend.set_state_channels(self._afterimage.state_channels)
        self._noise = NoiseField(self.layout, self.params, self.seed)
        self._gaze = (width / 2.0, height / 2.0)
        self._eyes = 1.0
        self._prepared_for: float | None = None
        self._rho: np.ndarray | None = None
        # Set by reset: the next step settles the eye at its own gaze (and dt) first.
        self._settle_pending = True
        self._boost_since = -math.inf  # time of the last blink's end or saccade (Sec. 5)
        self._visibility = 1.0  # the afterimages' visibility at the last step (Sec. 5's boost)
        self.load_scene(np.zeros((height, width, 3), np.float32))

    # --- properties ---------------------------------------------------------------------------

    @property
    def width(self) -> int:
        return self.layout.width

    @property
    def height(self) -> int:
        return self.layout.height

    @property
    def backend(self) -> str:
        return self._backend.name

    @property
    def device(self) -> str:
        """Which device runs the model, for logs and benchmarks."""
        return self._backend.device_name

    @property
    def afterimage(self) -> str:
        return self.models.afterimage

    @property
    def acuity(self) -> str:
        return self.models.acuity

    @property
    def adaptation(self) -> float:
        """Current global adaptation A, log10 cd/m^2 (never below A_min)."""
        return self._backend.A

    @property
    def gaze(self) -> tuple[float, float]:
        return self._gaze

    def rho_at_gaze(self) -> float:
        """Mesopic rho (Eq. 13, unclamped) of the scene where the eye looks, for displays."""
        if self._rho is None:
            self._prepare()
            self._rho = self._backend.get("rho").astype(np.float64)
        x, y = (c / self.layout.cell for c in self._gaze)
        return bilinear_at(self._rho, x, y)

    def scene_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """What the eye looks at, for inspection: the radiance as loaded (H×W×3 cd/m^2, fitted
        to the frame) and rho (Eq. 13, unclamped) at every pixel, as `rho_at_gaze` samples it."""
        self._prepare()
        radiance = self._backend.get("scene").transpose(1, 2, 0)
        rho = self._backend.get("rho")[None].astype(np.float64)
        ys, xs = np.mgrid[: self.height, : self.width] + 0.5
        cell = self.layout.cell
        return np.ascontiguousarray(radiance, np.float32), bilinear(rho, xs / cell, ys / cell)[0]

    # --- control ------------------------------------------------------------------------------

    def load_scene(self, rgb: np.ndarray, *, reset: bool = True) -> None:
        """Take H×W×3 radiance in cd/m^2 of any size; NaN -> 0, +Inf and excess -> the cap.

        With `reset=False` only the radiance changes (animated scenes); the eye keeps its state
        (an eye still to settle settles on the scene it had, at the current gaze, first).
        """
        if not reset and self._settle_pending:
            self._settle(SETTLE_MIN_DT)
        clean = sanitize_radiance(rgb, self.params)
        fitted = fit_to_frame(clean, self.width, self.height)
        self._backend.set_scene(np.ascontiguousarray(fitted.transpose(2, 0, 1), np.float32))
        self._prepared_for = None
        self._rho = None
        if reset:
            self.reset()

    def reset(self) -> None:
        """Back to equilibrium, no afterimage: the next step finds the eye as if it had always
        looked at the current scene from that step's gaze (or the current one, if it gives
        none), adapted there and with its retina settled for steps of that step's dt."""
        self._prepare()
        self._backend.adapt(self._gaze, 0.0, True)
        self._afterimage.retina(self._gaze, 0.0, True)  # in the meantime, without the map blur
        self._settle_pending = True

    def _settle(self, dt: float) -> None:
        """Adapted at the gaze, and the retina at the state that steps of dt leave as it is
        (the map blur and the relaxation in balance; layout.settle_plan)."""
        self._prepare()
        self._backend.adapt(self._gaze, 0.0, True)
        self._afterimage.retina(self._gaze, max(dt, SETTLE_MIN_DT), True)
        self._settle_pending = False

    def start(
        self,
        rgb: np.ndarray,
        gaze: Sequence[float],
        eyes_open: bool = True,
        continue_from: Simulator | None = None,
    ) -> None:
        """Look at `rgb` from `gaze`, settled there; with `continue_from`, go on with that eye
        (`carry_state_from`): how a new simulator takes over after a parameter or model
        change."""
        self._gaze = self._check_gaze(gaze)
        self._eyes = 1.0 if eyes_open else 0.0
        self.load_scene(rgb, reset=True)
        if continue_from is not None:
            self.carry_state_from(continue_from)

    def carry_state_from(self, other: Simulator) -> None:
        """Continue `other`'s eye (after a parameter change): its time and adaptation, and its
        retinal state when both retina grids and afterimage models are the same; else the
        retina starts settled, with that adaptation."""
        self.time = other.time
        self._boost_since = other._boost_since
        self._backend.put("A", other._backend.get("A"))
        if other.layout == self.layout and other.afterimage == self.afterimage:
            self._backend.put("state", other._backend.get("state"))
            self._settle_pending = other._settle_pending
        elif other._settle_pending:
            self._settle_pending = True
        else:
            self._prepare()
            self._afterimage.retina(self._gaze, SETTLE_MIN_DT, True)
            self._settle_pending = False

    def step(
        self,
        dt: float,
        gaze: Sequence[float] | None = None,
        eyes_open: bool = True,
        output: str = "float32",
    ) -> np.ndarray:
        """Advance by `dt` seconds with the eye at `gaze` (screen px) and return H×W×3 `v`.
        The first step after `load_scene` or `reset` starts settled at its gaze.

        `output` "float16" or "rgb10a2" returns `v` encoded for the viewer (see
        `layout.encode_output`); the OpenCL backend encodes on the device, so the host never
        makes a pass over the frame."""
        _check_output(output)
        self.advance(dt, gaze, eyes_open)
        return self.frame(output)

    def frame(
        self,
        output: str = "float32",
        gaze: Sequence[float] | None = None,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """The frame of the eye as the last step left it (`step` is `advance` then this); into
        `out` when given (an array of the output's shape and dtype: a frame message's pixels,
        `protocol.frame_buffer`), which is returned.

        With `gaze` (screen px) it is seen from there instead of from the step's gaze: the
        afterimages, locked to the retina, and their foveal fall-off move with it, as they do
        in the eye. A gaze newer than the step's, read just before this (after `wait`), cuts
        the time from a gaze to the frame that shows it by the step's own (`Eye.step`'s
        `late_gaze`); the gaze becomes the eye's."""
        _check_output(output)
        if gaze is not None:
            self._gaze = self._check_gaze(gaze)
        b = self._backend
        if output != "float32" and b.name == "opencl":
            kind = OUTPUT_DTYPES[output]
            return b.compose(self._gaze, self._eyes, kind, self._visibility, out)
        v = encode_output(b.compose(self._gaze, self._eyes, visibility=self._visibility), output)
        if out is None:
            return v
        out[...] = v
        return out

    def wait(self) -> None:
        """Block until the device has done the steps asked of it: a gaze read after this is
        as new as one can be for `frame`."""
        self._backend.wait()

    def warp_layers(self) -> WarpLayers:
        """The last step's frame as a late gaze warp sends it (`gazehdr.warp`): the parts of
        compose that stay on the screen, and the retina-locked afterimage maps the viewer
        applies at its newest gaze. Call it after `step` or `advance`."""
        rgb, maps = self._backend.warp_layers(self._eyes)
        lay = self.layout
        return WarpLayers(
            np.asarray(rgb, np.float16), np.asarray(maps, np.float16), self._gaze,
            self._visibility, lay.cell, lay.px(self.params.fovea_sigma_deg),
        )  # fmt: skip

    def advance(
        self, dt: float, gaze: Sequence[float] | None = None, eyes_open: bool = True
    ) -> None:
        """`step` without its compose: the eye advanced, no frame made (a late gaze warp
        composes in the viewer; `warp_layers`)."""
        dt = float(dt)
        if not (math.isfinite(dt) and 0.0 <= dt <= MAX_DT):
            raise InputError(f"dt must be a finite number of seconds in [0, {MAX_DT}], got {dt}")
        previous, was_open = self._gaze, self._eyes
        if gaze is not None:
            self._gaze = self._check_gaze(gaze)
        self._eyes = 1.0 if eyes_open else 0.0
        self.time += dt
        b = self._backend
        if self._settle_pending:
            self._settle(dt)
        elif self._eyes > was_open or self._saccade(previous, dt):
            self._boost_since = self.time
        self._prepare()

        def eye() -> None:
            b.adapt(self._gaze, dt, False)
            self._afterimage.retina(self._gaze, dt, False)

        if self._eyes:  # the acuity (Sec. 2.3) needs neither: it runs beside them
            noise = self._noise.at(self.time)
            b.alongside(lambda: self._acuity.acuity(noise, self._gaze, self.time), eye)
            if blind_spot_strength(self.params) > 0:
                b.blind_spot(self._gaze)
        else:
            eye()
        p = self.params
        self._visibility = 1.0 + p.afterimage_boost * math.exp(
            -(self.time - self._boost_since) / p.afterimage_boost_s
        )

    # --- internals ----------------------------------------------------------------------------

    def _prepare(self) -> None:
        """Scene-only maps (cone input, local rho) change only with the scene or the eyelids."""
        if self._prepared_for != self._eyes:
            self._backend.prepare(self._eyes)
            self._afterimage.prepared()
            self._prepared_for = self._eyes

    def _saccade(self, previous: tuple[float, float], dt: float) -> bool:
        """Whether the gaze moved faster than saccade_deg_s in this step (any move at dt = 0)."""
        moved = math.dist(previous, self._gaze) / self.layout.ppd
        return moved > 0 and moved >= self.params.saccade_deg_s * dt

    def _check_gaze(self, gaze: Sequence[float]) -> tuple[float, float]:
        try:
            x, y = (float(g) for g in gaze)
        except (TypeError, ValueError):
            raise InputError(f"gaze must be (x, y) in screen pixels, got {gaze!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(f"gaze must be finite, got ({x}, {y})")
        # Beyond two screens away nothing of the retina grid overlaps the screen; clamping there
        # keeps coordinates exact in float32 without changing the result.
        w, h = self.width, self.height
        return (min(max(x, -3.0 * w), 4.0 * w), min(max(y, -3.0 * h), 4.0 * h))
