"""Ritschel & Eisemann 2012, "A Computational Model of Afterimages": the NumPy reference.

Per retina cell and cone (L, M, S), one "virtual chemical" r in [0, 1] follows Eq. 3,
r' = c_a L (1 - r) - c_d r, integrated with the clamped explicit steps of Listing 1, each step
followed by the diffusion blur. The input is the cone stimulus blurred once for micro-saccades.
The afterimage is the opponent colour, in oRGB (Bratkova, Boulos, Shirley 2009), of the
bleaching the current input does not explain (its displayable part, gamma-encoded), brought into
the display gamut at the same luma and oRGB hue and added to the display (positive afterimages
only, as published). Our readings of what the paper leaves open are in docs/baselines/ritschel.md.

The OpenCL stage (ritschel_cl.py, kernels/ritschel2012_afterimages.cl) mirrors this step by step.
"""

from __future__ import annotations

import math
from typing import Generic

import numpy as np

from gazehdr.sim.layout import LMS_TO_RGB, Layout
from gazehdr.sim.models import Gaze, ReferenceStageBackend, StageBackendT
from gazehdr.sim.params import Params
from gazehdr.sim.reference import blur2d, retina_input

# oRGB (Bratkova et al. 2009, Eq. 1): gamma-encoded R'G'B' -> luma L', C1 (yellow-blue), C2
# (red-green), before the hue rotation. The inverse is the exact matrix inverse (the paper prints
# it rounded to four digits), so a round trip is the identity to rounding.
ORGB_FROM_RGB = np.array(
    [
        [0.2990, 0.5870, 0.1140],
        [0.5000, 0.5000, -1.0000],
        [0.8660, -0.8660, 0.0000],
    ]
)
RGB_FROM_ORGB = np.linalg.inv(ORGB_FROM_RGB)
_R_MIN = 1e-30  # guard of r_inf's denominator (c_d = 0 in darkness would be 0/0)


# --- oRGB ----------------------------------------------------------------------------------------


def hue_forward(theta: np.ndarray) -> np.ndarray:
    """oRGB hue compression (Bratkova et al. Eq. 2): |θ| < π/3 -> 3θ/2, π/3 <= |θ| <= π ->
    π/2 + 3(|θ| - π/3)/4, mirrored for negative angles; red lands on +C_rg, yellow on +C_yb."""
    a = np.abs(theta)
    out = np.where(a < math.pi / 3, 1.5 * a, math.pi / 2 + 0.75 * (a - math.pi / 3))
    return np.copysign(out, theta)


def hue_inverse(theta_o: np.ndarray) -> np.ndarray:
    """The exact inverse of `hue_forward`."""
    a = np.abs(theta_o)
    out = np.where(a < math.pi / 2, a / 1.5, math.pi / 3 + (a - math.pi / 2) / 0.75)
    return np.copysign(out, theta_o)


def _remap_hue(c: np.ndarray, hue_map) -> np.ndarray:
    """Chroma (2, ...) rotated so that its angle θ becomes hue_map(θ); the radius is kept."""
    rho = np.hypot(c[0], c[1])
    theta = np.where(rho > 0, np.arctan2(c[1], c[0]), 0.0)
    t = hue_map(theta)
    return np.stack([rho * np.cos(t), rho * np.sin(t)])


def rgb_to_orgb(rgb: np.ndarray) -> np.ndarray:
    """Gamma-encoded R'G'B' (3, ...) -> oRGB (L', C_yb, C_rg): the matrix, then the hue map."""
    lcc = np.tensordot(ORGB_FROM_RGB, rgb, axes=1)
    return np.concatenate([lcc[:1], _remap_hue(lcc[1:], hue_forward)])


def orgb_to_rgb(orgb: np.ndarray) -> np.ndarray:
    """The exact inverse of `rgb_to_orgb`."""
    lcc = np.concatenate([orgb[:1], _remap_hue(orgb[1:], hue_inverse)])
    return np.tensordot(RGB_FROM_ORGB, lcc, axes=1)


def encode(rgb: np.ndarray, gamma: float) -> np.ndarray:
    """Linear RGB (3, ...) -> gamma-encoded R'G'B' = max(J, 0)^gamma, the display encoding that
    oRGB takes. Only what a display can show has an encoding: negative components (a bleaching
    in LMS need not be a colour inside the RGB gamut) are 0."""
    return np.power(np.maximum(rgb, 0.0), gamma)


def opponent_chroma(orgb: np.ndarray, flight: float) -> np.ndarray:
    """The opponent of an oRGB colour (3, ...): both chroma axes negated (a half turn of the
    oRGB hue), turned by the flight-of-colours angle `flight` (radians); luma kept."""
    cos, sin = math.cos(flight), math.sin(flight)
    c1 = -(cos * orgb[1] - sin * orgb[2])
    c2 = -(sin * orgb[1] + cos * orgb[2])
    return np.stack([orgb[0], c1, c2])


