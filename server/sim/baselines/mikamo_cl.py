"""Mikamo et al. 2012 on the OpenCL backend: kernels/mikamo2012_afterimages.cl, then the
backend's separable blur as the fixed low-pass. Same steps as MikamoReference (the oracle)."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from gazehdr.sim.baselines.mikamo import (
    LUMINANCE_EPS,
    WHITE_XYZ,
    XYZ_TO_RGB,
    MikamoModel,
)
from gazehdr.sim.layout import RGB_TO_XYZ
from gazehdr.sim.models import Gaze, OpenCLStageBackend

KERNEL_FILES = ("common.cl", "mikamo2012_afterimages.cl")


class MikamoOpenCL(MikamoModel[OpenCLStageBackend]):
    """Own kernel and buffers per instance (kernel arguments are state)."""

    def __init__(self, backend: OpenCLStageBackend, seed: int) -> None:
        super().__init__(backend, seed)
        self.kernel = backend.kernels(KERNEL_FILES)["mikamo_step"]
        consts = np.concatenate(
            [
                RGB_TO_XYZ.ravel(),
                XYZ_TO_RGB.ravel(),
                [
                    WHITE_XYZ[0],
                    WHITE_XYZ[2],
                    *self.ref_ab,
                    backend.p.mikamo_delta_e_floor,
                    LUMINANCE_EPS,
                ],
            ]
        ).astype(np.float32)
        seq = np.ascontiguousarray(np.column_stack([self.sequence.t, self.lab]), np.float32)
        mf = cl.mem_flags
        ctx = backend.ctx
        self.consts = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=consts)
        self.seq = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=seq)
        self.n_seq = len(seq)
        lay = self.lay
        self.plane_bytes = 4 * lay.grid_w * lay.grid_h
        self.add, self.blurred, self.tmp = (
            cl.Buffer(ctx, mf.READ_WRITE, 3 * self.plane_bytes) for _ in range(3)
        )
        self.taps = backend.taps_for(self.lowpass_cells)

    def retina(self, gaze: Gaze, dt: float, reset: bool) -> None:
        b, lay, p = self.backend, self.lay, self.p
        thr, y_max = self.on_stats(reset)
        self.kernel(
            b.queue, (lay.grid_w, lay.grid_h), None,
            b.P, b.buf["down"], b.buf["surround"], b.buf["state"], b.buf["maps"], self.add,
            self.consts, self.seq, np.int32(self.n_seq), *b.grid_args(gaze), np.float32(dt),
            np.int32(reset), np.float32(thr), np.float32(y_max),
            np.float32(10.0**p.mikamo_drop_log10), np.float32(p.mikamo_gamma),
            np.float32(p.mikamo_strength),
        )  # fmt: skip
        b.blur(self.add, self.blurred, self.tmp, self.taps, lay.grid_w, lay.grid_h, 3)
        cl.enqueue_copy(
            b.queue, b.buf["maps"], self.blurred,
            dst_offset=3 * self.plane_bytes, byte_count=3 * self.plane_bytes,
        )  # fmt: skip
