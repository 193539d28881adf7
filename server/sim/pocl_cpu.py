"""PoCL on the CPU: its CPU named where its LLVM cannot, so that kernels build on new CPUs
(and use the AVX-512 they have), its worker threads pinned (`pin_pocl_workers`), and each
kernel built once for every work-group size (`one_build_per_kernel`).

pyopencl's wheels bundle PoCL 3.0 built on LLVM 14, which cannot name CPUs newer than itself
(AMD family 1Ah, Zen 5, among them): `llvm::sys::getHostCPUName()` answers "generic", PoCL passes
`-target-cpu generic` to its clang, and clang 14 refuses it, so every kernel build fails with
"unknown target CPU 'generic'" (pocl/pocl#1049). PoCL 3.0 has no setting for the name and filters
`-target-cpu` out of build options.

So, before PoCL sets up its devices and only when it would say "generic", LLVM's
`getHostCPUName` is made to answer the x86-64 micro-architecture level (x86-64-v2/-v3/-v4,
known to LLVM since 12) that this CPU's flags satisfy: kernels are built for features the CPU
has. The same where LLVM 14 names an older CPU without AVX-512 than this one, which has it: AMD
Zen 4 is "znver3" to it (it knows no znver4), and the kernels would miss AVX-512, with which
the live step is 0.78× as long at 1280x720 (16 pixels a work-item, cl_program.vector_width).
`GAZEHDR_POCL_CPU` names an LLVM CPU to use instead, on any CPU (e.g. `znver3`).
The patch is the function's first 16 bytes: `movabs rax, name; mov edx, len; ret`, the
StringRef it returns in rax:rdx. It is made only to the PoCL build it was written against
(checked by its code bytes), and checked by asking PoCL again.
"""

from __future__ import annotations

import ctypes
import mmap
import os
import platform
import re
import struct
from functools import cache
from pathlib import Path

import numpy as np
import pyopencl as cl

# x86-64 psABI levels, each adding to the one before, with flags as /proc/cpuinfo names them
# (abm is LZCNT).
LEVELS = (
    ("x86-64-v2", {"cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3"}),
    ("x86-64-v3", {"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"}),
    ("x86-64-v4", {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}),
)
# pocl_get_llvm_cpu_name in PoCL 3.0: push rbp; push rbx; sub rsp, 8; call getHostCPUName
PROLOGUE = bytes.fromhex("5553 4883ec08 e8")
# The CPUs LLVM 14 knows without AVX-512 that it takes newer ones with AVX-512 for.
NAMES_WITHOUT_AVX512 = frozenset({"znver1", "znver2", "znver3"})
_NAME_RE = re.compile(r"[a-z0-9][a-z0-9_.-]{0,63}")
_keep: list[ctypes.Array] = []  # the name the patched function returns must outlive it


def level_for_flags(flags: set[str]) -> str:
    """The highest x86-64 level whose features are all in `flags`."""
    level = "x86-64"
    for name, needs in LEVELS:
        if not needs <= flags:
            break
        level = name
    return level


def better_name(llvm_name: str, flags: set[str]) -> str | None:
    """The CPU name to give PoCL where LLVM's answer `llvm_name` misses what `flags` (this CPU's,
    /proc/cpuinfo) can do; None where it is right."""
    level = level_for_flags(flags)
    misses_avx512 = level == "x86-64-v4" and llvm_name in NAMES_WITHOUT_AVX512
    return level if llvm_name == "generic" or misses_avx512 else None


def cpu_flags(cpuinfo: str) -> set[str]:
    """The first `flags` line of /proc/cpuinfo as a set."""
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "flags":
            return set(value.split())
    return set()


def _bundled_pocl() -> Path | None:
    """pyopencl's own libpocl (its wheels ship one beside an ICD file), or None."""
    import pyopencl

    libs = Path(pyopencl.__file__).parent / ".libs"
    icd = libs / "pocl.icd"
    if not icd.is_file():
        return None
    lib = libs / icd.read_text().strip()
    return lib if lib.is_file() else None


def _ask(fn: ctypes._CFuncPtr) -> str:
    libc = ctypes.CDLL(None)
    libc.free.argtypes = [ctypes.c_void_p]
    ptr = fn()
    try:
        return ctypes.string_at(ptr).decode()
    finally:
        libc.free(ptr)


def _patch(target: int, name: str) -> None:
    buf = ctypes.create_string_buffer(name.encode())
    _keep.append(buf)
    stub = (
        b"\x48\xb8" + struct.pack("<Q", ctypes.addressof(buf))  # movabs rax, name
        + b"\xba" + struct.pack("<I", len(name))  # mov edx, len
        + b"\xc3"  # ret
    )  # fmt: skip
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    page = target & ~(mmap.PAGESIZE - 1)
    length = target + len(stub) - page
    rw, rx = mmap.PROT_READ | mmap.PROT_WRITE, mmap.PROT_READ | mmap.PROT_EXEC
    if libc.mprotect(page, length, rw) != 0:
        raise OSError(ctypes.get_errno(), "mprotect")
    ctypes.memmove(target, stub, len(stub))
    if libc.mprotect(page, length, rx) != 0:
        raise OSError(ctypes.get_errno(), "mprotect")


