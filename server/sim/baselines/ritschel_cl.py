"""Ritschel & Eisemann 2012 afterimages on the OpenCL backend (kernels/ritschel2012_afterimages.cl).

Step for step the NumPy reference in `ritschel.py`: input, micro-saccade blur, n clamped steps
of Eq. 3 each followed by the diffusion blur, then the maps over the whole retina grid.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from gazehdr.sim.baselines.ritschel import (
    ORGB_FROM_RGB,
    RGB_FROM_ORGB,
    RitschelStage,
    diffusion_sigma,
    saccade_sigma,
    steps,
)
from gazehdr.sim.models import Gaze, OpenCLStageBackend

KERNEL_FILES = ("common.cl", "ritschel2012_afterimages.cl")


class RitschelOpenCL(RitschelStage[OpenCLStageBackend]):
    """The model on the OpenCL backend's device buffers; its own scratch planes on the grid."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self.k = backend.kernels(KERNEL_FILES)
        lay = backend.lay
        self.cells = lay.grid_w * lay.grid_h
        mf = cl.mem_flags
        # L before and after the micro-saccade blur, and the blurs' intermediate: 3 planes each.
        self.buf = {n: cl.Buffer(backend.ctx, mf.READ_WRITE, 12 * self.cells) for n in "LRT"}
        for buf in self.buf.values():
            cl.enqueue_fill_buffer(backend.queue, buf, np.uint8(0), 0, buf.size)
        matrices = np.concatenate([ORGB_FROM_RGB.ravel(), RGB_FROM_ORGB.ravel()])
        self.orgb = cl.Buffer(
            backend.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=matrices.astype(np.float32)
        )
        self.saccade_taps = backend.taps_for(saccade_sigma(lay, backend.p))

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        b, lay, p, q = self.backend, self.backend.lay, self.backend.p, self.backend.queue
        raw, L, tmp = self.buf["R"], self.buf["L"], self.buf["T"]
        state = b.buf["state"]
        grid = (lay.grid_w, lay.grid_h)
        self.k["ritschel_input"](
            q, grid, None, b.buf["down"], b.buf["surround"], raw, np.int32(lay.low_w),
            np.int32(lay.low_h),
            np.int32(lay.cell), np.int32(lay.grid_w), np.int32(lay.grid_h),
            np.float32(gaze[0]), np.float32(gaze[1]), np.float32(1.0 / p.ritschel_L_ref),
        )  # fmt: skip
        b.blur(raw, L, tmp, self.saccade_taps, lay.grid_w, lay.grid_h, 3)
        kin = self.k["ritschel_kinetics"]
        rates = (np.float32(p.c_a), np.float32(p.c_d))
        n3 = (3 * self.cells,)
        if reset:
            kin(q, n3, None, L, state, state, np.int32(n3[0]), np.float32(0), *rates, np.int32(1))
        else:
            h = np.float32(dt / steps(p))
            taps = b.taps_for(diffusion_sigma(dt, lay, p))
            for _ in range(steps(p)):  # Listing 1: step into grid_a, blur back into state
                kin(q, n3, None, L, state, b.buf["grid_a"], np.int32(n3[0]), h, *rates,
                    np.int32(0))  # fmt: skip
                b.blur(b.buf["grid_a"], state, tmp, taps, lay.grid_w, lay.grid_h, 3)
        flight = self.flight_angle(dt, reset)
        self.k["ritschel_maps"](
            q, (-(-self.cells // b.vec),), None, b.P, self.orgb, L, state, b.buf["maps"],
            np.int32(self.cells), *rates, np.float32(p.ritschel_strength),
            np.float32(math.cos(flight)), np.float32(math.sin(flight)),
        )  # fmt: skip
