"""G's 16 bits (gazehdr/sim/lum16.py, kernels/common.cl's to_lum16v and from_lum16v): within
2^-11 of every value in its range on the host, and the kernels' codes and values bit for bit
the host's, the vector and the one-at-a-time paths (a row's end) both."""

from __future__ import annotations

from functools import cache

import numpy as np
import pyopencl as cl

from gazehdr.sim import lum16
from gazehdr.sim.cl_program import build_options, kernel_source, shared_context, vector_width

DECODE = """
__kernel void lum16_decode(__global const ushort *src, __global float *dst, int n) {
    int i = get_global_id(0) * VEC;
    if (i >= n) return;
    if (i + VEC <= n) {
        STOREV_G(dst + i, lum16v_row(src, i, n));
        return;
    }
    for (int k = i; k < n; ++k) dst[k] = from_lum16(src[k]);
}
"""


def values(rng: np.random.Generator) -> np.ndarray:
    """Every binade from below the range to above it, and its edges, 0 and negatives."""
    x = np.exp(rng.uniform(np.log(1e-12), np.log(1e12), 20000))
    edges = [lum16.SMALLEST, lum16.LARGEST, 2.0**-30, 2.0**34, 1e10, 1.0, 1 + 2**-11, -0.0]
    return np.concatenate([[0.0, -1.0, -1e-20], edges, x]).astype(np.float32)


def test_within_its_precision_over_its_range_zero_below_and_capped_above() -> None:
    x = values(np.random.default_rng(1)).astype(np.float64)
    back = lum16.decode(lum16.encode(x)).astype(np.float64)
    inside = (x >= lum16.SMALLEST) & (x <= lum16.LARGEST)
    assert inside.sum() > 10000
    assert (np.abs(back - x)[inside] <= lum16.PRECISION * x[inside]).all()
    assert (back[x < 2.0**-30] == 0).all()  # below the range, and 0 and negatives: black
    assert (back[x > lum16.LARGEST] == np.float32(lum16.LARGEST)).all()
    assert lum16.LARGEST > 1e10  # Params.radiance_max fits
    codes = lum16.encode(np.sort(x))
    assert (np.diff(codes.astype(int)) >= 0).all()  # order kept


@cache
def _program() -> cl.Program:
    ctx = shared_context()
    return cl.Program(ctx, kernel_source(("common.cl",)) + DECODE).build(build_options(ctx))


def test_the_kernels_code_and_decode_as_the_host_bit_for_bit() -> None:
    ctx = shared_context()
    queue = cl.CommandQueue(ctx)
    x = values(np.random.default_rng(2))
    n = x.size - 5  # a tail of fewer than VEC values goes one at a time
    mf = cl.mem_flags
    src = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    codes = cl.Buffer(ctx, mf.READ_WRITE, 2 * x.size)
    back = cl.Buffer(ctx, mf.WRITE_ONLY, 4 * x.size)
    vec = vector_width()
    items = (-(-n // vec),)
    cl.Kernel(_program(), "lum16_encode")(queue, items, None, src, codes, np.int32(n))
    cl.Kernel(_program(), "lum16_decode")(queue, items, None, codes, back, np.int32(n))
    got_codes, got = np.empty(x.size, np.uint16), np.empty(x.size, np.float32)
    cl.enqueue_copy(queue, got_codes, codes)
    cl.enqueue_copy(queue, got, back)
    assert n % vec != 0
    assert np.array_equal(got_codes[:n], lum16.encode(x[:n]))
    assert np.array_equal(got[:n].view(np.uint32), lum16.decode(got_codes[:n]).view(np.uint32))
