"""PyOpenCL backend: the model's stages as kernels, state kept on the device between frames.

A GPU is used when one exists, otherwise the CPU (PoCL from PyPI). Set GAZEHDR_CL_DEVICE to a
substring of a device name to pick one. Kernel files live in `kernels/`, one per paper section.
"""

from __future__ import annotations

import math
import os
from functools import cache
from importlib import resources

import numpy as np
import pyopencl as cl

from server.sim.layout import (
    LMS_TO_RGB,
    RGB_TO_LMS,
    Layout,
    NoiseFrame,
    acuity_increments,
    gaussian_taps,
)
from server.sim.params import Params
from server.sim.reference import adaptation_window

KERNEL_FILES = (
    "common.cl",
    "sec2_1_global_adaptation.cl",
    "sec2_2_afterimages.cl",
    "sec2_3_mesopic.cl",
    "sec2_4_display.cl",
)
MAX_BANDS = 8
ROW_GROUP = 64  # global sizes of per-pixel kernels are rounded up to this
VEC = 8  # pixels per work-item in the blurs (VEC in kernels/common.cl)
ADAPT_WG = 256

PARAMS_DTYPE = np.dtype(
    [
        ("gamma", "f4"), ("n", "f4"), ("a1", "f4"), ("a2", "f4"),
        ("b1", "f4", 3), ("b2", "f4", 3),
        ("c2", "f4"), ("j1", "f4"), ("j2", "f4"), ("m1", "f4"), ("m2", "f4"),
        ("w_P", "f4", 3), ("w_S", "f4", 3), ("k_s", "f4", 3),
        ("g", "f4"), ("A_min", "f4"), ("alpha_eps", "f4"), ("Y_min", "f4"),
        ("ln_K_m", "f4"), ("n_minus_m", "f4"),
        ("H", "f4", 9), ("rgb2lms", "f4", 9), ("lms2rgb", "f4", 9),
        ("rho_i", "f4", MAX_BANDS), ("bands", "i4"),
    ]
)  # fmt: skip


def pack_params(p: Params) -> np.ndarray:
    """The kernels' `params_t` block (see kernels/common.cl), field for field."""
    if p.bands > MAX_BANDS:
        raise ValueError(f"the OpenCL backend supports at most {MAX_BANDS} acuity bands")
    m = p.n * p.plateau_m_over_n
    rec = np.zeros(1, PARAMS_DTYPE)
    for name in ("gamma", "n", "a1", "a2", "c2", "j1", "j2", "m1", "m2", "g", "A_min"):
        rec[name] = getattr(p, name)
    for name in ("b1", "b2", "w_P", "w_S", "k_s", "alpha_eps", "Y_min"):
        rec[name] = getattr(p, name)
    rec["ln_K_m"] = m * math.log(p.plateau_K)
    rec["n_minus_m"] = p.n - m
    rec["H"] = np.asarray(p.H).ravel()
    rec["rgb2lms"] = RGB_TO_LMS.ravel()
    rec["lms2rgb"] = LMS_TO_RGB.ravel()
    rec["rho_i"][0, : p.bands] = p.rho_i()
    rec["bands"] = p.bands
    return rec


def pick_device() -> cl.Device:
    """GAZEHDR_CL_DEVICE if set, else the first GPU, else the first device of any kind."""
    devices = [d for platform in cl.get_platforms() for d in platform.get_devices()]
    if not devices:
        raise RuntimeError("no OpenCL device found; install pyopencl[pocl] for the CPU")
    wanted = os.environ.get("GAZEHDR_CL_DEVICE")
    if wanted:
        for d in devices:
            if wanted.lower() in d.name.lower():
                return d
        names = ", ".join(d.name for d in devices)
        raise RuntimeError(f"GAZEHDR_CL_DEVICE={wanted!r} matches none of: {names}")
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    return (gpus or devices)[0]


@cache
def _context_and_program() -> tuple[cl.Context, cl.Program]:
    """One context and one built program per process: building takes seconds on PoCL."""
    ctx = cl.Context([pick_device()])
    pkg = resources.files("server.sim") / "kernels"
    source = "\n".join((pkg / name).read_text() for name in KERNEL_FILES)
    return ctx, cl.Program(ctx, source).build(options=["-cl-fast-relaxed-math"])


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


