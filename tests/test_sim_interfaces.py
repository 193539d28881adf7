"""The simulation's internal contracts: the kernels' parameter block is Params, and the
production backend does not load the NumPy oracle."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from importlib import resources

import numpy as np
import pytest

from gazehdr.sim.kernel_params import (
    ANNOTATION_TYPES,
    FIELDS,
    NUMPY_TYPES,
    PARAMS_DTYPE,
    PARAMS_FIELDS,
    from_params,
    pack_params,
    params_struct,
)
from gazehdr.sim.params import Params


def test_opencl_simulator_runs_without_the_numpy_oracle() -> None:
    """reference.py is the oracle the kernels are tested against, not a library: importing the
    OpenCL backend and the simulator, and stepping an OpenCL simulator with the default stages,
    must not load it. Checked in a fresh interpreter (this one has it loaded already)."""
    code = (
        "import json, sys\n"
        "import gazehdr.sim.opencl, gazehdr.sim.simulator\n"
        "from gazehdr.sim import Simulator\n"
        "Simulator(64, 48, backend='opencl').step(0.1)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('gazehdr.'))))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = json.loads(run.stdout.splitlines()[-1])
    assert "gazehdr.sim.opencl" in loaded  # the check ran the OpenCL path
    assert "gazehdr.sim.reference" not in loaded


# --- the kernels' parameter block, generated from Params ----------------------------------------


def test_block_fields_named_after_params_carry_their_values() -> None:
    """A block field named after a Params field has that field's type, length and value (in
    float32 / int32), so a kernel's P->name is Params.name; the derived ones are not named
    after a Params field, which they would shadow."""
    p = Params(n=0.9, b1=(1e-3, 2e-4, 3e-7), H=((1, 2, 3), (4, 5, 6), (7, 8, 9)), bands=6)
    rec = pack_params(p)
    names = [f.name for f in FIELDS]
    assert len(set(names)) == len(names)
    assert list(PARAMS_DTYPE.names) == names
    shared = [f for f in FIELDS if f.name in PARAMS_FIELDS]
    assert len(shared) == 20  # every field but the six derived ones
    for f in shared:
        assert (f.ctype, f.count) == ANNOTATION_TYPES[PARAMS_FIELDS[f.name].type], f.name
        want = np.asarray(getattr(p, f.name), NUMPY_TYPES[f.ctype]).ravel()
        assert np.array_equal(rec[f.name].ravel(), want), f.name
    assert np.array_equal(rec["rho_i"][0], np.float32([*p.rho_i(), 0.0, 0.0]))
    assert rec["ln_K_m"][0] == np.float32(0.45 * math.log(p.plateau_K))


def test_a_params_field_of_a_type_the_block_cannot_hold_is_refused() -> None:
    with pytest.raises(TypeError, match="mikamo_reference_xy"):
        from_params("mikamo_reference_xy")
    with pytest.raises(ValueError, match="at most 8 acuity bands"):
        pack_params(Params(bands=9))


def test_no_kernel_file_declares_params_t_by_hand() -> None:
    """The struct is generated (kernel_params.params_struct); a second, hand-written one would
    be the copy that drifts."""
    kernels = resources.files("gazehdr.sim") / "kernels"
    for cl_file in kernels.iterdir():
        if cl_file.name.endswith(".cl"):
            assert "} params_t;" not in cl_file.read_text(), cl_file.name


def test_the_compiler_lays_out_params_t_as_the_numpy_record() -> None:
    """The device reads every field of the generated struct back as raw words: each must sit at
    the offset PARAMS_DTYPE gives it (no padding, same order, 4-byte types), and sizeof must
    match. Word i of the record holds i + 1, so any shift shows."""
    import pyopencl as cl

    from gazehdr.sim.opencl import pick_device

    reads = [
        f"out[k++] = as_uint(P->{f.name}{f'[{i}]' if f.count > 1 else ''});"
        for f in FIELDS
        for i in range(f.count)
    ]
    source = params_struct() + (
        "__kernel void read_back(__constant const params_t *P, __global uint *out) {\n"
        "    int k = 0;\n    " + "\n    ".join(reads) + "\n"
        "    out[k] = (uint)sizeof(params_t);\n}\n"
    )
    ctx = cl.Context([pick_device()])
    queue = cl.CommandQueue(ctx)
    words = np.arange(1, PARAMS_DTYPE.itemsize // 4 + 1, dtype=np.uint32)
    mf = cl.mem_flags
    block = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=words)
    out = np.zeros(len(words) + 1, np.uint32)
    out_buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    cl.Program(ctx, source).build().read_back(queue, (1,), None, block, out_buf)
    cl.enqueue_copy(queue, out, out_buf)
    assert out[-1] == PARAMS_DTYPE.itemsize
    assert np.array_equal(out[:-1], words)
