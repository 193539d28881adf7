"""The process's one OpenCL context and the kernels' programs: which device, the build
options and the width the kernels are built for, and how a kernel is launched. Apart from the
backend (opencl.py) because its stages, the baseline models' stages (models.py) and the
streams' converters (gazehdr.yuv) all build and launch on it."""

from __future__ import annotations

import os
import threading
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pyopencl as cl

from gazehdr.sim.kernel_params import params_struct
from gazehdr.sim.pocl_cpu import (
    builds_for_avx512,
    name_cpu_for_pocl,
    one_build_per_kernel,
    pin_pocl_workers,
)


def pick_device() -> cl.Device:
    """GAZEHDR_CL_DEVICE if set, else the first GPU, else the first device of any kind."""
    name_cpu_for_pocl()  # before PoCL sets up its devices
    pin_pocl_workers()
    one_build_per_kernel()
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


#: Sessions (and the streams' converters, gazehdr.yuv) start on threads of their own,
#: several at once: without it, each first caller of `shared_context` would make a context of
#: its own (functools.cache does not hold others back), and a program built on one would meet
#: buffers of another (INVALID_CONTEXT).
_ONCE = threading.RLock()


def shared_context() -> cl.Context:
    """The one OpenCL context of this process."""
    with _ONCE:
        return _make_context()


@cache
def _make_context() -> cl.Context:
    return cl.Context([pick_device()])


def build_program(files: tuple[str, ...], vec: int | None = None) -> cl.Program:
    """`kernels/` files built as one program for `vec` pixels per work-item (vector_width()
    when None), once per process: building takes seconds on PoCL. A baseline model builds
    common.cl plus its own file, so the default pipeline does not pay for models it does not
    run. The parameter block `params_t` comes first, generated from `Params`
    (kernel_params.py)."""
    with _ONCE:
        return _build_program(files, tuple(build_options(shared_context(), vec)))


@cache
def _build_program(files: tuple[str, ...], options: tuple[str, ...]) -> cl.Program:
    return cl.Program(shared_context(), kernel_source(files)).build(options=list(options))


def kernel_source(files: tuple[str, ...], changed: Path | None = None) -> str:
    """The program text of `kernels/` files: `params_t` first, then the files in order; a file
    that the folder `changed` holds is read from there instead (gazehdr.bench.ab)."""
    pkg = resources.files("gazehdr.sim") / "kernels"
    texts = [
        (changed / n if changed is not None and (changed / n).is_file() else pkg / n).read_text()
        for n in files
    ]
    return "\n".join([params_struct(), *texts])


def build_options(ctx: cl.Context, vec: int | None = None) -> list[str]:
    """The compiler options of every program of the kernels, for `vec` pixels per work-item
    (vector_width() when None). GAZEHDR_CL_PORTABLE=1 builds them on PoCL as other OpenCL
    implementations (GPUs) do, with the builtins in place of PoCL's clang and x86 ones: slow,
    for the tests of that code."""
    # -cl-kernel-arg-info: each launch's by-value argument types (`Launch`) from the kernels
    options = ["-cl-fast-relaxed-math", "-cl-kernel-arg-info", f"-DVEC={vec or vector_width()}"]
    if _is_pocl(ctx) and not os.environ.get("GAZEHDR_CL_PORTABLE"):
        options.append("-DGAZEHDR_POCL")  # see kernels/common.cl
    return options


def _is_pocl(ctx: cl.Context) -> bool:
    return "Portable Computing Language" in ctx.devices[0].platform.name


VECTOR_WIDTHS = (8, 16)


def vector_width() -> int:
    """Pixels per work-item of the per-pixel kernels and blurs (VEC in kernels/common.cl):
    GAZEHDR_VEC if set, else 16 where PoCL builds for AVX-512 (one float16 register: the live
    step 0.78× as long as with 8 at 1280x720), else 8. GPUs take 8 (a float8 per thread)."""
    wanted = os.environ.get("GAZEHDR_VEC", "").strip()
    if not wanted:
        return native_width()
    if wanted not in {str(w) for w in VECTOR_WIDTHS}:
        raise RuntimeError(f"GAZEHDR_VEC={wanted!r}: pixels per work-item are 8 or 16")
    return int(wanted)


@cache
def native_width() -> int:
    """16 where PoCL builds for AVX-512 (X86_AVX512 in kernels/common.cl, unless
    GAZEHDR_CL_PORTABLE), else 8."""
    ctx = shared_context()
    return 16 if _is_pocl(ctx) and builds_for_avx512(ctx) else 8


class Launch:
    """A kernel that the device starts on as soon as it is enqueued. PoCL starts queued work at
    a flush or a blocking call, else only a while later (0.6 ms for a lone kernel here): a
    step's first kernels waited until the host had enqueued them all (about 1 ms of Python at
    1280x720). Flushed at each launch, bench-live made 1.02-1.14x the frames at 1280x720 and
    1.03-1.04x at 1920x1080 (docs/performance.md). Its by-value arguments are packed as
    the kernel declares them (`_declare_scalars`). Called as a `cl.Kernel` is:
    `launch(queue, global_size, local_size, *args)`."""

    __slots__ = ("kernel",)

    def __init__(self, kernel: cl.Kernel) -> None:
        self.kernel = kernel
        _declare_scalars(kernel)

    def __call__(self, queue: cl.CommandQueue, *args: Any) -> cl.Event:
        event = self.kernel(queue, *args)
        queue.flush()
        return event


#: OpenCL C's scalar types, as a kernel's argument info names them, in NumPy.
_SCALARS = {
    "char": np.int8, "uchar": np.uint8, "short": np.int16, "ushort": np.uint16,
    "int": np.int32, "uint": np.uint32, "long": np.int64, "ulong": np.uint64,
    "float": np.float32, "double": np.float64,
}  # fmt: skip


def _declare_scalars(kernel: cl.Kernel) -> None:
    """Give pyopencl the types of `kernel`'s by-value arguments, read from the kernel itself
    (built with -cl-kernel-arg-info): a launch then packs them at once, where pyopencl first
    tries each argument as a memory object and falls back through a C++ exception. Setting
    compose's 15 arguments took 85-91 us that way, 2 us declared, on the step's thread with
    the GIL held (docs/performance.md). A kernel without argument info, or with a
    by-value type not in _SCALARS, is launched as pyopencl does by default."""
    info, private = cl.kernel_arg_info, cl.kernel_arg_address_qualifier.PRIVATE
    dtypes: list[Any] = []
    try:
        for i in range(kernel.num_args):
            by_value = kernel.get_arg_info(i, info.ADDRESS_QUALIFIER) == private
            dtypes.append(_SCALARS[kernel.get_arg_info(i, info.TYPE_NAME)] if by_value else None)
    except (cl.Error, KeyError):
        return
    kernel.set_scalar_arg_dtypes(dtypes)
