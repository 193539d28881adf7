"""The live step against this machine's limits: a roofline line per stage for `gazehdr bench`.

Two parts. The pure part (`launch_cost`, `KERNELS`) turns one recorded kernel launch (its name,
global size and arguments, as the backend enqueued it) into the traffic and arithmetic it
needs. The measured part (`measure_roofs`, `profile_live`) measures the device's memory
bandwidth (a large copy and a triad) and arithmetic rate (an FMA kernel) on the same device and
queue, and times each kernel of a live step with OpenCL profiling events.

What is counted:

- Bytes: compulsory traffic per launch. Each buffer a kernel reads or writes counts once, at
  its allocated size (`cl.Buffer.size`, so the figure follows the backend's buffers), or at the
  part of it the launch touches where the kernel works on a window (the adaptation window, the
  retina cells the screen shows, the edge ring of the surround). A buffer read and written
  (`rw`) counts twice. Re-reads (blur taps, halos, bilinear neighbours) are not counted: a
  cache serves them.
- Flops: arithmetic per element as counted from the kernels' source and rounded (an add, a
  multiply, a compare, a division each 1; an FMA 2). Transcendentals (exp, log, pow, sqrt) are
  counted apart and not in the flops. Blur flops follow the launch's tap radius; the acuity
  bank's follow the levels each tile runs (the d map's maximum per tile), each on the box of
  the tile's pixels that need it.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

# --- pure part: what one launch moves and computes ------------------------------------------

#: Per-element flop counts from the kernels' source (see the module docstring), and
#: transcendentals per element.
RETINA_INPUT_FLOPS = 30  # bilinear LMS from down or the surround ring, with its coordinates
MAPS_FLOPS, MAPS_TRANS = RETINA_INPUT_FLOPS + 160, 32  # mapsv: gain and bleaching, per cell
RETINA_UPDATE_FLOPS, RETINA_UPDATE_TRANS = RETINA_INPUT_FLOPS + 66, 9
COMPOSE_FLOPS, COMPOSE_TRANS = 170, 5  # tone, ratio, maps bilinear, LMS gain, gamut, pow


@dataclass
class Cost:
    """One launch (or a sum of them): bytes moved, elements made, flops, transcendentals."""

    bytes: float = 0.0
    flops: float = 0.0
    trans: float = 0.0
    launches: int = 0
    kernels: list[str] = field(default_factory=list)

    def __iadd__(self, other: Cost) -> Cost:
        self.bytes += other.bytes
        self.flops += other.flops
        self.trans += other.trans
        self.launches += other.launches
        self.kernels += [k for k in other.kernels if k not in self.kernels]
        return self


def _size(buf) -> int:
    return int(buf.size)


def _edge_cells(low_w: int, low_h: int) -> int:
    return 2 * (low_w + low_h) - 4 if low_w > 1 and low_h > 1 else low_w * low_h


def _screen_window(lay, gaze) -> tuple[int, int, int, int]:
    from gazehdr.sim.opencl import OpenCLBackend

    return OpenCLBackend._screen_window(SimpleNamespace(lay=lay), gaze)


def _cells(window) -> int:
    j0, i0, j1, i1 = window
    return max(j1 - j0 + 1, 0) * max(i1 - i0 + 1, 0)


def _blur_flops(radius: int) -> int:
    return 2 * (2 * radius + 1)


def _io(name: str, a: tuple, gsize: tuple, lay, params, d_map) -> tuple[list, float, float]:
    """(accesses, flops, transcendentals) of one launch: accesses are (arg index, "r"|"w"|"rw",
    fraction of the buffer touched)."""
    low, grid = lay.low_w * lay.low_h, lay.grid_w * lay.grid_h
    edge = _edge_cells(lay.low_w, lay.low_h)
    if name == "downsample":  # P, scene, down, W, H, cell, low_w, low_h, eyes
        return [(0, "r", 1), (1, "r", 1), (2, "w", 1)], low * (3 * lay.cell**2 + 30), 0
    if name in ("blur_h", "blur_v"):  # src, dst, taps, r, w, h [, d, G, level]
        r, w, h, ch = int(a[3]), int(a[4]), int(a[5]), gsize[2]
        plane = 4 * w * h * ch
        acc = [(0, "r", plane / _size(a[0])), (1, "w", plane / _size(a[1])), (2, "r", 1)]
        if name == "blur_v" and int(a[8]) >= 0:  # an acuity level: d read, G's pixels written
            acc += [(6, "r", 1), (7, "w", 1)]
        return acc, w * h * ch * _blur_flops(r), 0
    if name == "rho_map":  # P, yp_blurred, rho, n
        return [(0, "r", 1), (1, "r", 1), (2, "w", 1)], int(a[3]) * 4, int(a[3])
    if name == "rho_upsample":  # rho, rho_full, low_w, low_h, cell, W, H
        return [(0, "r", 1), (1, "w", 1)], lay.width * lay.height * 8, 0
    if name == "surround_map":  # P, down, surround, taps, r, n, low_w, low_h
        r, n = int(a[4]), int(a[5])
        return (
            [(0, "r", 1), (1, "r", 3 * n / (5 * low)), (2, "w", n / low), (3, "r", 1)],
            n * 3 * _blur_flops(r),
            0,
        )
    if name == "adapt":  # P, down, rho, A, low_w, low_h, cell, cx, cy, sigma, x0, x1, y0, y1
        cells = (int(a[11]) - int(a[10]) + 1) * (int(a[13]) - int(a[12]) + 1)
        acc = [(0, "r", 1), (1, "r", 2 * cells / (5 * low)), (2, "r", cells / low), (3, "rw", 1)]
        return acc, cells * 14, cells
    if name == "retina_update":  # P, down, surround, state, out, A, ...
        acc = [(0, "r", 1), (1, "r", 3 / 5), (2, "r", edge / low), (3, "r", 1), (4, "w", 1)]
        acc.append((5, "r", 1))
        return acc, grid * RETINA_UPDATE_FLOPS, grid * RETINA_UPDATE_TRANS
    if name == "retina_blur":  # src, dst, taps, r, grid_w, grid_h, rows
        taps = 2 * int(a[3]) + 1  # per cell: 3 taps along its row once, then 3 down; else taps
        macs = 2 * taps if taps == 3 else taps * taps + taps  # rows of taps, then taps down
        return [(0, "r", 1), (1, "w", 1), (2, "r", 1)], grid * 9 * 2 * macs, 0
    if name == "afterimage_maps":  # P, down, surround, state, maps, A, ..., window, made
        window, made = [int(v) for v in a[-8:-4]], [int(v) for v in a[-4:]]
        both = (*map(max, window[:2], made[:2]), *map(min, window[2:], made[2:]))
        cells = _cells(window) - _cells(both)
        f = cells / grid
        acc = [(0, "r", 1), (1, "r", 3 / 5), (2, "r", edge / low), (3, "r", f), (4, "w", f)]
        return [*acc, (5, "r", 1)], cells * MAPS_FLOPS, cells * MAPS_TRANS
    if name == "acuity_levels":  # P, rho_full, noise, spacing, nw, W, H, d, d_max, flag
        px = lay.width * lay.height
        acc = [(0, "r", 1), (1, "r", 1), (2, "r", 1), (7, "w", 1)]
        if int(a[9]):
            acc.append((8, "rw", 1))
        return acc, px * 24, 0
    if name == "acuity_bank":  # scene, d, G, taps, levels, W, H, TX, TY, local
        return (
            [(0, "r", 1), (1, "r", 1), (2, "w", 1), (3, "r", 1), (4, "r", 1)],
            _bank_flops(a, lay, params, d_map),
            0,
        )
    if name == "acuity_pick":  # stack, stride, d, G, W, H
        px = lay.width * lay.height
        read = _pick_levels_read(d_map, -(-lay.width // gsize[0])) if d_map is not None else px
        level = 2 * 3 * read / _size(a[0])  # a level's pixel: three 16-bit channels
        return [(0, "r", level), (2, "r", 1), (3, "w", 1)], px * 3, 0
    if name == "lum16_encode":  # src, dst, n
        n = int(a[2])
        return [(0, "r", 4 * n / _size(a[0])), (1, "w", 2 * n / _size(a[1]))], n * 4, 0
    if name in ("compose", "compose_half", "compose_rgb10"):
        # P, G, rho_full, maps, A, W, H, cell, grid_w, grid_h, gx, gy, eyes, fovea, out
        cells = _cells(_screen_window(lay, (float(a[10]), float(a[11]))))
        acc = [(0, "r", 1), (1, "r", 1), (2, "r", 1), (3, "r", cells / grid), (4, "r", 1)]
        px = lay.width * lay.height
        return [*acc, (13, "r", 1), (14, "w", 1)], px * COMPOSE_FLOPS, px * COMPOSE_TRANS
    raise KeyError(f"no accounting for kernel {name!r}: add it to roofline._io")


def _pick_levels_read(d_map: np.ndarray, vec: int) -> int:
    """Pixels' worth of levels the pick reads (kernel acuity_pick): each whole run of `vec`
    pixels reads every level from its lowest d to its highest, the row's last pixels their own
    one each. Without a d map the roofline counts one level a pixel."""
    h, w = d_map.shape
    whole = w // vec * vec
    runs = d_map[:, :whole].reshape(h, -1, vec).astype(np.int32)
    spans = runs.max(axis=2) - runs.min(axis=2) + 1
    return int(spans.sum()) * vec + h * (w - whole)


def _bank_flops(a: tuple, lay, params, d_map) -> float:
    """The tiled bank blurs each tile through the levels up to the tile's largest d, each level
    only on the box of the tile's pixels that drop more than it and the next level's box widened
    by that level's radius (kernel acuity_bank): per pixel of that box (inside the screen) and
    channel, a horizontal and a vertical pass of the level's taps."""
    from gazehdr.sim.layout import acuity_increments, gaussian_taps

    # the bank's tap radii, as opencl._acuity_bank_setup makes them
    radii = [len(gaussian_taps(s)) // 2 for s in acuity_increments(params, lay.ppd)]
    tx, ty = int(a[7]), int(a[8])
    if d_map is None:  # every pixel at the deepest level
        d_map = np.full((lay.height, lay.width), len(radii), np.uint8)
    total = 0.0
    for y0 in range(0, lay.height, ty):
        for x0 in range(0, lay.width, tx):
            tile = d_map[y0 : y0 + ty, x0 : x0 + tx]
            box = None  # the next level's box: x0, x1, y0, y1 (inclusive)
            for level in range(min(int(tile.max()), len(radii)) - 1, -1, -1):
                ys, xs = np.nonzero(tile > level)
                own = [x0 + xs.min(), x0 + xs.max(), y0 + ys.min(), y0 + ys.max()]
                if box is not None:
                    r = radii[level + 1]
                    lo, hi = (
                        (min(own[0], box[0] - r), min(own[2], box[2] - r)),
                        (max(own[1], box[1] + r), max(own[3], box[3] + r)),
                    )
                    own = [lo[0], hi[0], lo[1], hi[1]]
                box = own
                w = min(box[1], lay.width - 1) - max(box[0], 0) + 1
                h = min(box[3], lay.height - 1) - max(box[2], 0) + 1
                total += w * h * 2 * _blur_flops(radii[level])
    return 3 * total


def launch_cost(name: str, gsize: tuple, args: tuple, lay, params, d_map=None) -> Cost:
    """Bytes, flops and transcendentals of one launch of kernel `name` with `args` (the
    arguments after queue, global and local size); `d_map` (the acuity levels dropped per
    pixel) sets the bank's levels per tile, else every tile counts the deepest level."""
    gsize = tuple(gsize) + (1,) * (3 - len(gsize))
    acc, flops, trans = _io(name, args, gsize, lay, params, d_map)
    moved = 0.0
    for i, mode, frac in acc:
        moved += _size(args[i]) * min(frac, 1.0) * (2 if mode == "rw" else 1)
    return Cost(bytes=moved, flops=float(flops), trans=float(trans), launches=1, kernels=[name])


@dataclass
class Launch:
    stage: str
    name: str
    gsize: tuple
    args: tuple
    event: object = None


class Recorder:
    """Wraps a backend's kernels: each launch is kept with its stage, arguments and event."""

    def __init__(self, backend) -> None:
        self.stage = "?"
        self.launches: list[Launch] = []
        self._orig = backend.k
        backend.k = {n: self._wrap(n, k) for n, k in backend.k.items()}
        self.backend = backend

    def _wrap(self, name: str, kernel):
        def call(queue, gsize, lsize, *args):
            ev = kernel(queue, gsize, lsize, *args)
            self.launches.append(Launch(self.stage, name, tuple(gsize), args, ev))
            return ev

        return call

    def restore(self) -> None:
        self.backend.k = self._orig


def account(launches: list[Launch], lay, params, d_map=None) -> dict[str, Cost]:
    """Cost per stage of the recorded launches (in stage order)."""
    out: dict[str, Cost] = {}
    for ln in launches:
        out.setdefault(ln.stage, Cost())
        out[ln.stage] += launch_cost(ln.name, ln.gsize, ln.args, lay, params, d_map)
    return out


# --- measured part -------------------------------------------------------------------------

ROOF_SRC = """
__kernel void copy4(__global const float4 *a, __global float4 *b) {
    size_t i = get_global_id(0); b[i] = a[i];
}
__kernel void triad4(__global const float4 *a, __global const float4 *b, __global float4 *c,
                     float s) {
    size_t i = get_global_id(0); c[i] = a[i] + s * b[i];
}
// 12 independent chains of x * m + k (contracted to FMAs by -cl-fast-relaxed-math; PoCL's
// mad() builtin is far slower than that): float8 for the implicit vectoriser across items,
// float16 run one item per group for AVX-512.
#define FMA_CHAINS(T) \
    T x0 = (T)(get_global_id(0) * 1e-9f), x1 = x0 + 1, x2 = x0 + 2, x3 = x0 + 3, x4 = x0 + 4, \
      x5 = x0 + 5, x6 = x0 + 6, x7 = x0 + 7, x8 = x0 + 8, x9 = x0 + 9, xa = x0 + 10, xb = x0 + 11; \
    for (int i = 0; i < FMA_ITERS; ++i) { F(x0) F(x1) F(x2) F(x3) F(x4) F(x5) F(x6) F(x7) \
        F(x8) F(x9) F(xa) F(xb) } \
    T s = ((x0 + x1) + (x2 + x3)) + ((x4 + x5) + (x6 + x7)) + ((x8 + x9) + (xa + xb));
#define F(x) x = x * m + k;
#define FMA_ITERS 512
__kernel void fma8(__global float *out, float m, float k) {
    FMA_CHAINS(float8)
    out[get_global_id(0)] = s.s0 + s.s7;
}
__kernel void fma16(__global float *out, float m, float k) {
    FMA_CHAINS(float16)
    out[get_global_id(0)] = s.s0 + s.sf;
}
"""
FMA_ITERS, FMA_CHAINS = 512, 12  # as in ROOF_SRC


def profiling_queue(ctx):
    import pyopencl as cl

    return cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)