class OpenCLBackend:
    """Device buffers for every map of `Layout`; stage methods match ReferenceBackend's."""

    name = "opencl"

    def __init__(self, layout: Layout, params: Params) -> None:
        self.lay, self.p = layout, params
        self.ctx, self.prg = _context_and_program()
        self.queue = cl.CommandQueue(self.ctx)
        self.device_name = self.ctx.devices[0].name.strip()
        # Own kernel objects per backend: kernel arguments are state, simulators must not share it.
        self.k = {n: cl.Kernel(self.prg, n) for n in self.prg.kernel_names.split(";")}
        lay = layout
        full, low, grid = lay.width * lay.height, lay.low_w * lay.low_h, lay.grid_w * lay.grid_h
        self.shapes = {
            "scene": (3, lay.height, lay.width),
            "down": (5, lay.low_h, lay.low_w),
            "rho": (lay.low_h, lay.low_w),
            "A": (1,),
            "state": (6, lay.grid_h, lay.grid_w),
            "maps": (6, lay.grid_h, lay.grid_w),
            "d": (lay.height, lay.width),
            "G": (3, lay.height, lay.width),
            "v": (lay.height, lay.width, 3),
        }
        sizes = {
            "scene": 3 * full, "down": 5 * low, "rho": low, "A": 1, "state": 6 * grid,
            "maps": 6 * grid, "G": 3 * full, "v": 3 * full, "d_max": 1,
            "grid_a": 6 * grid, "grid_b": 6 * grid, "low_yp": low, "low_blur": low, "low_tmp": low,
            "lvl_a": 3 * full, "lvl_b": 3 * full, "lvl_tmp": 3 * full,
        }  # fmt: skip
        mf = cl.mem_flags
        self.buf = {n: cl.Buffer(self.ctx, mf.READ_WRITE, 4 * s) for n, s in sizes.items()}
        self.buf["d"] = cl.Buffer(self.ctx, mf.READ_WRITE, full)
        self.P = cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pack_params(params))
        self._taps: dict[float, tuple[cl.Buffer, int]] = {}
        self._noise_bufs: tuple[cl.Buffer, cl.Buffer] | None = None
        self._acuity_taps = [self._taps_for(s) for s in acuity_increments(params, lay.ppd)]
        self._rho_taps = self._taps_for(lay.px(params.rho_sigma_deg) / lay.cell)

    # --- host access (tests, adaptation readout) ----------------------------------------------

    def get(self, name: str) -> np.ndarray:
        dtype = np.uint8 if name == "d" else np.float32
        out = np.empty(self.shapes[name], dtype)
        cl.enqueue_copy(self.queue, out, self.buf[name])
        return out

    def put(self, name: str, value: np.ndarray) -> None:
        dtype = np.uint8 if name == "d" else np.float32
        arr = np.ascontiguousarray(np.asarray(value, dtype).reshape(self.shapes[name]))
        cl.enqueue_copy(self.queue, self.buf[name], arr)

    @property
    def A(self) -> float:
        return float(self.get("A")[0])

    # --- helpers --------------------------------------------------------------------------------

    def _taps_for(self, sigma: float) -> tuple[cl.Buffer, int]:
        key = round(float(sigma), 6)
        if key not in self._taps:
            taps = gaussian_taps(key)
            mf = cl.mem_flags
            buf = cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=taps)
            self._taps[key] = (buf, len(taps) // 2)
        return self._taps[key]

    def _blur(self, src, dst, tmp, taps, w: int, h: int, channels: int, level: int = -1):
        """Separable blur src -> dst through tmp; level >= 0 also fills G (acuity bank)."""
        tbuf, r = taps
        size = (-(-w // VEC), h, channels)
        dims = (np.int32(r), np.int32(w), np.int32(h))
        self.k["blur_h"](self.queue, size, None, src, tmp, tbuf, *dims)
        extra = (self.buf["d"], self.buf["G"], np.int32(level))
        self.k["blur_v"](self.queue, size, None, tmp, dst, tbuf, *dims, *extra)

    def _grid_args(self, gaze):
        lay = self.lay
        return (
            np.int32(lay.low_w), np.int32(lay.low_h), np.int32(lay.cell),
            np.int32(lay.grid_w), np.int32(lay.grid_h),
            np.float32(gaze[0]), np.float32(gaze[1]),
        )  # fmt: skip

    # --- stages ---------------------------------------------------------------------------------

    def set_scene(self, planar: np.ndarray) -> None:
        cl.enqueue_copy(self.queue, self.buf["scene"], planar)

    def prepare(self, eyes: float) -> None:
        lay, b = self.lay, self.buf
        self.k["downsample"](
            self.queue, (_round_up(lay.low_w, ROW_GROUP), lay.low_h), None,
            self.P, b["scene"], b["down"], np.int32(lay.width), np.int32(lay.height),
            np.int32(lay.cell), np.int32(lay.low_w), np.int32(lay.low_h), np.float32(eyes),
        )  # fmt: skip
        low = lay.low_w * lay.low_h
        # A copy, not a sub-buffer: sub-buffer offsets must be aligned, plane offsets are not.
        cl.enqueue_copy(
            self.queue, b["low_yp"], b["down"], src_offset=3 * low * 4, byte_count=low * 4
        )
        blurred = b["low_blur"]
        self._blur(b["low_yp"], blurred, b["low_tmp"], self._rho_taps, lay.low_w, lay.low_h, 1)
        self.k["rho_map"](
            self.queue, (_round_up(low, ROW_GROUP),), None, self.P, blurred, b["rho"],
            np.int32(low),
        )  # fmt: skip

    def adapt(self, gaze, dt: float, reset: bool) -> None:
        lay, b = self.lay, self.buf
        cx, cy, sig, x0, x1, y0, y1 = adaptation_window(gaze, lay, self.p)
        self.k["adapt"](
            self.queue, (ADAPT_WG,), (ADAPT_WG,), self.P, b["down"], b["rho"], b["A"],
            np.int32(lay.low_w), np.int32(lay.low_h), np.int32(lay.cell),
            np.float32(cx), np.float32(cy), np.float32(sig),
            np.int32(x0), np.int32(x1), np.int32(y0), np.int32(y1),
            np.float32(dt), np.int32(reset),
        )  # fmt: skip

    def retina(self, gaze, dt: float, reset: bool) -> None:
        lay, b, p = self.lay, self.buf, self.p
        grid = (_round_up(lay.grid_w, ROW_GROUP), lay.grid_h)
        args = self._grid_args(gaze)
        sigma = lay.px(p.map_blur_deg) * math.sqrt(dt) / lay.cell
        blurred = not reset and sigma > 0
        target = b["grid_a"] if blurred else b["state"]
        self.k["retina_update"](
            self.queue, grid, None, self.P, b["down"], b["state"], target, b["A"],
            *args, np.float32(dt), np.int32(reset),
        )  # fmt: skip
        if blurred:
            taps = self._taps_for(sigma)
            self._blur(b["grid_a"], b["state"], b["grid_b"], taps, lay.grid_w, lay.grid_h, 6)
        self.k["afterimage_maps"](
            self.queue, grid, None, self.P, b["down"], b["state"], b["maps"], b["A"], *args
        )

    def acuity(self, noise: NoiseFrame) -> None:
        lay, b = self.lay, self.buf
        self._upload_noise(noise)
        cl.enqueue_fill_buffer(self.queue, b["d_max"], np.int32(0), 0, 4)
        k0, k1 = self._noise_bufs
        self.k["acuity_levels"](
            self.queue, (_round_up(lay.width, ROW_GROUP), lay.height), None,
            self.P, b["rho"], k0, k1, np.float32(noise.frac), np.float32(noise.spacing),
            np.int32(noise.key0.shape[1]), np.int32(lay.low_w), np.int32(lay.low_h),
            np.int32(lay.cell), np.int32(lay.width), np.int32(lay.height),
            b["scene"], b["G"], b["d"], b["d_max"],
        )  # fmt: skip
        d_max = np.empty(1, np.int32)
        cl.enqueue_copy(self.queue, d_max, b["d_max"])
        # Levels no pixel needs are skipped: a photopic frame costs no blur at all.
        src, dst = b["scene"], b["lvl_a"]
        for level in range(int(d_max[0])):
            taps = self._acuity_taps[level]
            self._blur(src, dst, b["lvl_tmp"], taps, lay.width, lay.height, 3, level)
            src, dst = dst, (b["lvl_b"] if dst is b["lvl_a"] else b["lvl_a"])

    def _upload_noise(self, noise: NoiseFrame) -> None:
        if self._noise_bufs is None:
            mf = cl.mem_flags
            self._noise_bufs = tuple(
                cl.Buffer(self.ctx, mf.READ_ONLY, noise.key0.nbytes) for _ in range(2)
            )
        for buf, key in zip(self._noise_bufs, (noise.key0, noise.key1), strict=True):
            cl.enqueue_copy(self.queue, buf, np.ascontiguousarray(key, np.float32))

    def compose(self, gaze, eyes: float) -> np.ndarray:
        lay, b = self.lay, self.buf
        self.k["compose"](
            self.queue, (_round_up(lay.width, ROW_GROUP), lay.height), None,
            self.P, b["G"], b["rho"], b["maps"], b["A"], b["v"],
            np.int32(lay.width), np.int32(lay.height), np.int32(lay.low_w), np.int32(lay.low_h),
            np.int32(lay.cell), np.int32(lay.grid_w), np.int32(lay.grid_h),
            np.float32(gaze[0]), np.float32(gaze[1]), np.float32(eyes),
            np.float32(lay.px(self.p.fovea_sigma_deg)),
        )  # fmt: skip
        return self.get("v")