@cache
def pin_pocl_workers() -> None:
    """Before PoCL sets up its devices: each of its worker threads on a core of its own
    (POCL_AFFINITY=1), unless POCL_AFFINITY is set already. The live server's own threads
    (sockets, the step's host side) preempt the workers; unpinned, the scheduler then moves
    them between cores and they lose their caches. Measured with bench-live at 1280x720
    (uncapped, socket client, nine pairs of runs in turn): 1.02-1.19x the frames pinned, 1.10
    at the median (docs/performance.md). POCL_AFFINITY=0 leaves them unpinned. Not in a
    process held to some of the cores (taskset, a cpuset): PoCL pins to cores 0..n-1 whatever
    the process may use, and would take a core the process was kept off."""
    if "POCL_AFFINITY" in os.environ:
        return
    if hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) < (os.cpu_count() or 1):
        return
    os.environ["POCL_AFFINITY"] = "1"


def one_build_per_kernel() -> None:
    """Before PoCL sets up its devices: kernels built once for any work-group size
    (POCL_WORK_GROUP_SPECIALIZATION=0), unless the variable is set already. PoCL otherwise
    builds every kernel again for each local size it picks, and it picks them from the global
    size: each new frame size (a viewer's window resized, a split view, a test's frame) cost
    0.4-2.9 s of builds before its first frame, and the test suite built 711 kernels where 99
    (one each) do. The live step is the same either way (gazehdr bench, in turn:
    docs/performance.md); the kernels make VEC pixels a work-item themselves, which is what
    specialising for the local size would vectorise."""
    os.environ.setdefault("POCL_WORK_GROUP_SPECIALIZATION", "0")


def name_cpu_for_pocl() -> str | None:
    """Before the first `cl.get_platforms()`: give PoCL a CPU name if it needs one.

    Returns the name given, or None when nothing was changed (PoCL knows the CPU, or this is
    not pyopencl's bundled PoCL on Linux x86-64)."""
    wanted = os.environ.get("GAZEHDR_POCL_CPU", "").strip()
    if wanted and not _NAME_RE.fullmatch(wanted):
        raise RuntimeError(f"GAZEHDR_POCL_CPU={wanted!r} is not an LLVM CPU name")
    if platform.system() != "Linux" or platform.machine() != "x86_64":
        return None
    lib = _bundled_pocl()
    if lib is None:
        return None
    # The ICD loader later opens the same file by its soname and gets this same instance.
    pocl = ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
    ask = pocl.pocl_get_llvm_cpu_name
    ask.restype = ctypes.c_void_p
    if not wanted:
        wanted = better_name(_ask(ask), cpu_flags(Path("/proc/cpuinfo").read_text()))
        if wanted is None:
            return None
    start = ctypes.cast(ask, ctypes.c_void_p).value
    code = ctypes.string_at(start, len(PROLOGUE) + 4)
    why = "PoCL's LLVM does not know this CPU (pocl/pocl#1049, or no AVX-512 on Zen 4)"
    if code[: len(PROLOGUE)] != PROLOGUE:
        raise RuntimeError(f"{why}, and {lib.name} is not the PoCL build gazehdr can name it for")
    (rel,) = struct.unpack("<i", code[len(PROLOGUE) :])
    get_host_cpu_name = start + len(PROLOGUE) + 4 + rel
    try:
        _patch(get_host_cpu_name, wanted)
    except OSError as exc:
        raise RuntimeError(f"{why}, and naming it failed: {exc}") from exc
    if _ask(ask) != wanted:
        raise RuntimeError(f"{why}, and naming it {wanted!r} did not take")
    return wanted


_AVX512_PROBE = """
__kernel void avx512(__global int *out) {
#if defined(__AVX512F__)
    out[0] = 1;
#else
    out[0] = 0;
#endif
}
"""


def builds_for_avx512(ctx: cl.Context) -> bool:
    """Whether PoCL's compiler builds the kernels of `ctx` for AVX-512: asked of the compiler
    itself (a kernel reports its __AVX512F__), whatever the CPU name came from."""
    queue = cl.CommandQueue(ctx)
    out = np.zeros(1, np.int32)
    buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Program(ctx, _AVX512_PROBE).build().avx512(queue, (1,), None, buf)
    cl.enqueue_copy(queue, out, buf)
    return bool(out[0])
