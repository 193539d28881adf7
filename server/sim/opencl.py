"""PyOpenCL backend: the model's stages as kernels, state kept on the device between frames.

A GPU is used when one exists, otherwise the CPU (PoCL from PyPI). Set GAZEHDR_CL_DEVICE to a
substring of a device name to pick one. Kernel files live in `kernels/`, one per paper section.

Written for speed on PoCL (see kernels/common.cl):
- the per-pixel kernels make VEC pixels of a row per work-item (16 where PoCL builds for
  AVX-512, else 8: vector_width);
- a scene that stays gets its acuity levels made once, and each frame picks every pixel's level
  from them; until then the acuity bank runs all its levels per screen tile in local memory
  (GPUs, or GAZEHDR_CL_ACUITY=levels, use the level-by-level bank instead);
- the afterimage maps are made only where the screen shows them, the rest of the grid on demand
  (get("maps"), or a compose at another gaze);
- rho at every pixel is kept from the last scene load;
- G, and the acuity levels it is picked from, are 16 bits a channel (lum16.py): half the bytes;
- the acuity runs on a second queue beside the adaptation and the retina (`alongside`).

The parts that stand alone live apart: the context, the programs' build and the kernels'
launch (cl_program.py), the parameter block (kernel_params.py), the acuity levels
(level_stack.py), G's 16 bits (lum16.py), PoCL's CPU settings (pocl_cpu.py). Past 600 lines
because what is left is one object: every stage's launches read and write the same device
buffers, in the order `ReferenceBackend`'s stage methods give.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import numpy as np
import pyopencl as cl

from gazehdr.drivers.errors import InputError
from gazehdr.sim import lum16
from gazehdr.sim.cl_program import Launch, build_program, shared_context, vector_width
from gazehdr.sim.kernel_params import pack_params
from gazehdr.sim.layout import (
    Layout,
    NoiseFrame,
    acuity_increments,
    adaptation_window,
    blind_spot_strength,
    edge_loop,
    gaussian_taps,
    map_blur_sigma,
    settle_plan,
)
from gazehdr.sim.level_stack import LevelStack
from gazehdr.sim.params import MAX_BANDS, Params

KERNEL_FILES = (
    "common.cl",
    "sec2_1_global_adaptation.cl",
    "sec2_2_afterimages.cl",
    "sec2_3_mesopic.cl",
    "sec2_4_display.cl",
    "sec5_discussion.cl",
)
TAPS_CACHE = 32  # blur tap buffers kept per backend
STATE_PLANES = 9  # retinal state planes allocated; an afterimage model uses up to this many
ROW_GROUP = 64  # global sizes of per-pixel kernels are rounded up to this
ADAPT_WG = 256
#: Rows of the map blur a work-item makes (kernel retina_blur), each row's horizontal pass made
#: once: the kernel 0.85-0.89x as long as with one row (three passes per row) within live steps
#: at 1280x720 and 1920x1080, 0.44-0.70x run alone with its input in cache; 4 and 8 rows did
#: best there, 12 and more less well balanced over the cores (2026-11-27, the 640x360 grid).
BLUR_ROWS = 8
ACUITY_TILE = (128, 64)  # screen px per work-item of the tiled bank (x: 16 multiple, <= 128)

#: Runs of VEC pixels a work-item of compose's kernels (COMPOSE_RUNS in sec2_4_display.cl).
COMPOSE_RUNS = 2
# compose's outputs: kernel, buffer, shape
COMPOSE_OUTPUTS = {
    np.dtype(np.float32): ("compose", "v", lambda lay: (lay.height, lay.width, 3)),
    np.dtype(np.float16): ("compose_half", "v16", lambda lay: (lay.height, lay.width, 3)),
    np.dtype(np.uint32): ("compose_rgb10", "v10", lambda lay: (lay.height, lay.width)),
}


#: Retina cells (j0, i0, j1, i1), inclusive.
Window = tuple[int, int, int, int]
NO_CELLS: Window = (0, 0, -1, -1)


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def _done(event: cl.Event) -> bool:
    return event.command_execution_status == cl.command_execution_status.COMPLETE


class OpenCLBackend:
    """Device buffers for every map of `Layout`; stage methods match ReferenceBackend's. What a
    baseline stage may use is declared by `models.OpenCLStageBackend`."""

    name = "opencl"

    def __init__(self, layout: Layout, params: Params) -> None:
        self.lay, self.p = layout, params
        self.ctx = shared_context()
        self.queue = cl.CommandQueue(self.ctx)
        self.device_name = self.ctx.devices[0].name.strip()
        #: The device's memory is the host's (PoCL on the CPU): compose writes into a frame's
        #: message itself (`compose`'s `out`, CL_MEM_USE_HOST_PTR; mapping it copies nothing)
        #: instead of being read back into it: 1.05x the frames at 720p (docs/performance.md).
        self.shares_host_memory = bool(self.ctx.devices[0].host_unified_memory)
        self.vec = vector_width()  # pixels per work-item, fixed for this backend's programs
        self.k = self.kernels(KERNEL_FILES)
        lay = layout
        full, low, grid = lay.width * lay.height, lay.low_w * lay.low_h, lay.grid_w * lay.grid_h
        self.shapes = {
            "scene": (3, lay.height, lay.width),
            "down": (5, lay.low_h, lay.low_w),
            "rho": (lay.low_h, lay.low_w),
            "surround": (3, lay.low_h, lay.low_w),
            "fill": (3, lay.low_h, lay.low_w),
            "A": (1,),
            "state": (9, lay.grid_h, lay.grid_w),
            "maps": (6, lay.grid_h, lay.grid_w),
            "d": (lay.height, lay.width),
            "G": (3, lay.height, lay.width),
            "v": (lay.height, lay.width, 3),
            "rho_full": (lay.height, lay.width),
        }
        self._bank = self._acuity_bank_setup()
        sizes = {
            "scene": 3 * full, "down": 5 * low, "rho": low, "A": 1,
            "state": STATE_PLANES * grid, "maps": 6 * grid, "v": 3 * full,
            "d_max": 1, "rho_full": full, "grid_a": STATE_PLANES * grid, "low_yp": low,
            "low_blur": low, "low_tmp": low, "fovea": lay.width + lay.height,
            "surround": 3 * low, "fill": 3 * low, "fill_tmp": 3 * low,
            "blind_xy": lay.width + lay.height,
        }  # fmt: skip
        if self._bank is None:  # the level-by-level bank's whole-frame levels
            sizes.update({"lvl_a": 3 * full, "lvl_b": 3 * full, "lvl_tmp": 3 * full})
        mf = cl.mem_flags
        self.buf = {n: cl.Buffer(self.ctx, mf.READ_WRITE, 4 * s) for n, s in sizes.items()}
        self.buf["d"] = cl.Buffer(self.ctx, mf.READ_WRITE, full)
        self.buf["G"] = cl.Buffer(self.ctx, mf.READ_WRITE, 2 * 3 * full)  # lum16 codes
        self.buf["v16"] = cl.Buffer(self.ctx, mf.READ_WRITE, 2 * 3 * full)
        self.buf["v10"] = cl.Buffer(self.ctx, mf.READ_WRITE, 4 * full)
        for buf in self.buf.values():  # never read uninitialised memory (NaN patterns)
            cl.enqueue_fill_buffer(self.queue, buf, np.uint8(0), 0, buf.size)
        # rho at every pixel (from "rho"), remade when rho changes
        self._rho_full_stale = True
        # The afterimage maps are made only where the screen shows them: (the gaze of the last
        # retina step, the window of cells made) while the rest of the grid is still to be
        # made (_more_maps, _full_maps); None when all of it is.
        self._maps_made: tuple[tuple[float, float], Window] | None = None
        self.P = cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pack_params(params))
        self._taps: dict[float, tuple[cl.Buffer, int]] = {}
        self._noise_buf: cl.Buffer | None = None
        self._uploads: list[cl.Event] = []  # host-to-device copies still in flight (_upload)
        self._beside: tuple[cl.CommandQueue, cl.CommandQueue] | None = None  # (queue, its side)
        self._acuity_taps = [self.taps_for(s) for s in acuity_increments(params, lay.ppd)]
        self._rho_taps = self.taps_for(lay.px(params.rho_sigma_deg) / lay.cell)
        self._surround_taps = self.taps_for(lay.px(params.surround_sigma_deg) / lay.cell)
        self._fill_taps = self.taps_for(lay.px(2 * params.rod_free_radius_deg) / lay.cell)
        self._settle_buf: dict[str, cl.Buffer] = {}  # made at the first settle
        # The scene's acuity levels, made once the scene has stayed a while.
        self._stack = LevelStack(self)

    # --- host access (tests, adaptation readout) ----------------------------------------------

    def set_state_channels(self, n: int) -> None:
        """The afterimage model's retinal state has `n` planes (of STATE_PLANES allocated)."""
        if not 1 <= n <= STATE_PLANES:
            raise InputError(f"an afterimage model may keep 1 to {STATE_PLANES} state planes")
        self.shapes["state"] = (n, self.lay.grid_h, self.lay.grid_w)

    def get(self, name: str) -> np.ndarray:
        """A map as float32 (G decoded from its 16 bits), `d` as uint8."""
        if name == "maps":
            self._full_maps()
        out = np.empty(self.shapes[name], self._dtype(name))
        cl.enqueue_copy(self.queue, out, self.buf[name])
        return lum16.decode(out) if name == "G" else out

    def put(self, name: str, value: np.ndarray) -> None:
        arr = np.asarray(value, np.float32 if name == "G" else self._dtype(name))
        if name == "G":
            arr = lum16.encode(arr)
        arr = np.ascontiguousarray(arr.reshape(self.shapes[name]))
        cl.enqueue_copy(self.queue, self.buf[name], arr)
        if name == "rho":
            self._rho_full_stale = True
        if name == "scene":
            self._stack.scene_changed()
        if name == "maps":
            self._maps_made = None

    @staticmethod
    def _dtype(name: str) -> type:
        """How a map is kept on the device."""
        return {"d": np.uint8, "G": np.uint16}.get(name, np.float32)

    @property
    def A(self) -> float:
        return float(self.get("A")[0])

    # --- for stages (models.OpenCLStageBackend) -----------------------------------------------

    def kernels(self, files: tuple[str, ...]) -> dict[str, Launch]:
        """Own kernel objects of the program of `files`: kernel arguments are state, so no two
        simulators (or stages) may share one."""
        prg = build_program(files, self.vec)
        return {n: Launch(cl.Kernel(prg, n)) for n in prg.kernel_names.split(";")}

    def taps_for(self, sigma: float) -> tuple[cl.Buffer, int]:
        """Taps on the device, cached by sigma. A live session's dt, and so its per-frame blur
        sigma, varies from frame to frame: the cache keeps the newest TAPS_CACHE only (a buffer
        still used by queued kernels lives until they finish)."""
        key = round(float(sigma), 6)
        if key not in self._taps:
            if len(self._taps) >= TAPS_CACHE:
                del self._taps[next(iter(self._taps))]
            taps = gaussian_taps(key)
            mf = cl.mem_flags
            buf = cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=taps)
            self._taps[key] = (buf, len(taps) // 2)
        return self._taps[key]

    def alongside(self, side: Callable[[], None], main: Callable[[], None]) -> None:
        """Enqueue `side` on a second queue and `main` on `queue`, so that their kernels run at
        once: each kernel leaves a core idle at times (its last work-groups, the pick's waits
        on memory) that the other's can use. `side` starts once everything enqueued before it
        is done, and what is enqueued after waits for both. The acuity beside the adaptation and
        the retina: whole 1920x1080 steps 0.96x as long on two CPU cores (docs/performance.md,
        "Launching kernels")."""
        queue = self.queue
        if self._beside is None or self._beside[0] is not queue:  # a bench swaps `queue`
            self._beside = (queue, cl.CommandQueue(self.ctx, properties=queue.properties))
        beside = self._beside[1]
        cl.enqueue_barrier(beside, wait_for=[cl.enqueue_marker(queue)])
        self.queue = beside
        try:
            side()
        finally:
            self.queue = queue
            side_done = cl.enqueue_marker(beside)
        try:
            main()
        finally:
            cl.enqueue_barrier(queue, wait_for=[side_done])

    def blur(
        self, src: cl.Buffer, dst: cl.Buffer, tmp: cl.Buffer, taps: tuple[cl.Buffer, int],
        w: int, h: int, channels: int, level: int = -1,
    ) -> None:  # fmt: skip
        """Separable blur src -> dst through tmp; level >= 0 also fills G (acuity bank)."""
        tbuf, r = taps
        size = (-(-w // self.vec), h, channels)
        dims = (np.int32(r), np.int32(w), np.int32(h))
        self.k["blur_h"](self.queue, size, None, src, tmp, tbuf, *dims)
        extra = (self.buf["d"], self.buf["G"], np.int32(level))
        self.k["blur_v"](self.queue, size, None, tmp, dst, tbuf, *dims, *extra)

    def store_G(self, src: cl.Buffer) -> None:
        """G from three float planes of the screen (`src`: the scene, or a baseline's blur),
        in its 16 bits (kernel lum16_encode)."""
        self.encode_lum16(src, self.buf["G"], 3 * self.lay.width * self.lay.height)

    def encode_lum16(self, src: cl.Buffer, dst: cl.Buffer, n: int) -> None:
        """`n` floats of `src` as lum16 codes into `dst` (G, a level of the acuity stack)."""
        size = (_round_up(-(-n // self.vec), ROW_GROUP),)
        self.k["lum16_encode"](self.queue, size, None, src, dst, np.int32(n))

    def rows_v(self, runs: int = 1) -> tuple[int, int]:
        """Global size of the kernels that make `runs` runs of VEC neighbouring pixels of a row
        per work-item (compose's make two)."""
        return (-(-self.lay.width // (runs * self.vec)), self.lay.height)

    def rho_full(self) -> cl.Buffer:
        """rho at every screen pixel, remade from "rho" when that changed."""
        lay, b = self.lay, self.buf
        if self._rho_full_stale:
            self.k["rho_upsample"](
                self.queue, self.rows_v(), None, b["rho"], b["rho_full"],
                np.int32(lay.low_w), np.int32(lay.low_h), np.int32(lay.cell),
                np.int32(lay.width), np.int32(lay.height),
            )  # fmt: skip
            self._rho_full_stale = False
        return b["rho_full"]

    def grid_args(self, gaze) -> tuple[np.int32 | np.float32, ...]:
        """Retina-grid arguments of the kernels: low-res and grid sizes, cell, gaze."""
        lay = self.lay
        return (
            np.int32(lay.low_w), np.int32(lay.low_h), np.int32(lay.cell),
            np.int32(lay.grid_w), np.int32(lay.grid_h),
            np.float32(gaze[0]), np.float32(gaze[1]),
        )  # fmt: skip

    # --- internals ------------------------------------------------------------------------------

    def _acuity_bank_setup(self) -> dict | None:
        """Taps and work sizes of the tiled bank (kernel acuity_bank), or None where the
        level-by-level bank is used instead: on GPUs (one work-item per tile suits a CPU only),
        when the tile's local memory would not fit, or GAZEHDR_CL_ACUITY=levels."""
        dev = self.ctx.devices[0]
        mode = os.environ.get("GAZEHDR_CL_ACUITY", "")
        if mode not in ("", "tiles", "levels"):
            raise RuntimeError(f"GAZEHDR_CL_ACUITY must be tiles or levels, got {mode!r}")
        if mode == "levels" or (not mode and dev.type & cl.device_type.GPU):
            return None
        taps = [gaussian_taps(s) for s in acuity_increments(self.p, self.lay.ppd)]
        levels = np.zeros(2 * MAX_BANDS, np.int32)
        offsets = np.cumsum([0] + [len(t) for t in taps])
        for i, t in enumerate(taps):
            levels[2 * i], levels[2 * i + 1] = len(t) // 2, offsets[i]
        halo = int(sum(len(t) // 2 for t in taps))
        tx, ty = ACUITY_TILE
        pad_x = (-(-halo // self.vec) + 1) * self.vec
        floats = 2 * (tx + 2 * pad_x) * (ty + 2 * halo) + tx * ty
        if 4 * floats > dev.local_mem_size:
            return None
        mf = cl.mem_flags
        flat = np.concatenate(taps).astype(np.float32)
        return {
            "taps": cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=flat),
            "levels": cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=levels),
            "local": cl.LocalMemory(4 * floats),
            "size": (-(-self.lay.width // tx), -(-self.lay.height // ty), 1),
            "tile": (np.int32(tx), np.int32(ty)),
        }

    # --- stages ---------------------------------------------------------------------------------

    def set_scene(self, planar: np.ndarray) -> None:
        cl.enqueue_copy(self.queue, self.buf["scene"], planar)
        self._stack.scene_changed()

    @property
    def level_stack_pending(self) -> bool:
        """`LevelStack.pending`: whether the scene's acuity will move to its level stack."""
        return self._stack.pending

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
        self.blur(b["low_yp"], blurred, b["low_tmp"], self._rho_taps, lay.low_w, lay.low_h, 1)
        self.k["rho_map"](
            self.queue, (_round_up(low, ROW_GROUP),), None, self.P, blurred, b["rho"],
            np.int32(low),
        )  # fmt: skip
        self._rho_full_stale = True
        self.rho_full()
        n = len(edge_loop(lay.low_w, lay.low_h)[0])
        tbuf, r = self._surround_taps
        self.k["surround_map"](
            self.queue, (n,), None, self.P, b["down"], b["surround"], tbuf, np.int32(r),
            np.int32(n), np.int32(lay.low_w), np.int32(lay.low_h),
        )  # fmt: skip
        if blind_spot_strength(self.p) > 0:  # reference.fill_map: L, M, S, the down's first three
            self.blur(b["down"], b["fill"], b["fill_tmp"], self._fill_taps, lay.low_w, lay.low_h, 3)

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
        args = self.grid_args(gaze)
        sigma = map_blur_sigma(dt, lay, p)
        if reset and dt > 0 and sigma > 0:
            self._settle(gaze, dt)
        else:
            blurred = not reset and sigma > 0
            target = b["grid_a"] if blurred else b["state"]
            self.k["retina_update"](
                self.queue, (*self._grid_v(), 3), None, self.P, b["down"], b["surround"],
                b["state"], target, b["A"], *args, np.float32(dt), np.int32(reset),
                np.float32(math.exp(-p.c2 * dt)),
            )  # fmt: skip
            if blurred:
                tbuf, r = self.taps_for(sigma)
                gw, gh = self._grid_v()
                self.k["retina_blur"](
                    self.queue, (gw, -(-gh // BLUR_ROWS), 9), None, b["grid_a"], b["state"],
                    tbuf, np.int32(r), np.int32(lay.grid_w), np.int32(lay.grid_h),
                    np.int32(BLUR_ROWS),
                )  # fmt: skip
        # Maps only for the cells the screen shows at this gaze; the rest waits for get("maps")
        # or a compose at another gaze (_full_maps).
        self._maps(gaze, self._screen_window(gaze))

    def _grid_v(self) -> tuple[int, int]:
        """Global size of the kernels that make VEC neighbouring cells of a grid row each."""
        return (-(-self.lay.grid_w // self.vec), self.lay.grid_h)

    def _settle(self, gaze, dt: float) -> None:
        """The state that steps of dt leave as it is (layout.settle_plan): Jacobi iterations,
        each a blur of u = R s and a pointwise update (kernels retina_settle_*)."""
        lay, b, p = self.lay, self.buf, self.p
        plan = settle_plan(dt, lay, p)
        grid_planes = lay.grid_w * lay.grid_h * 4
        s = self._settle_buf
        if not s:
            mf = cl.mem_flags
            sizes = {"rate": 3, "u": 9, "w": 9, "b": 9}
            s.update(
                {n: cl.Buffer(self.ctx, mf.READ_WRITE, k * grid_planes) for n, k in sizes.items()}
            )
            s["diag"] = cl.Buffer(self.ctx, mf.READ_WRITE, 4 * (lay.grid_w + lay.grid_h))
        cl.enqueue_copy(
            self.queue, s["diag"], np.concatenate([plan.diag_x, plan.diag_y]).astype(np.float32)
        )
        decay_c = np.float32(math.exp(-p.c2 * dt))
        self.k["retina_settle_init"](
            self.queue, self._grid_v(), None, self.P, b["down"], b["surround"], b["A"],
            *self.grid_args(gaze), np.float32(dt), decay_c, b["state"], s["rate"], s["u"], s["b"],
        )  # fmt: skip
        taps = self.taps_for(plan.sigma)
        self.blur(s["b"], s["b"], b["grid_a"], taps, lay.grid_w, lay.grid_h, 9)
        for k in range(plan.iterations):
            self.blur(s["u"], s["w"], b["grid_a"], taps, lay.grid_w, lay.grid_h, 9)
            self.k["retina_settle_step"](
                self.queue, self._grid_v(), None, b["state"], s["u"], s["w"], s["b"], s["rate"],
                decay_c, s["diag"], np.int32(lay.grid_w), np.int32(lay.grid_h),
                np.int32(k == plan.iterations - 1),
            )  # fmt: skip

    def _screen_window(self, gaze) -> Window:
        """Retina cells (j0, i0, j1, i1), inclusive, that compose reads at this gaze."""
        lay = self.lay

        def span(g: float, n_px: int, n_grid: int) -> tuple[int, int]:
            lo = math.floor((0.5 - g) / lay.cell + n_grid / 2 - 0.5) - 1  # a cell of margin
            hi = math.floor((n_px - 0.5 - g) / lay.cell + n_grid / 2 - 0.5) + 2
            return min(max(lo, 0), n_grid - 1), min(max(hi, 0), n_grid - 1)

        (j0, j1) = span(gaze[0], lay.width, lay.grid_w)
        (i0, i1) = span(gaze[1], lay.height, lay.grid_h)
        return j0, i0, j1, i1

    def _maps(self, gaze, window: Window) -> None:
        self._map_cells(gaze, window)
        self._maps_made = None if window == self._whole_grid() else (tuple(gaze), window)

    def _whole_grid(self) -> Window:
        return (0, 0, self.lay.grid_w - 1, self.lay.grid_h - 1)

    def _map_cells(self, gaze, window: Window, made: Window = NO_CELLS) -> None:
        """The maps of the cells of `window` (j0, i0, j1, i1), inclusive, except those of `made`,
        in runs of VEC cells (a run may reach past the window's sides; one inside `made` stays)."""
        b = self.buf
        self.k["afterimage_maps"](
            self.queue, self._grid_v(), None, self.P, b["down"], b["surround"], b["state"],
            b["maps"], b["A"], *self.grid_args(gaze), *(np.int32(v) for v in (*window, *made)),
        )  # fmt: skip

    def _more_maps(self, window: Window) -> None:
        """Make the maps cover `window` too (a compose at a newer gaze than the retina step's:
        `Simulator.frame(output, gaze)`, the live sessions' late gaze): the cells of the box
        around both windows not made yet, from the step's state at the step's gaze, in one
        launch. `_full_maps` is this with `window` the whole grid."""
        if self._maps_made is None:
            return
        gaze, made = self._maps_made
        box = (
            min(made[0], window[0]), min(made[1], window[1]),
            max(made[2], window[2]), max(made[3], window[3]),
        )  # fmt: skip
        if box == made:
            return
        self._map_cells(gaze, box, made)
        self._maps_made = None if box == self._whole_grid() else (gaze, box)

    def _full_maps(self) -> None:
        """Complete the afterimage maps of the last retina step (get("maps"), the warp)."""
        self._more_maps(self._whole_grid())

    def acuity(self, noise: NoiseFrame) -> None:
        lay, b = self.lay, self.buf
        self._upload_noise(noise)
        rho_full = self.rho_full()
        stack = self._stack.for_frame(self)
        by_levels = stack is None and self._bank is None
        if by_levels:
            cl.enqueue_fill_buffer(self.queue, b["d_max"], np.int32(0), 0, 4)
        self.k["acuity_levels"](
            self.queue, self.rows_v(), None, self.P, rho_full, self._noise_buf,
            np.float32(noise.spacing), np.int32(noise.key0.shape[1]),
            np.int32(lay.width), np.int32(lay.height), b["d"], b["d_max"], np.int32(by_levels),
        )  # fmt: skip
        if stack is not None:
            self.k["acuity_pick"](
                self.queue, self.rows_v(), None, stack, np.int32(self._stack.stride), b["d"],
                b["G"], np.int32(lay.width), np.int32(lay.height),
            )  # fmt: skip
            return
        if self._bank is not None:
            bank = self._bank
            self.k["acuity_bank"](
                self.queue, bank["size"], (1, 1, 1), b["scene"], b["d"], b["G"], bank["taps"],
                bank["levels"], np.int32(lay.width), np.int32(lay.height), *bank["tile"],
                bank["local"],
            )  # fmt: skip
            return
        # Level by level over the whole frame (GPUs): G starts as the scene (d = 0), each level
        # fills its pixels; levels no pixel needs are skipped, so a photopic frame costs no blur.
        self.store_G(b["scene"])
        d_max = np.empty(1, np.int32)
        cl.enqueue_copy(self.queue, d_max, b["d_max"])
        src, dst = b["scene"], b["lvl_a"]
        for level in range(int(d_max[0])):
            taps = self._acuity_taps[level]
            self.blur(src, dst, b["lvl_tmp"], taps, lay.width, lay.height, 3, level)
            src, dst = dst, (b["lvl_b"] if dst is b["lvl_a"] else b["lvl_a"])

    def _upload_noise(self, noise: NoiseFrame) -> None:
        """The two key frames mixed in time, X = ((1-f) key0 + f key1) / sqrt((1-f)^2 + f^2):
        interpolation is linear, so this is the same field the kernel would mix per pixel."""
        f = noise.frac
        mixed = (1 - f) * noise.key0.astype(np.float64) + f * noise.key1.astype(np.float64)
        mixed = np.ascontiguousarray(mixed / math.sqrt((1 - f) ** 2 + f * f), np.float32)
        if self._noise_buf is None:
            self._noise_buf = cl.Buffer(self.ctx, cl.mem_flags.READ_ONLY, mixed.nbytes)
        self._upload(self._noise_buf, mixed)

    def _upload(self, buf: cl.Buffer, host: np.ndarray) -> None:
        """Copy a frame's small host array to the device without waiting: a blocking copy
        would idle the device while the host makes the next launches. The transfer's event
        keeps `host` alive; events are let go once done (they wait for their copy when freed)."""
        self._uploads = [e for e in self._uploads if not _done(e)]
        self._uploads.append(cl.enqueue_copy(self.queue, buf, host, is_blocking=False))

    def blind_spot(self, gaze) -> None:
        """Sec. 5: the scotopic foveal blind spot, on G (reference.foveal_blind_spot)."""
        lay, b = self.lay, self.buf
        s = lay.px(self.p.rod_free_radius_deg) / math.sqrt(2 * math.log(2))
        w = self._gaussian_xy(gaze, s)
        w[: lay.width] *= blind_spot_strength(self.p)
        self._upload(b["blind_xy"], w)
        self.k["foveal_blind_spot"](
            self.queue, self.rows_v(), None, self.P, b["G"], self.rho_full(), b["fill"],
            b["blind_xy"], np.int32(lay.width), np.int32(lay.height), np.int32(lay.cell),
            np.int32(lay.low_w), np.int32(lay.low_h),
        )  # fmt: skip

    def _gaussian_xy(self, gaze, sigma: float) -> np.ndarray:
        """exp(-|x - gaze|^2 / 2 sigma^2) = f(x) f(y) at the pixel centres: W + H factors."""
        lay = self.lay
        xs = np.concatenate(
            [np.arange(lay.width) + 0.5 - gaze[0], np.arange(lay.height) + 0.5 - gaze[1]]
        )
        return np.exp(-(xs * xs) / (2.0 * sigma * sigma)).astype(np.float32)

    def wait(self) -> None:
        """Block until the device has done all that was enqueued (a step's kernels). Waiting
        only until the acuity, which no gaze changes, is left to run keeps the device busy
        through compose's launch but reads the gaze that much earlier: in bench-live at 720p,
        three runs of each in turn, 4 % more frames and 15 ms more latency at p95 (51 against
        36 ms)."""
        self.queue.finish()

    def compose(
        self,
        gaze,
        eyes: float,
        out_dtype=np.float32,
        visibility: float = 1.0,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """H×W×3 `v` as float32, or made ready to send without a pass over it in NumPy:
        out_dtype float16 gives H×W×3 half floats (round to nearest even, the same as
        `v.astype(np.float16)`), uint32 gives H×W RGB10_A2 words (`r | g << 10 | b << 20` of
        round(1023 v), the same as gazehdr.protocol's rgb10a2 encoding). The afterimage maps
        are seen with `visibility` (Sec. 5's boost) times the foveal fall-off. Into `out` when
        given (that shape and dtype; a pane of a split frame is a strided view): written there
        by the kernel where `shares_host_memory`, else read back into it."""
        lay, b = self.lay, self.buf
        kind = np.dtype(out_dtype)
        if kind not in COMPOSE_OUTPUTS:
            raise InputError(f"out_dtype must be float32, float16 or uint32, got {out_dtype!r}")
        kernel, buf_name, shape = COMPOSE_OUTPUTS[kind]
        if out is not None and (out.shape != shape(lay) or out.dtype != kind):
            raise InputError(f"out must be {shape(lay)} {kind}, got {out.shape} {out.dtype}")
        rho_full = self.rho_full()
        self._more_maps(self._screen_window(gaze))
        fovea = self._gaussian_xy(gaze, lay.px(self.p.fovea_sigma_deg))  # the foveal fall-off
        fovea[: lay.width] *= visibility
        self._upload(b["fovea"], fovea)
        direct = out is not None and out.flags.c_contiguous and self.shares_host_memory
        host_memory = cl.mem_flags.WRITE_ONLY | cl.mem_flags.USE_HOST_PTR  # `out`'s, as it is
        target = cl.Buffer(self.ctx, host_memory, hostbuf=out) if direct else b[buf_name]
        self.k[kernel](
            self.queue, self.rows_v(COMPOSE_RUNS), None,
            self.P, b["G"], rho_full, b["maps"], b["A"],
            np.int32(lay.width), np.int32(lay.height), np.int32(lay.cell),
            np.int32(lay.grid_w), np.int32(lay.grid_h),
            np.float32(gaze[0]), np.float32(gaze[1]), np.float32(eyes), b["fovea"], target,
        )  # fmt: skip
        if direct:
            read = cl.map_flags.READ
            view, _ = cl.enqueue_map_buffer(self.queue, target, read, 0, out.shape, out.dtype)
            view.base.release(self.queue)  # mapped and unmapped: `out` holds what compose wrote
            target.release()
            return out
        into = out if out is not None and out.flags.c_contiguous else np.empty(shape(lay), kind)
        cl.enqueue_copy(self.queue, into, target)
        if out is None:
            return into
        if into is not out:  # a pane of a split frame: its rows lie apart in `out`
            out[...] = into
        return out

    def warp_layers(self, eyes: float) -> tuple[np.ndarray, np.ndarray]:
        """What a late gaze warp sends (`gazehdr.warp`), made on the device: linear RGB before
        Eq. 12 as H×W×3 half floats (kernel compose_base), and the afterimage maps of the whole
        retina grid (the viewer may look anywhere before the next frame) as gain - 1 and the
        additive term, 2×grid_h×grid_w×3 half floats (kernel warp_maps). Reuses compose_half's
        buffer: call it after compose, never between."""
        lay, b = self.lay, self.buf
        self.k["compose_base"](
            self.queue, self.rows_v(), None, self.P, b["G"], self.rho_full(), b["A"],
            np.int32(lay.width), np.int32(lay.height), np.float32(eyes), b["v16"],
        )  # fmt: skip
        rgb = np.empty((lay.height, lay.width, 3), np.float16)
        cl.enqueue_copy(self.queue, rgb, b["v16"])
        self._full_maps()
        if "warp_maps" not in b:
            b["warp_maps"] = cl.Buffer(
                self.ctx, cl.mem_flags.READ_WRITE, 12 * lay.grid_w * lay.grid_h
            )
        self.k["warp_maps"](
            self.queue, (_round_up(lay.grid_w, ROW_GROUP), lay.grid_h), None, b["maps"],
            np.int32(lay.grid_w), np.int32(lay.grid_h), b["warp_maps"],
        )  # fmt: skip
        maps = np.empty((2, lay.grid_h, lay.grid_w, 3), np.float16)
        cl.enqueue_copy(self.queue, maps, b["warp_maps"])
        return rgb, maps
