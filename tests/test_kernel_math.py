"""The kernels' own transcendentals to display precision (kernels/common.cl: log2_shown8,
exp2_shown8, pow8_unit, tone8_shown), run on the OpenCL device against float64 NumPy, over
every binade they take: compose's gamma and tone curve rest on them."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pyopencl as cl
import pytest

from gazehdr.sim.kernel_params import pack_params, params_struct, plateau_m
from gazehdr.sim.opencl import build_options, shared_context
from gazehdr.sim.params import Params

KERNEL = """
__kernel void shown(__constant const params_t *P, __global const float *x,
                    __global const float *z, float lsn, __global float *out) {
    int i = get_global_id(0) * 8;
    float8 v = LOAD8_G(x + i);
    STORE8_G(out + i, log2_shown8(MAX(v, FLT_MIN)));
    STORE8_G(out + i + get_global_size(0) * 8, pow8_unit(v, P->gamma));
    STORE8_G(out + i + 2 * get_global_size(0) * 8, tone8_shown(P, lsn, v));
    STORE8_G(out + i + 3 * get_global_size(0) * 8, tone8(P, lsn, v));
    STORE8_G(out + i + 4 * get_global_size(0) * 8, exp2_shown8(LOAD8_G(z + i)));
}
"""


def run(x: np.ndarray, lsn: float, p: Params) -> np.ndarray:
    """log2_shown8(x), pow8_unit(x, gamma), tone8_shown and tone8 at x, and exp2_shown8 at
    z = -126 + 252 x (float32)."""
    ctx = shared_context()
    common = (resources.files("gazehdr.sim") / "kernels" / "common.cl").read_text()
    prg = cl.Program(ctx, "\n".join([params_struct(), common, KERNEL])).build(build_options(ctx))
    queue = cl.CommandQueue(ctx)
    mf = cl.mem_flags
    xs = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    zs = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=exp2_inputs(x))
    P = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pack_params(p))
    out = np.empty((5, x.size), np.float32)
    buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    prg.shown(queue, (x.size // 8,), None, P, xs, zs, np.float32(lsn), buf)
    cl.enqueue_copy(queue, out, buf)
    return out.astype(np.float64)


def exp2_inputs(x: np.ndarray) -> np.ndarray:
    return np.float32(-126.0) + np.float32(252.0) * x


@pytest.fixture(scope="module")
def unit() -> np.ndarray:
    """Floats in [0, 1]: 0, every binade down to the smallest normal, a fine linear ramp, 1."""
    x = np.concatenate([[0.0, 1.0], np.geomspace(1.2e-38, 1.0, 40_000), np.linspace(0, 1, 40_006)])
    return x.astype(np.float32)


def test_display_gamma_within_a_tenth_of_a_10_bit_step(unit: np.ndarray) -> None:
    p = Params()
    log2, gamma, _, _, exp2 = run(unit, 0.0, p)
    x = unit.astype(np.float64)
    on = x > 0
    assert np.abs(log2[on] - np.log2(x[on])).max() < 3.5e-5
    z = exp2_inputs(unit).astype(np.float64)
    assert (np.abs(exp2 / 2.0**z - 1) < 3.5e-6).all()
    exact = x**p.gamma
    assert np.abs(gamma - exact).max() < 1.2e-5  # a 10-bit step: 1/1023 = 9.8e-4
    assert (np.abs(gamma[on] / exact[on] - 1) < 1.5e-5).all()
    assert gamma[x == 0].max() == 0.0 and (gamma[x == 1] == 1.0).all()  # black and white kept


def test_display_tone_curve_follows_the_model_tone_curve(unit: np.ndarray) -> None:
    """tone8_shown (compose) against tone8 (the retina's) and the exact Naka-Rushton curve, at
    luminances from 1e-6 to 1e8 cd/m^2 and adaptation levels from the floor to a sunlit scene."""
    p = Params()
    lum = np.geomspace(1e-6, 1e8, unit.size // 8 * 8).astype(np.float32)
    for A in (np.log10(100.0), 3.0, 5.0):
        m = plateau_m(p)
        lsn = (p.n - m) * A * np.log(10) + m * np.log(p.plateau_K)  # sigma^n = I^(n-m) K^m
        _, _, shown, model, _ = run(lum, lsn, p)
        exact = 1 / (1 + np.exp(lsn - p.n * np.log(lum.astype(np.float64))))
        assert (np.abs(shown / exact - 1) < 2e-5).all()
        assert (np.abs(shown / model - 1) < 2e-5).all()
