"""Acuity models Jacobs et al. 2015 compare their stochastic model with (Sec. 2.3.3, Fig. 12):
NumPy references, the oracle of the OpenCL stages in `acuity_cl`.

- `none`: G is the scene.
- `gaussian`: one uniform blur of the frame (Ferwerda et al. 1996) whose sigma puts the
  response `acuity_cutoff_response` at the acuity limit R(L) of the luminance where the eye
  looks.
- `bilateral`: a per-pixel sigma from the local luminance, edges kept by a range kernel on
  log10 luminance (Jensen et al. 2000), made separable (ours, for cost).
- `thompson`: the uniform blur plus a difference-of-Gaussians band (in log luminance) that keeps
  edges crisp, then multiplicative temporal noise growing toward scotopic vision (Thompson et
  al. 2002).

Shared readings (ours, docs/baselines/acuity.md): the viewer's own eye already resolves the
display at the adaptation floor 10^A_min, so each model adds only the blur beyond it
(sigma_add^2 = sigma(L)^2 - sigma(10^A_min)^2): photopic scenes come out unchanged. Sigma is
capped at `acuity_sigma_max_deg`, where the fit R(L) falls toward zero.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gazehdr.sim.layout import Layout, NoiseFrame, bilinear, bilinear_at
from gazehdr.sim.models import Gaze, ReferenceStageBackend
from gazehdr.sim.params import Params
from gazehdr.sim.reference import blur2d, screen_coords

# Ferwerda et al. 1996, fit to Shaler's data: R(L) = 17.25 atan(1.4 log10 L + 0.35) + 25.72 cpd.
FERWERDA = (17.25, 1.4, 0.35, 25.72)
_M32 = 0xFFFFFFFF
_GOLDEN = 0x9E3779B9  # decorrelates the second uniform of Box-Muller from the first
# Floor of the bilateral's sigma^2 (px^2): keeps 1/sigma^2 finite where sigma = 0; a neighbour's
# weight is then at most e^-500, so the pass is the identity.
VAR_FLOOR_PX2 = 1e-3


def acuity_limit_cpd(log10_L: Any) -> Any:
    """Highest resolvable spatial frequency (cycles/deg) at adaptation luminance 10^log10_L."""
    a, b, c, d = FERWERDA
    return a * np.arctan(b * np.asarray(log10_L, np.float64) + c) + d


def sigma_constants(p: Params) -> tuple[float, float, float]:
    """(k, sigma_display^2, sigma_max) in degrees: sigma(L) = k / R(L) gives the response
    exp(-2 pi^2 sigma^2 R^2) = acuity_cutoff_response at the limit R."""
    k = math.sqrt(-math.log(p.acuity_cutoff_response) / (2.0 * math.pi**2))
    s_disp = k / float(acuity_limit_cpd(p.A_min))
    return k, s_disp * s_disp, p.acuity_sigma_max_deg


def blur_sigma_px(log10_L: Any, lay: Layout, p: Params) -> Any:
    """Sigma (px) added for luminance 10^log10_L: beyond the viewer's own at 10^A_min, capped."""
    k, s_disp2, s_max = sigma_constants(p)
    s = k / np.maximum(acuity_limit_cpd(log10_L), k / s_max)  # R <= 0 below ~1e-9 cd/m^2
    return np.sqrt(np.maximum(s * s - s_disp2, 0.0)) * lay.ppd


def log10_L_of_rho(rho: Any, p: Params) -> Any:
    """Eq. 13 inverted: the locally averaged photopic log10 luminance."""
    return p.m2 + np.asarray(rho, np.float64) * (p.m1 - p.m2)


def gaze_sigma_px(rho: np.ndarray, gaze: Gaze, lay: Layout, p: Params) -> float:
    """The one sigma of the uniform models: from rho (the 0.5 deg local mean, Eq. 13) at the
    gaze, read from the low-res map as compose reads it (edges clamped)."""
    r = bilinear_at(np.asarray(rho, np.float64), gaze[0] / lay.cell, gaze[1] / lay.cell)
    return float(blur_sigma_px(log10_L_of_rho(r, p), lay, p))


def rho_per_pixel(rho: np.ndarray, lay: Layout) -> np.ndarray:
    """rho at every screen pixel, bilinear from the low-res map (the OpenCL `rho_full`)."""
    X, Y = screen_coords(lay)
    return bilinear(np.asarray(rho, np.float64)[None], X / lay.cell, Y / lay.cell)[0]


def log10_luminance(scene: np.ndarray, p: Params) -> np.ndarray:
    """log10 of the photopic luminance, floored at Y_min (no log of 0)."""
    return np.log10(np.maximum(np.tensordot(np.asarray(p.w_P), scene, axes=1), p.Y_min))


def bilateral_radius(sigma_max_px: float) -> int:
    """Half-width of both bilateral passes: 3 sigma of the widest pixel of the frame."""
    return math.ceil(3.0 * sigma_max_px)