def _event_s(ev) -> float:
    """A launch's time by its profiling event, at least 1 ns: a coarse device timer can read a
    short kernel as 0, and rates are divided by these times."""
    return max(ev.profile.end - ev.profile.start, 1) * 1e-9


@dataclass
class Roofs:
    copy_gbs: float  # (read + write) bytes / s of the copy, best of the repeats
    triad_gbs: float
    gflops: float
    mib: int

    @property
    def bandwidth(self) -> float:
        """The bandwidth roof in GB/s: the better of copy and triad."""
        return max(self.copy_gbs, self.triad_gbs)

    @property
    def balance(self) -> float:
        """Flops per byte where the two roofs meet."""
        return self.gflops / self.bandwidth


def measure_roofs(ctx, queue, mib: int = 256, repeats: int = 5) -> Roofs:
    """Memory bandwidth (copy and triad of `mib` MiB per array, best of `repeats`) and the FMA
    rate, on the device of `ctx` through `queue` (which must have profiling enabled)."""
    import pyopencl as cl

    prg = cl.Program(ctx, ROOF_SRC).build(options=["-cl-fast-relaxed-math"])
    n4 = mib * 2**20 // 16
    mf = cl.mem_flags
    bufs = [cl.Buffer(ctx, mf.READ_WRITE, n4 * 16) for _ in range(3)]
    for b in bufs:
        cl.enqueue_fill_buffer(queue, b, np.float32(1.0), 0, b.size)
    copy, triad = cl.Kernel(prg, "copy4"), cl.Kernel(prg, "triad4")
    best_copy = best_triad = math.inf
    for _ in range(repeats + 1):  # the first run touches the pages
        ev = copy(queue, (n4,), None, bufs[0], bufs[1])
        ev.wait()
        best_copy = min(best_copy, _event_s(ev))
        ev = triad(queue, (n4,), None, bufs[0], bufs[1], bufs[2], np.float32(0.5))
        ev.wait()
        best_triad = min(best_triad, _event_s(ev))
    best_fma = 0.0  # GFLOP/s, the better of the two FMA kernels
    for name, lanes, local in (("fma8", 8, None), ("fma16", 16, (1,))):
        items = (1 << 17) // lanes
        out = cl.Buffer(ctx, mf.WRITE_ONLY, 4 * items)
        kernel = cl.Kernel(prg, name)
        for _ in range(repeats + 1):
            ev = kernel(queue, (items,), local, out, np.float32(0.999), np.float32(1e-3))
            ev.wait()
            flops = items * lanes * FMA_ITERS * FMA_CHAINS * 2
            best_fma = max(best_fma, flops / _event_s(ev) / 1e9)
    del bufs
    return Roofs(
        copy_gbs=2 * n4 * 16 / best_copy / 1e9,
        triad_gbs=3 * n4 * 16 / best_triad / 1e9,
        gflops=best_fma,
        mib=mib,
    )