def into_gamut(orgb: np.ndarray) -> np.ndarray:
    """oRGB (3, ...) with luma L' >= 0 -> R'G'B' >= 0 of the same luma and oRGB hue: where a
    component would be negative, the chroma is shrunk towards the grey (L', L', L') until the
    smallest component is 0. The hue map keeps radii, so shrinking the chroma in oRGB is
    shrinking R'G'B' - L' by the same factor s."""
    rgb = orgb_to_rgb(orgb)
    luma, low = orgb[0], rgb.min(axis=0)
    s = np.where(low < 0.0, luma / np.maximum(luma - low, 1e-30), 1.0)  # guard: black, 0/0
    return np.maximum(luma + s * (rgb - luma), 0.0)


def opponent(rgb: np.ndarray, flight: float, gamma: float) -> np.ndarray:
    """The opponent colour of linear RGB (3, ...) in oRGB, as linear RGB >= 0: encoded
    (`encode`, v = J^gamma), to oRGB, `opponent_chroma`, into the display gamut at the same
    luma and hue (`into_gamut`), decoded."""
    o = opponent_chroma(rgb_to_orgb(encode(rgb, gamma)), flight)
    return np.power(into_gamut(o), 1.0 / gamma)


# --- the model -----------------------------------------------------------------------------------


def saccade_sigma(lay: Layout, p: Params) -> float:
    """Micro-saccade blur of the input (Sec. 3.1, Eq. 1 as a convolution), in retina cells."""
    return lay.px(p.ritschel_saccade_sigma_deg) / lay.cell


def steps(p: Params) -> int:
    return max(1, int(p.ritschel_steps))


def diffusion_sigma(dt: float, lay: Layout, p: Params) -> float:
    """Diffusion blur of one of the n steps of a frame, in retina cells: σ = N_σ/sqrt(f) per
    frame (f = 1/dt) spread over the n blurs of Listing 1, so the blur after one second does
    not depend on the frame rate nor on n."""
    return lay.px(p.ritschel_N_sigma_deg) * math.sqrt(max(dt, 0.0) / steps(p)) / lay.cell


def effective_input(down: np.ndarray, surround: np.ndarray, gaze, lay: Layout, p: Params):
    """L of Eq. 3 at every retina cell: cone input (`surround` off the screen) / L_ref,
    blurred for micro-saccades."""
    I = retina_input(down, surround, gaze, lay)
    return blur2d(I / p.ritschel_L_ref, saccade_sigma(lay, p))


def r_inf(L: np.ndarray, p: Params) -> np.ndarray:
    """Equilibrium of Eq. 3 for a constant input: r = c_a L / (c_a L + c_d)."""
    a = p.c_a * L
    return a / np.maximum(a + p.c_d, _R_MIN)


def kinetics(r: np.ndarray, L: np.ndarray, dt: float, lay: Layout, p: Params) -> np.ndarray:
    """One frame of Listing 1: n explicit steps of Eq. 3 of length dt/n, each clamped to [0, 1]
    and followed by the diffusion blur."""
    h = dt / steps(p)
    sigma = diffusion_sigma(dt, lay, p)
    for _ in range(steps(p)):
        r = np.clip(r + h * (p.c_a * L * (1.0 - r) - p.c_d * r), 0.0, 1.0)  # Eq. 3
        r = blur2d(r, sigma)
    return r


def afterimage_maps(r: np.ndarray, L: np.ndarray, flight: float, p: Params) -> np.ndarray:
    """maps[0:3] = 1 (no gain); maps[3:6] = strength × the opponent colour of the bleaching in
    excess of the current input's equilibrium, max(r - r_inf(L), 0), as linear RGB >= 0."""
    excess = np.maximum(r - r_inf(L, p), 0.0)
    add = p.ritschel_strength * opponent(np.tensordot(LMS_TO_RGB, excess, axes=1), flight, p.gamma)
    return np.concatenate([np.ones_like(add), add])


class RitschelStage(Generic[StageBackendT]):
    """What both backends share: three state planes (r of L, M, S) and the flight-of-colours
    clock, the time since the last reset (deterministic: only dt moves it)."""

    state_channels = 3

    def __init__(self, backend: StageBackendT, seed: int) -> None:
        self.backend = backend
        self.clock = 0.0

    def prepared(self) -> None:
        pass

    def flight_angle(self, dt: float, reset: bool) -> float:
        """Advance the clock; the oRGB hue rotation of Sec. 3.3, in radians."""
        self.clock = 0.0 if reset else self.clock + dt
        return math.fmod(self.backend.p.ritschel_flight_rate * self.clock, 2.0 * math.pi)


class RitschelReference(RitschelStage[ReferenceStageBackend]):
    """The model on the reference backend's float64 arrays."""

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        a, lay, p = self.backend.a, self.backend.lay, self.backend.p
        L = effective_input(a["down"], a["surround"], gaze, lay, p)
        a["state"] = r_inf(L, p) if reset else kinetics(a["state"], L, dt, lay, p)
        a["maps"] = afterimage_maps(a["state"], L, self.flight_angle(dt, reset), p)
