"""The simulation's internal contracts: the kernels' parameter block is Params, stages use only
what their backend's protocol declares, and the production backend does not load the NumPy
oracle."""

from __future__ import annotations

import ast
import importlib
import json
import math
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path
from typing import Generic, Protocol, TypeVar, get_type_hints

import numpy as np
import pytest

from gazehdr.sim import BACKENDS, Params, Simulator, models, simulator
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
from gazehdr.sim.layout import Layout
from gazehdr.sim.models import (
    ACUITY_MODELS,
    AFTERIMAGE_MODELS,
    AcuityStage,
    AfterimageStage,
    Models,
    OpenCLStageBackend,
    ReferenceStageBackend,
    StageBackend,
    each_beside_default,
    make_stages,
)
from gazehdr.sim.reference import ReferenceBackend


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
    derived = {"ln_K_m", "n_minus_m", "contrast_floor", "rgb2lms", "lms2rgb", "rho_i", "w_S_tone",
               "gamma_poly", "gamma_binades", "n_poly", "n_binades"}  # fmt: skip
    assert set(names) - set(PARAMS_FIELDS) == derived
    for f in shared:
        assert (f.ctype, f.count) == ANNOTATION_TYPES[PARAMS_FIELDS[f.name].type], f.name
        want = np.asarray(getattr(p, f.name), NUMPY_TYPES[f.ctype]).ravel()
        assert np.array_equal(rec[f.name].ravel(), want), f.name
    assert np.array_equal(rec["rho_i"][0], np.float32([*p.rho_i(), 0.0, 0.0]))
    assert rec["ln_K_m"][0] == np.float32(0.45 * math.log(p.plateau_K))


def test_a_params_field_of_a_type_the_block_cannot_hold_is_refused() -> None:
    with pytest.raises(TypeError, match="mikamo_reference_xy"):
        from_params("mikamo_reference_xy")
    with pytest.raises(
        ValueError, match=r"bands = 9 is outside \[1, 8\] \(acuity bands, the kernels"
    ):
        Params(bands=9)  # the block's room for band thresholds
    for name in ("gamma", "n"):  # what the kernels' polynomials for powers are fitted to
        with pytest.raises(ValueError, match=rf"{name} = 4.5 is above 4 \(the kernels' powers"):
            Params(**{name: 4.5})


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

    from gazehdr.sim.cl_program import pick_device

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


# --- what a stage may ask of its backend ----------------------------------------------------------
# Checked by running every stage against a proxy of its backend that has only the members the
# backend's protocol declares and refuses to have attributes set. Running, not reading: the
# stages reach the backend through aliases (b = self.backend), helpers and base classes, which
# an AST walk of `backend.X` would have to follow; the proxy sees every access that happens.
# The script below takes every stage through its branches (reset, scene change, gaze moves,
# eyes closed, mesopic light). A static check of the one thing running cannot see, a private
# member of another object on a path the script misses, backs it up.

PROTOCOLS: dict[str, type] = {"reference": ReferenceStageBackend, "opencl": OpenCLStageBackend}
STAGE_FILES = [
    Path(models.__file__),
    *sorted((Path(models.__file__).parent / "baselines").glob("*.py")),
]


#: (backend name, "module:Class") of every stage
STAGE_CLASSES = [
    (kind, path)
    for table in (AFTERIMAGE_MODELS, ACUITY_MODELS)
    for paths in table.values()
    for kind, path in paths.items()
]


def declared(protocol: type) -> frozenset[str]:
    """The members a Protocol declares, its bases' included: annotated attributes and methods."""
    names: set[str] = set()
    for cls in protocol.__mro__:
        if cls in (object, Protocol, Generic):
            continue
        names |= set(vars(cls).get("__annotations__", {}))
        names |= {n for n, v in vars(cls).items() if callable(v) and not n.startswith("_")}
    return frozenset(names)


class OnlyDeclared:
    """A backend as its protocol shows it to a stage: declared members only, none settable."""

    def __init__(self, backend: object, protocol: type) -> None:
        object.__setattr__(self, "_backend", backend)
        object.__setattr__(self, "_protocol", protocol)

    def __getattribute__(self, name: str) -> object:
        protocol = object.__getattribute__(self, "_protocol")
        if name not in declared(protocol):
            raise AttributeError(f"a stage used backend.{name}: {protocol.__name__} lacks it")
        return getattr(object.__getattribute__(self, "_backend"), name)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"a stage set backend.{name}; it may only use declared members")


