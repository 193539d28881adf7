"""Kernel A/B: the installed kernels against a changed copy, launch by launch in one process.

    python -m gazehdr.bench.ab DIR [--kernels compose_rgb10,retina_update] [--size 1280x720]
                               [--reps 40] [--scene lamp]

DIR holds the kernel files (`kernels/*.cl`) as changed; files it lacks come from the installed
package. A simulator steps a few live frames (rgb10a2) so that every buffer holds a real frame,
each named kernel's last launch is recorded (global size, local size, arguments), and the two
builds of it then run in turn, alternating which goes first, each timed by its OpenCL profiling
event. The medians (the first two launches of each left out) and their ratio hold on a machine
whose speed drifts, as this project's shared 2-core machines do; whole-run timings do not.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import pyopencl as cl

from gazehdr.drivers.cli_args import screen_size_arg
from gazehdr.sim import cl_program, opencl

DEFAULT_KERNELS = (
    "retina_update,retina_blur,afterimage_maps,acuity_levels,acuity_bank,acuity_pick,compose_rgb10"
)


def build(ctx: cl.Context, kernel_dir: Path | None) -> cl.Program:
    """The default pipeline's program, with DIR's files where it has them."""
    source = cl_program.kernel_source(opencl.KERNEL_FILES, kernel_dir)
    return cl.Program(ctx, source).build(cl_program.build_options(ctx))


def record_launches(size: tuple[int, int], scene_name: str) -> tuple[cl.Context, dict]:
    """Step a simulator on a profiling queue; each kernel's last launch, by kernel name."""
    from gazehdr.bench.roofline import to_steady_acuity
    from gazehdr.scenes import open_scene
    from gazehdr.sim import Simulator

    launches: dict[str, tuple] = {}
    plain_call = cl.Kernel.__call__

    def call(kernel, queue, global_size, local_size, *args, **kwargs):
        launches[kernel.function_name] = (queue, global_size, local_size, args)
        return plain_call(kernel, queue, global_size, local_size, *args, **kwargs)

    w, h = size
    sim = Simulator(w, h, backend="opencl", seed=0)
    backend = sim._backend
    backend.queue.finish()
    backend.queue = cl.CommandQueue(
        backend.ctx, properties=cl.command_queue_properties.PROFILING_ENABLE
    )  # every stage of the default pipeline enqueues on it
    cl.Kernel.__call__ = call
    try:
        sim.start(open_scene(scene_name).render(0.0, w, h), (w / 2, h / 2))
        to_steady_acuity(sim)  # the bank's launches are kept too, from the frames before
        for i in range(6):
            gaze = (w * (0.3 + 0.2 * (i % 3)), h * (0.4 + 0.2 * (i % 2)))
            sim.step(1 / 60, gaze=gaze, output="rgb10a2")
    finally:
        cl.Kernel.__call__ = plain_call
    backend.queue.finish()
    return backend.ctx, launches


def compare(kernel_dir: Path, names: list[str], size, reps: int, scene: str) -> list[tuple]:
    """(name, installed ms, changed ms) per kernel: medians of alternating launches."""
    ctx, launches = record_launches(size, scene)
    builds = build(ctx, None), build(ctx, kernel_dir)
    rows = []
    for name in names:
        if name not in launches:
            raise SystemExit(f"{name}: not launched by a live step (launched: {sorted(launches)})")
        queue, global_size, local_size, args = launches[name]
        kernels = [cl.Kernel(prg, name) for prg in builds]
        times: list[list[float]] = [[], []]
        for k in kernels:
            k.set_args(*args)
        for r in range(reps):
            for i in (0, 1) if r % 2 else (1, 0):
                event = cl.enqueue_nd_range_kernel(queue, kernels[i], global_size, local_size)
                event.wait()
                times[i].append((event.profile.end - event.profile.start) * 1e-6)
        rows.append((name, *(statistics.median(t[2:]) for t in times)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gazehdr.bench.ab", description=__doc__)
    parser.add_argument("kernel_dir", type=Path, help="folder with the changed kernel files")
    parser.add_argument("--kernels", default=DEFAULT_KERNELS)
    parser.add_argument("--size", type=screen_size_arg, default="1280x720")
    parser.add_argument("--reps", type=int, default=40, help="launches of each build (>= 4)")
    parser.add_argument("--scene", default="lamp")
    args = parser.parse_args(argv)
    if args.reps < 4:
        parser.error("--reps must be at least 4")
    if not args.kernel_dir.is_dir():
        parser.error(f"{args.kernel_dir} is not a folder")
    names = [n for n in args.kernels.split(",") if n]
    rows = compare(args.kernel_dir, names, args.size, args.reps, args.scene)
    print(f"{'kernel':20s} {'installed ms':>12s} {'changed ms':>10s} {'ratio':>6s}")
    for name, installed, changed in rows:
        print(f"{name:20s} {installed:12.3f} {changed:10.3f} {changed / installed:6.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