def bilateral_pass(
    img: np.ndarray, guide: np.ndarray, sigma: np.ndarray, p: Params, radius: int, axis: int
) -> np.ndarray:
    """One 1-D pass of the separable bilateral: spatial Gaussian of each output pixel's own
    sigma, range Gaussian on the guide (log10 luminance of the scene); taps off the frame are
    left out (the weights are normalised)."""
    inv_s = 0.5 / np.maximum(sigma * sigma, VAR_FLOOR_PX2)
    inv_r = 1.0 / (2.0 * p.bilateral_sigma_r**2)
    acc, wsum = img.copy(), np.ones(guide.shape)
    n = guide.shape[axis]
    idx = np.arange(n)
    for k in (*range(-radius, 0), *range(1, radius + 1)):
        src = np.clip(idx + k, 0, n - 1)
        inside = ((idx + k >= 0) & (idx + k < n)).reshape((-1, 1) if axis == 0 else (1, -1))
        dl = np.take(guide, src, axis=axis) - guide
        w = np.where(inside, np.exp(-k * k * inv_s - dl * dl * inv_r), 0.0)
        acc += w * np.take(img, src, axis=axis + 1)
        wsum += w
    return acc / wsum


def lowbias32(x: np.ndarray) -> np.ndarray:
    """C. Wellons' integer hash (as web/renderer.js), on uint32 arrays (wrapping arithmetic)."""
    shape = np.shape(x)
    x = np.array(x, np.uint32, ndmin=1)  # arrays wrap silently; NumPy scalars would warn
    x = x ^ (x >> np.uint32(16))
    x = x * np.uint32(0x7FEB352D)
    x = x ^ (x >> np.uint32(15))
    x = x * np.uint32(0x846CA68B)
    return (x ^ (x >> np.uint32(16))).reshape(shape)


def noise_key(seed: int, t: float, p: Params) -> int:
    """The counter of the Thompson noise: a hash of (seed, floor(t * thompson_noise_hz))."""
    frame = math.floor(max(t, 0.0) * p.thompson_noise_hz) & _M32
    return int(lowbias32(np.uint32(int(lowbias32(np.uint32(seed & _M32))) ^ frame)))


def normal_field(key: int, width: int, height: int) -> np.ndarray:
    """N(0,1) per pixel from (key, pixel index) only: lowbias32, then Box-Muller."""
    i = np.arange(width * height, dtype=np.uint32).reshape(height, width)
    h = lowbias32(np.uint32(key) ^ lowbias32(i))
    u1 = ((h >> np.uint32(8)).astype(np.float64) + 0.5) / 16777216.0  # (0, 1): no log of 0
    u2 = (lowbias32(h + np.uint32(_GOLDEN)) >> np.uint32(8)).astype(np.float64) / 16777216.0
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * math.pi * u2)


def thompson(
    scene: np.ndarray, sigma: float, rho_c: np.ndarray, normal: np.ndarray, p: Params
) -> np.ndarray:
    """Blur at sigma; add back, with gain thompson_dog_gain, the band between the luminance
    blurred at sigma and at thompson_dog_ratio * sigma (crisp edges), taken in log luminance
    (ours: on HDR radiance a linear band rings below 0 around lights); keep the blurred colour
    ratios; then multiply by 1 + thompson_noise (1 - rho_c) N (never below 0)."""
    wp = np.asarray(p.w_P)
    blurred = blur2d(scene, sigma)
    yb = np.maximum(np.tensordot(wp, blurred, axes=1), p.Y_min)
    ys = blur2d(np.tensordot(wp, scene, axes=1)[None], p.thompson_dog_ratio * sigma)[0]
    gain = np.exp(p.thompson_dog_gain * (np.log(yb) - np.log(np.maximum(ys, p.Y_min))))
    noise = np.maximum(1.0 + p.thompson_noise * (1.0 - rho_c) * normal, 0.0)
    return blurred * (gain * noise)[None]


class NoAcuityReference:
    """No acuity loss: the eye resolves everything the display shows."""

    def __init__(self, backend: ReferenceStageBackend, seed: int) -> None:
        self.backend = backend

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        self.backend.a["G"] = self.backend.a["scene"].copy()


class GaussianAcuityReference(NoAcuityReference):
    """Ferwerda et al. 1996: one Gaussian for the whole frame, from the luminance at the gaze."""

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b = self.backend
        b.a["G"] = blur2d(b.a["scene"], gaze_sigma_px(b.a["rho"], gaze, b.lay, b.p))


class BilateralAcuityReference(NoAcuityReference):
    """Jensen et al. 2000: sigma from each pixel's local luminance, a range kernel on log10
    luminance keeps strong edges; horizontal then vertical pass."""

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b = self.backend
        lay, p, rho, scene = b.lay, b.p, b.a["rho"], b.a["scene"]
        sigma = blur_sigma_px(log10_L_of_rho(rho_per_pixel(rho, lay), p), lay, p)
        radius = bilateral_radius(float(blur_sigma_px(log10_L_of_rho(rho.min(), p), lay, p)))
        guide = log10_luminance(scene, p)
        half = bilateral_pass(scene, guide, sigma, p, radius, axis=1)
        b.a["G"] = bilateral_pass(half, guide, sigma, p, radius, axis=0)


class ThompsonAcuityReference(NoAcuityReference):
    """Thompson et al. 2002: scotopic blur with crisp edges and seeded temporal noise."""

    def __init__(self, backend: ReferenceStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self.seed = int(seed)

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b = self.backend
        lay, p = b.lay, b.p
        sigma = gaze_sigma_px(b.a["rho"], gaze, lay, p)
        rho_c = np.clip(rho_per_pixel(b.a["rho"], lay), 0.0, 1.0)
        normal = normal_field(noise_key(self.seed, t, p), lay.width, lay.height)
        b.a["G"] = thompson(b.a["scene"], sigma, rho_c, normal, p)