LIVE_STAGES = ("adapt", "retina", "acuity", "blind_spot", "compose")


def to_steady_acuity(sim) -> None:
    """Run the acuity stage until a scene that stays has moved to its level stack
    (`OpenCLBackend.level_stack_pending`): the steady state that a benchmark of a still
    scene should time, not the frames before it."""
    b = sim._backend
    while getattr(b, "level_stack_pending", False):
        b.acuity(sim._noise.at(0.0))


def profile_live(sim, frames: int, dt: float, out_dtype=np.float32) -> tuple[dict, dict, dict]:
    """A live step's stages (the scene maps kept, as `Simulator.step` does once a scene is
    loaded; `prepare` too, for reference), each kernel timed by its profiling event.

    Returns (cost per stage, median kernel seconds per stage, median wall seconds per stage).
    The simulator's backend gets a profiling queue for the run and keeps it."""
    from gazehdr.sim.layout import blind_spot_strength

    b, lay, p = sim._backend, sim.layout, sim.params
    to_steady_acuity(sim)
    b.queue = profiling_queue(b.ctx)
    rec = Recorder(b)
    gazes = [
        (lay.width * (0.3 + 0.4 * (i % 3) / 2), lay.height * (0.4 + 0.2 * (i % 2)))
        for i in range(frames + 2)
    ]
    kernel_s: dict[str, list[float]] = {}
    wall_s: dict[str, list[float]] = {}
    costs: dict[str, Cost] = {}
    try:
        for i, gaze in enumerate(gazes):
            rec.launches.clear()
            noise = sim._noise.at(i * dt)
            stages = [("prepare", lambda: b.prepare(1.0))]
            stages += [
                ("adapt", lambda g=gaze: b.adapt(g, dt, False)),
                ("retina", lambda g=gaze: sim._afterimage.retina(g, dt, False)),
                ("acuity", lambda n=noise: b.acuity(n)),
            ]
            if blind_spot_strength(p) > 0:
                stages.append(("blind_spot", lambda g=gaze: b.blind_spot(g)))
            stages.append(("compose", lambda g=gaze: b.compose(g, 1.0, out_dtype)))
            walls = {}
            for stage, fn in stages:
                rec.stage = stage
                t0 = time.perf_counter()
                fn()
                b.queue.finish()
                walls[stage] = time.perf_counter() - t0
            if i < 2:  # warm-up
                continue
            d_map = b.get("d")
            costs = account(rec.launches, lay, p, d_map)
            per: dict[str, float] = {}
            for ln in rec.launches:
                per[ln.stage] = per.get(ln.stage, 0.0) + _event_s(ln.event)
            for stage, s in per.items():
                kernel_s.setdefault(stage, []).append(s)
                wall_s.setdefault(stage, []).append(walls[stage])
    finally:
        rec.restore()
    med = {k: statistics.median(v) for k, v in kernel_s.items()}
    wall = {k: statistics.median(v) for k, v in wall_s.items()}
    return costs, med, wall


