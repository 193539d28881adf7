"""Display values to 10-bit Y'CbCr 4:2:0 and back: the stream encodings' colour conversion.

BT.709 weights, full range (a grey `v` keeps its level `round(1023 v)` as Y', Cb = Cr = 512),
each chroma sample from the mean of a 2×2 block. The forward conversion is integer arithmetic
on the 10-bit levels with fixed rounding, so the OpenCL kernel (`Converter`, the live path: a
1080p frame in 1.8 ms on two cores, where numpy takes ~100 ms) and the numpy reference
(`to_yuv420p10`, tests and a fallback) agree bit for bit. The inverse (`to_rgb`) is the viewer
shader's (web/renderer.js), in float.
"""

from __future__ import annotations

import threading
from functools import cache
from typing import Any

import numpy as np

#: BT.709 luma weights; Cb = (B - Y) / (2 (1 - KB)), Cr = (R - Y) / (2 (1 - KR)).
KR, KB = 0.2126, 0.0722
KG = 1.0 - KR - KB
LEVELS = 1023
CHROMA_ZERO = 512
#: The weights as 16-bit fixed point, summing to 65536 exactly so that a grey keeps its level.
CR_, CB_ = round(KR * 65536), round(KB * 65536)
CG_ = 65536 - CR_ - CB_
#: Chroma: (4·65536·(S_B - Y_S)) / (4·65536·2(1 - KB)) as a multiply and a 40-bit shift; the
#: numerator of a 2×2 block's sums (S_R, S_G, S_B ≤ 4092) times these stays within ±2^49, and
#: with 512·2^40 added it is never negative, so the shift rounds the same way everywhere.
SHIFT = 40
MUL_CB = round(2**SHIFT / (4 * 65536 * 2 * (1 - KB)))
MUL_CR = round(2**SHIFT / (4 * 65536 * 2 * (1 - KR)))
BIAS = CHROMA_ZERO * 2**SHIFT + 2 ** (SHIFT - 1)


def levels(frame: np.ndarray) -> np.ndarray:
    """H×W×3 int64 10-bit levels of a raw frame: packed rgb10a2 words, or `v` (float16 or
    float32) as round(1023 clamp(v, 0, 1)) in float32."""
    if frame.dtype == np.uint32:
        return np.stack([(frame >> s) & 1023 for s in (0, 10, 20)], -1).astype(np.int64)
    v = np.clip(np.asarray(frame, np.float32), 0, 1)
    return np.rint(v * np.float32(LEVELS)).astype(np.int64)


