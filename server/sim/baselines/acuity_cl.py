"""OpenCL stages of the acuity baselines (kernels/sec2_3_3_acuity_baselines.cl); the NumPy
reference in `acuity` is their oracle and holds the readings. Host-side numbers (the sigma at
the gaze, the bilateral's radius, the noise counter) come from the same functions there."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from gazehdr.sim.baselines.acuity import (
    FERWERDA,
    VAR_FLOOR_PX2,
    bilateral_radius,
    blur_sigma_px,
    gaze_sigma_px,
    log10_L_of_rho,
    noise_key,
    sigma_constants,
)
from gazehdr.sim.layout import NoiseFrame, gaussian_taps
from gazehdr.sim.models import Gaze, OpenCLStageBackend

KERNEL_FILES = ("common.cl", "sec2_3_3_acuity_baselines.cl")


class _Taps:
    """One device buffer of Gaussian taps, rewritten when sigma changes: sigma follows the gaze
    continuously, so a buffer per sigma (the backend's cache) would grow without end."""

    def __init__(self, backend: OpenCLStageBackend, sigma_max: float) -> None:
        self.backend = backend
        n = len(gaussian_taps(sigma_max)) + 2  # + 2: rounding of sigma at the cap
        self.buf = cl.Buffer(backend.ctx, cl.mem_flags.READ_ONLY, 4 * n)
        self.sigma: float | None = None
        self.radius = 0

    def at(self, sigma: float) -> tuple[cl.Buffer, int]:
        if sigma != self.sigma:
            taps = gaussian_taps(sigma)
            cl.enqueue_copy(self.backend.queue, self.buf, taps)  # the stage's queue now
            self.sigma, self.radius = sigma, len(taps) // 2
        return self.buf, self.radius


class NoAcuityOpenCL:
    """G is the scene."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        self.backend = backend
        self.seed = int(seed)

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b = self.backend
        b.store_G(b.buf["scene"])

    # --- shared by the blurring stages ---------------------------------------------------------

    def _setup(self, full_planes: tuple[int, ...]) -> None:
        """Kernels of this file (own objects: arguments are per stage) and scratch buffers."""
        b = self.backend
        self.k = b.kernels(KERNEL_FILES)
        full = 4 * b.lay.width * b.lay.height
        self.scratch = [cl.Buffer(b.ctx, cl.mem_flags.READ_WRITE, n * full) for n in full_planes]
        self.sigma_max_px = b.lay.px(b.p.acuity_sigma_max_deg)

    def _gaze_sigma(self, gaze: Gaze) -> float:
        b = self.backend
        return gaze_sigma_px(b.get("rho").astype(np.float64), gaze, b.lay, b.p)

    def _size(self) -> tuple[int, int]:
        return self.backend.lay.width, self.backend.lay.height

    def _dims(self) -> tuple[np.int32, np.int32]:
        w, h = self._size()
        return np.int32(w), np.int32(h)


class GaussianAcuityOpenCL(NoAcuityOpenCL):
    """Ferwerda et al. 1996: the backend's separable blur with the sigma at the gaze."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self._setup((3, 3))  # blur scratch, blurred
        self.taps = _Taps(backend, self.sigma_max_px)

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b = self.backend
        w, h = self._size()
        tmp, blurred = self.scratch
        b.blur(b.buf["scene"], blurred, tmp, self.taps.at(self._gaze_sigma(gaze)), w, h, 3)
        b.store_G(blurred)


class BilateralAcuityOpenCL(NoAcuityOpenCL):
    """Jensen et al. 2000: guide and sigma per pixel, then a horizontal and a vertical pass."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self._setup((3, 1, 1, 3))  # half-filtered image, guide, sigma, filtered image

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b, p = self.backend, self.backend.p
        half, guide, sigma, filtered = self.scratch
        rho_full = b.rho_full()
        k, s_disp2, s_max = sigma_constants(p)
        self.k["bilateral_prep"](
            b.queue, self._size(), None, b.P, b.buf["scene"], rho_full, guide, sigma,
            *self._dims(), *(np.float32(v) for v in FERWERDA),
            np.float32(k), np.float32(s_disp2), np.float32(s_max), np.float32(b.lay.ppd),
        )  # fmt: skip
        rho_min = float(b.get("rho").min())
        radius = bilateral_radius(float(blur_sigma_px(log10_L_of_rho(rho_min, p), b.lay, p)))
        inv_r = np.float32(0.5 / p.bilateral_sigma_r**2)
        for src, dst, dx, dy in ((b.buf["scene"], half, 1, 0), (half, filtered, 0, 1)):
            self.k["bilateral_pass"](
                b.queue, b.rows_v(), None, src, dst, guide, sigma, *self._dims(),
                np.int32(radius), np.int32(dx), np.int32(dy), inv_r, np.float32(VAR_FLOOR_PX2),
            )  # fmt: skip
        b.store_G(filtered)


class ThompsonAcuityOpenCL(NoAcuityOpenCL):
    """Thompson et al. 2002: blur, luminance band between sigma and ratio x sigma, noise."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self._setup((3, 3, 1, 1))  # blurred, blur scratch, luminance, wide luminance
        self.taps = _Taps(backend, self.sigma_max_px)
        self.taps_wide = _Taps(backend, backend.p.thompson_dog_ratio * self.sigma_max_px)

    def acuity(self, noise: NoiseFrame, gaze: Gaze, t: float) -> None:
        b, p = self.backend, self.backend.p
        blurred, tmp, lum, wide = self.scratch
        w, h = self._size()
        sigma = self._gaze_sigma(gaze)
        b.blur(b.buf["scene"], blurred, tmp, self.taps.at(sigma), w, h, 3)
        self.k["luminance"](b.queue, (w, h), None, b.P, b.buf["scene"], lum, *self._dims())
        b.blur(lum, wide, tmp, self.taps_wide.at(p.thompson_dog_ratio * sigma), w, h, 1)
        rho_full = b.rho_full()
        self.k["thompson_combine"](
            b.queue, (w, h), None, b.P, blurred, wide, rho_full, tmp,
            *self._dims(), np.float32(p.thompson_dog_gain), np.float32(p.thompson_noise),
            np.uint32(noise_key(self.seed, t, p)),
        )  # fmt: skip
        b.store_G(tmp)  # the blur's scratch is free again