def table(costs: dict[str, Cost], kernel_s: dict, wall_s: dict, roofs: Roofs, pixels: int):
    """The roofline lines: one per stage, then the live step's total (without prepare)."""
    bw, peak = roofs.bandwidth, roofs.gflops
    head = (
        f"  {'stage':<11}{'ms':>7}{'wall':>7}{'MB':>8}{'B/px':>7}{'flop/px':>8}{'tr/px':>6}"
        f"{'GB/s':>7}{'%bw':>6}{'GFLOP/s':>8}{'%fma':>6}{'flop/B':>7}  bound"
    )
    lines = [head]
    total, tk, tw = Cost(), 0.0, 0.0

    def line(name: str, c: Cost, ks: float, ws: float) -> str:
        gbs, gfl = c.bytes / ks / 1e9, c.flops / ks / 1e9
        ai = c.flops / max(c.bytes, 1.0)
        # time each roof allows, and which is the larger
        t_mem, t_fma = c.bytes / (bw * 1e9), c.flops / (peak * 1e9)
        bound = "memory" if t_mem >= t_fma else "compute"
        floor = max(t_mem, t_fma)
        return (
            f"  {name:<11}{ks * 1e3:>7.2f}{ws * 1e3:>7.2f}{c.bytes / 1e6:>8.2f}"
            f"{c.bytes / pixels:>7.1f}{c.flops / pixels:>8.0f}{c.trans / pixels:>6.1f}"
            f"{gbs:>7.1f}{100 * gbs / bw:>6.1f}{gfl:>8.1f}{100 * gfl / peak:>6.1f}{ai:>7.2f}"
            f"  {bound} (roof {floor * 1e3:.2f} ms, {floor / ks * 100:.0f}% of it)"
        )

    for stage in ("prepare", *LIVE_STAGES):
        if stage not in costs:
            continue
        c, ks, ws = costs[stage], kernel_s[stage], wall_s[stage]
        lines.append(line(stage, c, ks, ws))
        if stage != "prepare":
            total += c
            tk += ks
            tw += ws
    lines.append(line("live step", total, tk, tw))
    return lines


def roofs_line(roofs: Roofs) -> str:
    return (
        f"  roofs: copy {roofs.copy_gbs:.1f} GB/s, triad {roofs.triad_gbs:.1f} GB/s "
        f"({roofs.mib} MiB arrays, best of 5), FMA {roofs.gflops:.1f} GFLOP/s; "
        f"balance {roofs.balance:.1f} flop/B"
    )