def to_yuv420p10(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw frame → Y' (H'×W'), Cb and Cr (H'/2×W'/2), uint16 in [0, 1023]; H' and W' are the
    frame's rounded up to even, the last row or column repeated. The reference: `Converter`
    gives the same bits."""
    q = levels(frame)
    h, w = q.shape[:2]
    q = np.pad(q, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    Y = (q[..., 0] * CR_ + q[..., 1] * CG_ + q[..., 2] * CB_ + 32768) >> 16
    s = q.reshape(q.shape[0] // 2, 2, q.shape[1] // 2, 2, 3).sum(axis=(1, 3))
    ys = s[..., 0] * CR_ + s[..., 1] * CG_ + s[..., 2] * CB_
    U = (((s[..., 2] << 16) - ys) * MUL_CB + BIAS) >> SHIFT
    V = (((s[..., 0] << 16) - ys) * MUL_CR + BIAS) >> SHIFT
    return tuple(np.clip(p, 0, LEVELS).astype(np.uint16) for p in (Y, U, V))  # type: ignore[return-value]


def to_rgb(Y: np.ndarray, U: np.ndarray, V: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The inverse, as the viewer's shader computes it: H×W×3 float32 `v` in [0, 1] of the
    frame `size` (w, h), each chroma sample spread over its 2×2 block."""
    w, h = size
    y = Y[:h, :w].astype(np.float32) / LEVELS
    cb, cr = (
        ((c.astype(np.float32) - CHROMA_ZERO) / LEVELS).repeat(2, 0).repeat(2, 1)[:h, :w]
        for c in (U, V)
    )
    r = y + 2 * (1 - KR) * cr
    b = y + 2 * (1 - KB) * cb
    g = (y - KR * r - KB * b) / KG
    return np.clip(np.stack([r, g, b], -1), 0.0, 1.0)


KERNEL = f"""
// 32-bit arithmetic where it fits (a level times a weight: < 2^26; a block's weighted sums:
// < 2^29), 64-bit only for the two chroma products.
#define CR_ {CR_}
#define CG_ {CG_}
#define CB_ {CB_}
#define MUL_CB {MUL_CB}L
#define MUL_CR {MUL_CR}L
#define BIAS {BIAS}L

int3 level_rgb10(__global const uint *in, int i) {{
    uint p = in[i];
    return (int3)(p & 1023u, (p >> 10) & 1023u, (p >> 20) & 1023u);
}}
int3 level_half(__global const half *in, int i) {{
    float3 v = clamp(vload_half3(i, in), 0.0f, 1.0f);
    return convert_int3(rint(v * 1023.0f));
}}
int weigh(int3 q) {{ return q.x * CR_ + q.y * CG_ + q.z * CB_; }}
ushort luma(int3 q) {{ return (ushort)((weigh(q) + 32768) >> 16); }}
ushort chroma(int diff, long mul) {{
    return (ushort)clamp((diff * mul + BIAS) >> {SHIFT}, 0L, 1023L);
}}

// One 2×2 block (bx, by) of the padded (even) frame; `w`, `h`: the frame's size.
#define BLOCK(name, T, LEVEL) \\
void name(__global const T *in, int w, int h, int bx, int by, __global ushort *Y, \\
          __global ushort *U, __global ushort *V) {{ \\
    int w2 = (w + 1) / 2; \\
    int3 s = (int3)(0); \\
    for (int dy = 0; dy < 2; dy++) {{ \\
        for (int dx = 0; dx < 2; dx++) {{ \\
            int x = min(2 * bx + dx, w - 1), y = min(2 * by + dy, h - 1); \\
            int3 q = LEVEL(in, y * w + x); \\
            Y[(2 * by + dy) * (2 * w2) + 2 * bx + dx] = luma(q); \\
            s += q; \\
        }} \\
    }} \\
    int ys = weigh(s); \\
    U[by * w2 + bx] = chroma((s.z << 16) - ys, MUL_CB); \\
    V[by * w2 + bx] = chroma((s.x << 16) - ys, MUL_CR); \\
}}
BLOCK(block_rgb10, uint, level_rgb10)
BLOCK(block_half, half, level_half)

// f16 frames: one work-item per block.
__kernel void yuv_from_half(__global const half *in, int w, int h, __global ushort *Y,
                            __global ushort *U, __global ushort *V) {{
    int bx = get_global_id(0), by = get_global_id(1);
    if (bx < (w + 1) / 2 && by < (h + 1) / 2) block_half(in, w, h, bx, by, Y, U, V);
}}

// rgb10a2 frames (the live default): VEC blocks a work-item (2 VEC pixels of two rows) as
// vectors, the same integer arithmetic; a row's last blocks one at a time. `Converter` at 1080p
// 0.36× as long as with a work-item per block (docs/performance.md, "The streams").
#if VEC == 16
#define EVEN(a, b) SHUFFLE2(a, b, 0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30)
#define ODD(a, b) SHUFFLE2(a, b, 1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31)
#else
#define EVEN(a, b) SHUFFLE2(a, b, 0, 2, 4, 6, 8, 10, 12, 14)
#define ODD(a, b) SHUFFLE2(a, b, 1, 3, 5, 7, 9, 11, 13, 15)
#endif
typedef CAT(long, VEC) longv;
#define TO_LONGV(x) CAT(convert_long, VEC)(x)

// The 10-bit levels of VEC words, and their Y' (as `luma`).
#define R_(p) AS_INTV((p) & 1023u)
#define G_(p) AS_INTV(((p) >> 10) & 1023u)
#define B_(p) AS_INTV(((p) >> 20) & 1023u)
inline ushortv luma_v(uintv p) {{
    return CAT(convert_ushort, VEC)((R_(p) * CR_ + G_(p) * CG_ + B_(p) * CB_ + 32768) >> 16);
}}

inline ushortv chroma_v(intv diff, long mul) {{
    longv c = (TO_LONGV(diff) * mul + BIAS) >> {SHIFT};
    return CAT(convert_ushort, VEC)(CLAMP(c, (longv)(0), (longv)(1023)));
}}

__kernel void yuv_from_rgb10(__global const uint *in, int w, int h, __global ushort *Y,
                             __global ushort *U, __global ushort *V) {{
    int bx0 = get_global_id(0) * VEC, by = get_global_id(1);
    int w2 = (w + 1) / 2;
    if (bx0 >= w2) return;
    if (2 * (bx0 + VEC) > w) {{  // the row's last blocks (and the odd column), one at a time
        for (int bx = bx0; bx < w2; ++bx) block_rgb10(in, w, h, bx, by, Y, U, V);
        return;
    }}
    intv sr = (intv)(0), sg = sr, sb = sr;  // each block's sums
    for (int dy = 0; dy < 2; dy++) {{
        __global const uint *row = in + (size_t)min(2 * by + dy, h - 1) * w + 2 * bx0;
        uintv a = LOADV_UI(row), b = LOADV_UI(row + VEC);
        __global ushort *y = Y + (size_t)(2 * by + dy) * (2 * w2) + 2 * bx0;
        STOREV_U16(y, luma_v(a));
        STOREV_U16(y + VEC, luma_v(b));
        uintv left = EVEN(a, b), right = ODD(a, b);  // each block's two columns
        sr += R_(left) + R_(right);
        sg += G_(left) + G_(right);
        sb += B_(left) + B_(right);
    }}
    intv ys = sr * CR_ + sg * CG_ + sb * CB_;
    STOREV_U16(U + (size_t)by * w2 + bx0, chroma_v((sb << 16) - ys, MUL_CB));
    STOREV_U16(V + (size_t)by * w2 + bx0, chroma_v((sr << 16) - ys, MUL_CR));
}}
"""

_ONCE = threading.Lock()


@cache
def _program() -> tuple[Any, Any, int]:
    """The kernels, built once per process in the simulator's context, on common.cl's vector
    types and loads, without fast math (so not `build_program`: the integer arithmetic and the
    one float rounding must be exact)."""
    import pyopencl as cl

    from gazehdr.sim.cl_program import build_options, kernel_source, shared_context, vector_width

    ctx = shared_context()
    vec = vector_width()
    options = [o for o in build_options(ctx, vec) if o != "-cl-fast-relaxed-math"]
    return ctx, cl.Program(ctx, kernel_source(("common.cl",)) + KERNEL).build(options), vec


class Converter:
    """`to_yuv420p10` on the OpenCL device, for frames of one size and raw encoding."""

    def __init__(self, size: tuple[int, int], dtype: np.dtype) -> None:
        import pyopencl as cl

        with _ONCE:
            ctx, program, vec = _program()
        self._cl = cl
        self.size, self.dtype = size, np.dtype(dtype)
        w, h = size
        w2, h2 = (w + 1) // 2, (h + 1) // 2
        self.queue = cl.CommandQueue(ctx)
        mf = cl.mem_flags
        per_pixel = 4 if self.dtype == np.uint32 else 6
        self._in = cl.Buffer(ctx, mf.READ_ONLY, w * h * per_pixel)
        self.planes = (
            np.empty((2 * h2, 2 * w2), np.uint16),
            np.empty((h2, w2), np.uint16),
            np.empty((h2, w2), np.uint16),
        )
        self._out = [cl.Buffer(ctx, mf.WRITE_ONLY, p.nbytes) for p in self.planes]
        name = "yuv_from_rgb10" if self.dtype == np.uint32 else "yuv_from_half"
        self._kernel = cl.Kernel(program, name)
        per_item = vec if self.dtype == np.uint32 else 1  # blocks a work-item
        self._grid = (-(-w2 // per_item), h2)

    def __call__(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The planes of `frame` (rgb10a2 words or float16 RGB), valid until the next call."""
        cl, w, h = self._cl, *self.size
        cl.enqueue_copy(self.queue, self._in, np.ascontiguousarray(frame))
        self._kernel(self.queue, self._grid, None, self._in, np.int32(w), np.int32(h), *self._out)
        for plane, buffer in zip(self.planes, self._out, strict=True):
            cl.enqueue_copy(self.queue, plane, buffer)
        self.queue.finish()
        return self.planes