def test_the_protocols_declare_members_and_the_proxy_keeps_to_them() -> None:
    assert {"name", "lay", "p", "get", "put", "retina", "acuity", "a"} == declared(
        ReferenceStageBackend
    )
    opencl = {"ctx", "queue", "P", "buf", "vec", "kernels", "taps_for", "blur", "rho_full",
              "rows_v", "grid_args", "store_G"}  # fmt: skip
    assert opencl == declared(OpenCLStageBackend) - declared(StageBackend)
    params = Params()
    backend = ReferenceBackend(Layout.for_frame(32, 32, params), params)
    proxy = OnlyDeclared(backend, ReferenceStageBackend)
    assert proxy.a is backend.a and proxy.lay is backend.lay
    for name in ("set_scene", "_private", "__dict__"):
        with pytest.raises(AttributeError, match=re.escape(f"backend.{name}: Reference")):
            getattr(proxy, name)
    with pytest.raises(AttributeError, match=re.escape("set backend.a;")):
        proxy.a = {}


@pytest.mark.parametrize("backend", BACKENDS)
def test_each_backend_has_every_member_of_its_protocol(backend: str) -> None:
    made = Simulator(32, 32, backend=backend)._backend
    assert sorted(n for n in declared(PROTOCOLS[backend]) if not hasattr(made, n)) == []


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("chosen", each_beside_default(), ids=str)
def test_each_stage_uses_only_what_its_backend_protocol_declares(
    monkeypatch: pytest.MonkeyPatch, backend: str, chosen: Models
) -> None:
    proxied: list[str] = []

    def make_strict_stages(
        models: Models, backend: StageBackend, seed: int
    ) -> tuple[AfterimageStage, AcuityStage]:
        proxied.append(backend.name)
        return make_stages(models, OnlyDeclared(backend, PROTOCOLS[backend.name]), seed)

    monkeypatch.setattr(simulator, "make_stages", make_strict_stages)
    sim = Simulator(64, 48, backend=backend, seed=3, afterimage=chosen.afterimage,
                    acuity=chosen.acuity)  # fmt: skip
    assert proxied == [backend]
    room = np.full((48, 64, 3), 0.01, np.float32)  # mesopic: the acuity models blur
    lamp = room.copy()
    lamp[16:32, 24:40] = 5e4
    sim.load_scene(lamp)
    script = [  # dt, gaze, eyes open, scene to switch to
        (1 / 30, (32.0, 24.0), True, None), (0.5, (32.0, 24.0), True, None),
        (1 / 30, (32.0, 24.0), True, room),  # the light goes off: Mikamo fires
        (1 / 30, (20.0, 30.0), True, None), (0.2, (20.0, 30.0), False, None),
        (1 / 30, (40.0, 20.0), True, lamp),
    ]  # fmt: skip
    for dt, gaze, eyes, scene in script:
        if scene is not None:
            sim.load_scene(scene, reset=False)
        assert np.isfinite(sim.step(dt, gaze=gaze, eyes_open=eyes)).all()


def test_stages_touch_no_private_member_of_another_object() -> None:
    found = []
    for path in STAGE_FILES:
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
            ):
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert found == []


@pytest.mark.parametrize(("kind", "path"), STAGE_CLASSES)
def test_stage_constructors_are_typed_with_a_backend_protocol(kind: str, path: str) -> None:
    module, _, name = path.partition(":")
    init = getattr(importlib.import_module(module), name).__init__
    hint = get_type_hints(init)["backend"]
    hint = hint.__bound__ if isinstance(hint, TypeVar) else hint  # a base shared by backends
    assert hint in (StageBackend, PROTOCOLS[kind]), f"{path}: backend is typed {hint}"


def test_every_parameter_has_a_symbol_unit_and_meaning() -> None:
    """The panel shows each parameter with these (server/sim/params.py, PARAM_INFO); one
    added without them, or a stale entry, fails here."""
    import dataclasses

    from gazehdr.sim.params import OURS, PARAM_INFO, param_info

    names = [f.name for f in dataclasses.fields(Params)]
    assert sorted(PARAM_INFO) == sorted(names)
    for name, info in PARAM_INFO.items():
        assert info.symbol.strip() and info.unit.strip(), name
        assert 10 <= len(info.meaning) <= 70 and "\n" not in info.meaning, (name, info.meaning)
    sent = param_info()
    assert {n for n, i in sent.items() if i["ours"]} == set(OURS)
    assert sent["A_min"] == {
        "symbol": "A_min", "unit": "log10 cd/m²", "ours": False,
        "meaning": "adaptation floor: 2 = 100 cd/m² (Sec. 2.4)",
    }  # fmt: skip
