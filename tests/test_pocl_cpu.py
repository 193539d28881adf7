"""PoCL gets a CPU name its LLVM knows (server/sim/pocl_cpu.py), so kernels build on new CPUs."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from gazehdr.sim.pocl_cpu import better_name, cpu_flags, level_for_flags

V2 = {"cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3"}
V3 = V2 | {"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"}
V4 = V3 | {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}


@pytest.mark.parametrize(
    ("flags", "level"),
    [
        (set(), "x86-64"),
        (V2 - {"popcnt"}, "x86-64"),
        (V2, "x86-64-v2"),
        (V3 - {"movbe"}, "x86-64-v2"),
        (V3 | {"avx512f"}, "x86-64-v3"),
        (V4, "x86-64-v4"),
        (V4 - V3 | V2, "x86-64-v2"),  # AVX-512 without AVX2 is not v4
    ],
)
def test_level_is_the_highest_whose_flags_all_present(flags: set[str], level: str) -> None:
    assert level_for_flags(flags) == level


def test_cpu_flags_reads_the_first_flags_line() -> None:
    text = "processor\t: 0\nflags\t\t: fpu sse2 avx2\nbugs\t: x\n\nflags\t: other\n"
    assert cpu_flags(text) == {"fpu", "sse2", "avx2"}
    assert cpu_flags("processor : 0\n") == set()


PROBE = textwrap.dedent(
    """
    import numpy as np, pyopencl as cl
    from gazehdr.sim.pocl_cpu import name_cpu_for_pocl
    given = name_cpu_for_pocl()
    pocl = [p for p in cl.get_platforms() if "Portable Computing Language" in p.name][0]
    dev = pocl.get_devices()[0]
    ctx = cl.Context([dev])
    prg = cl.Program(ctx, "__kernel void k(__global float *a) { a[get_global_id(0)] *= 2.0f; }")
    prg = prg.build()
    a = np.arange(8, dtype=np.float32)
    buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    q = cl.CommandQueue(ctx)
    prg.k(q, a.shape, None, buf)
    cl.enqueue_copy(q, a, buf)
    assert (a == 2 * np.arange(8)).all(), a
    print(given, dev.version.split("HSTR:")[1].split()[0])
    """
)


def _probe(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", PROBE],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_named_cpu_is_what_pocl_builds_for() -> None:
    """The override patches PoCL on any CPU: kernels build for that name and run correctly."""
    done = _probe({"GAZEHDR_POCL_CPU": "x86-64-v2"})
    assert done.returncode == 0, done.stderr
    given, hstr = done.stdout.split()
    assert given == "x86-64-v2"
    assert hstr.endswith("-x86-64-v2")


def test_without_override_pocl_never_builds_for_generic() -> None:
    done = _probe({"GAZEHDR_POCL_CPU": ""})
    assert done.returncode == 0, done.stderr
    given, hstr = done.stdout.split()
    assert not hstr.endswith("-generic")
    # a name is given only where PoCL's own was "generic" or lacked AVX-512: an x86-64 level
    assert given == "None" or given.startswith("x86-64")


def test_a_malformed_name_is_refused_clearly() -> None:
    done = _probe({"GAZEHDR_POCL_CPU": "not a cpu!"})
    assert done.returncode != 0
    assert "GAZEHDR_POCL_CPU='not a cpu!' is not an LLVM CPU name" in done.stderr


@pytest.mark.parametrize(
    ("llvm_name", "flags", "given"),
    [
        ("generic", V3, "x86-64-v3"),  # a CPU newer than LLVM 14 (pocl/pocl#1049)
        ("generic", V4, "x86-64-v4"),
        ("znver3", V4, "x86-64-v4"),  # Zen 4: AVX-512 that znver3 lacks
        ("znver3", V3, None),  # a real Zen 3
        ("znver2", V4 - {"avx512vl"}, None),  # short of x86-64-v4: left as LLVM names it
        ("icelake-server", V4, None),  # knows its AVX-512
        ("skylake", V3, None),
    ],
)
def test_a_name_is_given_only_where_llvm_misses_what_the_cpu_has(
    llvm_name: str, flags: set[str], given: str | None
) -> None:
    assert better_name(llvm_name, flags) == given


def test_kernels_are_16_wide_where_pocl_builds_for_avx512() -> None:
    """On this machine: where /proc/cpuinfo has x86-64-v4's flags, PoCL is told a CPU with
    AVX-512 (Zen 4's "znver3" included) and the kernels take 16 pixels a work-item."""
    code = "from gazehdr.sim.cl_program import vector_width; print(vector_width())"
    done = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, "GAZEHDR_POCL_CPU": "", "GAZEHDR_VEC": "", "GAZEHDR_CL_DEVICE": "pthr"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    flags = cpu_flags(Path("/proc/cpuinfo").read_text())
    assert int(done.stdout) == (16 if level_for_flags(flags) == "x86-64-v4" else 8)


PINNED = textwrap.dedent(
    """
    import os
    if os.environ.get("HOLD_TO"):  # as taskset starts a process
        os.sched_setaffinity(0, {int(os.environ["HOLD_TO"])})
    from gazehdr.sim import Simulator
    Simulator(64, 36, backend="opencl", seed=0).step(1 / 60)
    mine = os.sched_getaffinity(0)
    cores = [os.sched_getaffinity(int(t)) for t in os.listdir("/proc/self/task")]
    pinned = sorted(min(c) for c in cores if len(c) == 1 and c != mine)
    print(sorted(mine), pinned, all(c <= mine for c in cores), sep="|")
    """
)


@pytest.mark.parametrize(
    ("setting", "held", "pinned"), [(None, False, True), ("0", False, False), (None, True, False)]
)
def test_pocl_workers_are_pinned_one_to_a_core_unless_told(
    setting: str | None, held: bool, pinned: bool
) -> None:
    """The simulator's PoCL worker threads each keep a core of their own (pocl_cpu.
    pin_pocl_workers); POCL_AFFINITY=0 from the user leaves them free, and so does a process
    held to some of the cores (`held`: to the last one, as taskset does), whose threads all
    stay on it. In a fresh process: PoCL reads the setting once, when it sets up its devices."""
    env = {k: v for k, v in os.environ.items() if k != "POCL_AFFINITY"}
    if setting is not None:
        env["POCL_AFFINITY"] = setting
    env["GAZEHDR_CL_DEVICE"] = "pthr"
    mine = sorted(os.sched_getaffinity(0))
    assert len(mine) >= 2, "pinning shows only where the process may use two cores or more"
    env["HOLD_TO"] = str(mine[-1]) if held else ""
    done = subprocess.run(
        [sys.executable, "-c", PINNED], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    allowed, workers, kept_in = done.stdout.strip().split("|")
    assert workers == (allowed if pinned else "[]")
    assert kept_in == "True", "a thread runs on a core the process was kept off"


SIZES = textwrap.dedent(
    """
    from gazehdr.sim import Simulator
    for w, h in ((64, 36), (88, 52), (120, 68)):
        Simulator(w, h, backend="opencl", seed=0).step(1 / 60)
    """
)


@pytest.mark.parametrize(("setting", "once"), [(None, True), ("1", False)])
def test_each_kernel_is_built_once_whatever_the_frame_size(
    tmp_path: Path, setting: str | None, once: bool
) -> None:
    """Three frame sizes in a fresh process with an empty kernel cache: PoCL keeps one build of
    each kernel (pocl_cpu.one_build_per_kernel), where, specialising for the work-group size
    as it does by default (the user's POCL_WORK_GROUP_SPECIALIZATION=1), it builds kernels
    again for the local sizes each new size makes it pick. Guards: a resized viewer waiting
    seconds for builds (0.4-2.9 s a new size, measured)."""
    env = {k: v for k, v in os.environ.items() if k != "POCL_WORK_GROUP_SPECIALIZATION"}
    if setting is not None:
        env["POCL_WORK_GROUP_SPECIALIZATION"] = setting
    env["GAZEHDR_CL_DEVICE"] = "pthr"
    env["POCL_CACHE_DIR"] = str(tmp_path)
    done = subprocess.run(
        [sys.executable, "-c", SIZES], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    # PoCL's cache: PROGRAM_HASH/KERNEL/WORK_GROUP_VARIANT/KERNEL.so
    builds: dict[str, int] = {}
    for so in tmp_path.glob("*/*/*/*/*.so"):
        builds[so.parent.parent.name] = builds.get(so.parent.parent.name, 0) + 1
    assert "compose" in builds, sorted(builds)
    assert (max(builds.values()) == 1) == once, builds
