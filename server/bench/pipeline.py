"""`gazehdr bench`: time each stage of the OpenCL pipeline beside the same operations in OpenCV.

Both sides run in one process on the same scene, gaze path and sizes, alternating frame by
frame so that drift of a shared machine hits both alike. The OpenCV side is a straight port of
the stages to cv2 calls (area resize, separable filters, remap, exp/log/pow, per-pixel matrix
transforms) with NumPy only for glue, and the reference model's own NumPy functions for the
colour of the afterimage maps and the gamut; it is checked against the kernels at the end so
the comparison is of the same work. Figures are medians over the timed frames.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from gazehdr.bench import roofline
from gazehdr.drivers.cli_args import size_list_arg
from gazehdr.sim import Params, Simulator
from gazehdr.sim.layout import (
    LMS_TO_RGB,
    RGB_TO_LMS,
    Layout,
    NoiseFrame,
    acuity_increments,
    adaptation_window,
    gaussian_taps,
    surround_map,
)
from gazehdr.sim.models import Models, each_beside_default
from gazehdr.sim.reference import (
    bleach_response,
    gamut_map,
    linear_contrast,
    ln_sigma_n,
    opponent_gain,
)
from gazehdr.sim.simulator import OUTPUT_DTYPES

SIZES = ((640, 360), (1280, 720), (1920, 1080))
STAGES = ("prepare", "adapt", "retina", "acuity", "compose")


class OpenCVPipeline:
    """The model's stages written with OpenCV, interleaved HxWxC float32 as OpenCV likes."""

    def __init__(self, layout: Layout, params: Params) -> None:
        import cv2

        self.cv2, self.lay, self.p = cv2, layout, params
        cv2.setNumThreads(0)  # OpenCV's default: all cores
        lay = layout
        self.A = params.A_min
        self.state = np.zeros((lay.grid_h, lay.grid_w, 9), np.float32)
        self.rho_taps = gaussian_taps(lay.px(params.rho_sigma_deg) / lay.cell)
        self.acuity_taps = [gaussian_taps(s) for s in acuity_increments(params, lay.ppd)]
        ys, xs = np.mgrid[: lay.height, : lay.width].astype(np.float32) + 0.5
        self.xs, self.ys = xs, ys
        gy, gx = np.mgrid[: lay.grid_h, : lay.grid_w].astype(np.float32) + 0.5
        self.gx, self.gy = gx, gy
        m = params.n * params.plateau_m_over_n
        self.ln_K_m, self.n_minus_m = m * math.log(params.plateau_K), params.n - m
        self.b1 = np.array(params.b1, np.float32)
        self.b2 = np.array(params.b2, np.float32)
        self.w_P = np.array(params.w_P, np.float32)
        self.w_S = np.array(params.w_S, np.float32)

    def _tone(self, I: np.ndarray) -> np.ndarray:
        cv2 = self.cv2
        lsn = self.n_minus_m * self.A * math.log(10) + self.ln_K_m
        lnI = cv2.log(np.maximum(I, 1e-30))
        e = cv2.exp(np.minimum(lsn - self.p.n * lnI, 80.0))
        return np.where(I > 0, 1.0 / (1.0 + e), 0.0).astype(np.float32)

    def _sep(self, img: np.ndarray, taps: np.ndarray) -> np.ndarray:
        return self.cv2.sepFilter2D(img, -1, taps, taps, borderType=self.cv2.BORDER_REPLICATE)

    def prepare(self, scene: np.ndarray) -> None:
        cv2, lay = self.cv2, self.lay
        rgb = cv2.resize(scene, (lay.low_w, lay.low_h), interpolation=cv2.INTER_AREA)
        self.lms = cv2.transform(rgb, RGB_TO_LMS.astype(np.float32))
        # The retina's input, with a border of one cell that holds the surround (what a tap off
        # the screen reads, at the nearest cell): remap replicates it outwards.
        surround = surround_map(self.lms.transpose(2, 0, 1), lay, self.p)
        padded = np.pad(surround.transpose(1, 2, 0), ((1, 1), (1, 1), (0, 0)), mode="edge")
        padded[1:-1, 1:-1] = self.lms
        self.lms_padded = padded.astype(np.float32)
        self.lum_p = cv2.transform(rgb, self.w_P[None])
        self.lum_s = cv2.transform(rgb, self.w_S[None])
        L = cv2.log(np.maximum(self._sep(self.lum_p, self.rho_taps), self.p.Y_min)) / math.log(10)
        self.rho = (L - self.p.m2) / (self.p.m1 - self.p.m2)

    def adapt(self, gaze, dt: float) -> None:
        lay, p = self.lay, self.p
        cx, cy, sig, x0, x1, y0, y1 = adaptation_window(gaze, lay, p)
        ys, xs = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
        w = np.exp(
            -(((xs + 0.5) * lay.cell - cx) ** 2 + ((ys + 0.5) * lay.cell - cy) ** 2)
            / (2 * sig * sig)
        )
        rc = np.clip(self.rho[y0 : y1 + 1, x0 : x1 + 1], 0, 1)
        ymes = (
            rc * self.lum_p[y0 : y1 + 1, x0 : x1 + 1]
            + (1 - rc) * self.lum_s[y0 : y1 + 1, x0 : x1 + 1]
        )
        target = max(math.log10(max(float((w * ymes).sum() / w.sum()), p.Y_min)), p.A_min)
        step = p.a1 * dt if self.A < target else -p.a2 * dt
        self.A = min(self.A + step, target) if step > 0 else max(self.A + step, target)

    def retina(self, gaze, dt: float) -> None:
        cv2, lay, p = self.cv2, self.lay, self.p
        mx = (gaze[0] / lay.cell + self.gx - lay.grid_w / 2) + 0.5  # + 1: the padding
        my = (gaze[1] / lay.cell + self.gy - lay.grid_h / 2) + 0.5
        I = cv2.remap(self.lms_padded, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        b1I = I * self.b1
        B_inf = b1I / (b1I + self.b2)
        c_inf = 1.0 - self._tone(I)
        B = (self.state[..., :3] - B_inf) * cv2.exp(-(b1I + self.b2) * dt) + B_inf
        c = (self.state[..., 3:6] - c_inf) * math.exp(-p.c2 * dt) + c_inf
        x_inf = I * np.float32(math.exp(-ln_sigma_n(self.A, p) / p.n))  # adapted_light
        x = np.maximum((self.state[..., 6:] - x_inf) * math.exp(-p.c2 * dt) + x_inf, 0)
        new = np.concatenate([np.clip(np.concatenate([B, c], axis=2), 0, 1), x], axis=2)
        sigma = lay.px(p.map_blur_deg) * math.sqrt(dt) / lay.cell
        self.state = self._sep(new, gaussian_taps(sigma)) if sigma > 0 else new
        # The maps' colour math per retina cell: the reference's NumPy functions (planar).
        st = self.state
        hwc = (I, st[..., :3], B_inf, st[..., 3:6], c_inf, st[..., 6:], x_inf)
        I, B, B_inf, c, c_inf, x, x_inf = (np.moveaxis(a, 2, 0) for a in hwc)
        gain = opponent_gain(c, c_inf, p, linear_contrast(x, x_inf, p))
        bleach = bleach_response(I, B, B_inf, c, self.A, p)
        self.maps = np.moveaxis(np.concatenate([gain, bleach]), 0, 2).astype(np.float32)

    def acuity(self, scene: np.ndarray, noise: NoiseFrame) -> None:
        cv2, lay, p = self.cv2, self.lay, self.p
        rho = cv2.resize(self.rho, (lay.width, lay.height), interpolation=cv2.INTER_LINEAR)
        nx = (self.xs / noise.spacing).astype(np.float32)
        ny = (self.ys / noise.spacing).astype(np.float32)
        x0 = cv2.remap(noise.key0, nx, ny, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        x1 = cv2.remap(noise.key1, nx, ny, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        fx, fy, ft = nx - np.floor(nx), ny - np.floor(ny), noise.frac
        norm = np.sqrt(((1 - fx) ** 2 + fx**2) * ((1 - fy) ** 2 + fy**2) * ((1 - ft) ** 2 + ft**2))
        q = rho + p.g * ((1 - ft) * x0 + ft * x1) / norm
        d = np.zeros(q.shape, np.uint8)
        for t in p.rho_i():
            d += (q <= t).astype(np.uint8)
        out, level = scene.copy(), scene
        for i in range(int(d.max())):
            level = self._sep(level, self.acuity_taps[i])
            np.copyto(out, level, where=(d == i + 1)[..., None])
        self.G = out

    def compose(self, gaze) -> np.ndarray:
        cv2, lay, p = self.cv2, self.lay, self.p
        rc = np.clip(cv2.resize(self.rho, (lay.width, lay.height)), 0, 1)
        yp = cv2.transform(self.G, self.w_P[None])
        ys = cv2.transform(self.G, self.w_S[None])
        R = self._tone(rc * yp + (1 - rc) * ys)
        ratio = rc[..., None] * self.G / np.maximum(yp, p.Y_min)[..., None]
        J = R[..., None] * (ratio + (1 - rc)[..., None] * np.array(p.k_s, np.float32))
        mx = (self.xs - gaze[0]) / lay.cell + lay.grid_w / 2 - 0.5
        my = (self.ys - gaze[1]) / lay.cell + lay.grid_h / 2 - 0.5
        maps = cv2.remap(self.maps, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=(1, 1, 1, 0))  # fmt: skip
        gain, bleach = maps[..., :3], maps[..., 3:]
        sig = lay.px(p.fovea_sigma_deg)
        f = cv2.exp(-((self.xs - gaze[0]) ** 2 + (self.ys - gaze[1]) ** 2) / (2 * sig * sig))
        lms = cv2.transform(J, RGB_TO_LMS.astype(np.float32)) * (1 + f[..., None] * (gain - 1))
        J = cv2.transform(lms, LMS_TO_RGB.astype(np.float32))
        J += f[..., None] * cv2.transform(bleach, np.array(p.H, np.float32))
        J = np.moveaxis(gamut_map(np.moveaxis(J, 2, 0), p.w_P), 0, 2).astype(np.float32)
        return cv2.pow(J, p.gamma)


def _bench_size(
    width: int,
    height: int,
    frames: int,
    scene_name: str,
    dt: float = 1 / 60,
    opencv: bool = True,
    half: bool = False,
) -> dict:
    from gazehdr.scenes import open_scene

    gazes = [
        (width * (0.3 + 0.4 * (i % 3) / 2), height * (0.4 + 0.2 * (i % 2)))
        for i in range(frames + 2)
    ]
    sim = Simulator(width, height, backend="opencl", seed=0)
    scene = open_scene(scene_name).render(0.0, width, height)
    sim.start(scene, gazes[0])
    sim.step(0.0)  # settled there: the state the OpenCV side starts from
    # A second eye for the live frames, so that `sim` stays in step with the OpenCV side.
    live = Simulator(width, height, backend="opencl", seed=0)
    live.start(scene, gazes[0])
    for s in (sim, live):
        roofline.to_steady_acuity(s)
    b, lay, p = sim._backend, sim.layout, sim.params
    cvp = OpenCVPipeline(lay, p) if opencv else None
    if cvp is not None:
        cvp.A = sim.adaptation
        cvp.state = np.ascontiguousarray(b.get("state").transpose(1, 2, 0))
    fitted = np.ascontiguousarray(b.get("scene").transpose(1, 2, 0))
    times: dict[str, list[float]] = {f"cl.{s}": [] for s in (*STAGES, "step", "live")}
    times.update({f"cv.{s}": [] for s in (*STAGES, "step")})
    out_dtype = np.float16 if half else np.float32
    out = "float16" if half else "rgb10a2"  # the live step's: the server's f16, or its default

    def timed(key: str, fn):
        t0 = time.perf_counter()
        value = fn()
        b.queue.finish()
        times[key].append(time.perf_counter() - t0)
        return value

    for i, gaze in enumerate(gazes):
        noise = sim._noise.at(i * dt)
        # OpenCL, stage by stage (each stage waited for), then the whole step as users call it.
        timed("cl.prepare", lambda: b.prepare(1.0))
        timed("cl.adapt", lambda g=gaze: b.adapt(g, dt, False))
        timed("cl.retina", lambda g=gaze: b.retina(g, dt, False))
        timed("cl.acuity", lambda n=noise: b.acuity(n))
        timed("cl.compose", lambda g=gaze: b.compose(g, 1.0, out_dtype))
        sim._prepared_for = None  # make step() redo the scene maps, as the stage loop did
        timed("cl.step", lambda g=gaze: sim.step(dt, gaze=g))
        # A live frame: the scene maps are kept (they change only with the scene), and the
        # frame is encoded as the server sends it.
        frame = timed("cl.live", lambda g=gaze: live.step(dt, gaze=g, output=out))
        if cvp is None:
            continue
        t_all = time.perf_counter()
        for stage, fn in (
            ("prepare", lambda: cvp.prepare(fitted)),
            ("adapt", lambda g=gaze: cvp.adapt(g, dt)),
            ("retina", lambda g=gaze: cvp.retina(g, dt)),
            ("acuity", lambda n=noise: cvp.acuity(fitted, n)),
            ("compose", lambda g=gaze: cvp.compose(g)),
        ):
            t0 = time.perf_counter()
            fn()
            times[f"cv.{stage}"].append(time.perf_counter() - t0)
        times["cv.step"].append(time.perf_counter() - t_all)
    # The first two frames warm caches and JITs; medians of the rest.
    result = {k: statistics.median(v[2:]) * 1000 for k, v in times.items() if v}
    result["device"] = sim.device
    # named from the last frame itself: the encoding it came in, else its dtype (float32)
    names = {np.dtype(t): name for name, t in OUTPUT_DTYPES.items()}
    result["live_output"] = names.get(frame.dtype, frame.dtype.name)
    if cvp is not None:
        result["check"] = float(np.abs(cvp.compose(gazes[-1]) - b.compose(gazes[-1], 1.0)).mean())
    return result


def _bench_models(
    width: int, height: int, frames: int, scene_name: str, dt: float, models: list[Models]
) -> dict[str, float]:
    """Live-step ms per model: one simulator each, stepped in turn on the same scene and gaze
    path, so that a shared machine's drift hits every model alike."""
    from gazehdr.scenes import open_scene

    scene = open_scene(scene_name).render(0.0, width, height)
    sims = {}
    for m in models:
        sims[str(m)] = Simulator(
            width, height, backend="opencl", seed=0, afterimage=m.afterimage, acuity=m.acuity
        )
        sims[str(m)].load_scene(scene)
        roofline.to_steady_acuity(sims[str(m)])
    times: dict[str, list[float]] = {name: [] for name in sims}
    for i in range(frames + 2):
        gaze = (width * (0.3 + 0.2 * (i % 3)), height * (0.4 + 0.2 * (i % 2)))
        eyes_open = i % 8 != 7  # now and then a closed-eye frame, as in a blink
        for name, sim in sims.items():
            t0 = time.perf_counter()
            sim.step(dt, gaze=gaze, eyes_open=eyes_open, output="rgb10a2")
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(v[2:]) * 1000 for name, v in times.items()}


def _print_roofline(width: int, height: int, args, roofs):
    """The roofline table of one size (roofline.py); the roofs are measured once per run."""

    sim = Simulator(width, height, backend="opencl", seed=0)
    b = sim._backend
    if roofs is None:
        roofs = roofline.measure_roofs(b.ctx, roofline.profiling_queue(b.ctx), args.roof_mib)
    from gazehdr.scenes import open_scene

    sim.start(open_scene(args.scene).render(0.0, width, height), (width / 2, height / 2))
    sim.step(args.dt)
    # What the live path composes: rgb10a2 (the server's default) or, with --half, f16.
    out, name = (np.float16, "f16") if args.half else (np.uint32, "rgb10a2")
    costs, kernel_s, wall_s = roofline.profile_live(sim, args.frames, args.dt, out)
    print(
        f"\n{width}x{height}  scene={args.scene}  roofline, {name} out, OpenCL device: {sim.device}"
    )
    print(roofline.roofs_line(roofs))
    for line in roofline.table(costs, kernel_s, wall_s, roofs, width * height):
        print(line)
    return roofs


def _parse_models(text: str) -> list[Models]:
    if text == "all":
        return each_beside_default()
    return [Models.parse(spec) for spec in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gazehdr bench", description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=10, help="timed frames per size (default 10)")
    ap.add_argument("--scene", default="lamp", help="built-in scene (default lamp: 1e-1..1e6)")
    ap.add_argument("--sizes", type=size_list_arg, default=",".join(f"{w}x{h}" for w, h in SIZES))
    ap.add_argument("--dt", type=float, default=1 / 60, help="seconds per frame (default 1/60)")
    ap.add_argument(
        "--opencl-only", action="store_true", help="time the kernels only, without OpenCV"
    )
    ap.add_argument(
        "--half",
        action="store_true",
        help="compose to float16, as frames sent as f16 are (the roofline and the live step: "
        "else rgb10a2, the server's default encoding; the stage table: else float32, as "
        "OpenCV's side)",
    )
    ap.add_argument(
        "--models",
        metavar="LIST",
        help="instead of the stage table, time a live step of each model, e.g. "
        "'jacobs,ritschel,jacobs+thompson', or 'all' (each baseline beside the default)",
    )
    ap.add_argument(
        "--roofline",
        action="store_true",
        help="also a roofline line per stage of the live step: bytes and flops per pixel, "
        "time, and the fraction of this device's bandwidth and FMA rate, measured in the run",
    )
    ap.add_argument(
        "--roof-mib", type=int, default=256, help="MiB per array of the bandwidth kernels"
    )
    args = ap.parse_args(argv)
    models = None
    if args.models:
        try:
            models = _parse_models(args.models)
        except ValueError as e:
            ap.error(str(e))
    if not args.opencl_only and models is None:
        try:
            import cv2  # noqa: F401
        except ImportError:
            ap.error("the OpenCV side needs opencv: pip install -e '.[bench]'")
    if args.frames < 1:
        ap.error("--frames must be at least 1")
    if args.roofline and models is not None:
        ap.error("--roofline times the default model's stages; leave out --models")
    if args.roof_mib < 1:
        ap.error("--roof-mib must be at least 1")
    if not 0 < args.dt <= 60:
        ap.error("--dt must be in (0, 60] seconds")
    roofs = None
    for width, height in args.sizes:
        if args.roofline:
            roofs = _print_roofline(width, height, args, roofs)
        if models is not None:
            ms = _bench_models(width, height, args.frames, args.scene, args.dt, models)
            base = ms[str(models[0])]
            print(f"\n{width}x{height}  scene={args.scene}  live step, rgb10a2 out")
            print(f"  {'model':<22}{'ms':>9}{'fps':>8}{'× ' + str(models[0]):>26}")
            for name, t in ms.items():
                print(f"  {name:<22}{t:>9.2f}{1000 / t:>8.1f}{t / base:>26.2f}")
            continue
        r = _bench_size(
            width, height, args.frames, args.scene, args.dt, not args.opencl_only, args.half
        )
        print(f"\n{width}x{height}  scene={args.scene}  OpenCL device: {r['device']}")
        if args.opencl_only:
            print(f"  {'stage':<10}{'OpenCL ms':>12}")
            for stage in STAGES:
                print(f"  {stage:<10}{r[f'cl.{stage}']:>12.2f}")
            print(f"  {'pipeline':<10}{r['cl.step']:>12.2f}")
            live, out = r["cl.live"], r["live_output"]
            print(f"  live step {live:.2f} ms ({1000 / live:.1f} fps): scene maps kept, {out} out")
            continue
        print(f"  {'stage':<10}{'OpenCL ms':>12}{'OpenCV ms':>12}{'CL/CV':>9}")
        for stage in (*STAGES, "step"):
            cl_ms, cv_ms = r[f"cl.{stage}"], r[f"cv.{stage}"]
            name = "pipeline" if stage == "step" else stage
            print(f"  {name:<10}{cl_ms:>12.2f}{cv_ms:>12.2f}{cl_ms / max(cv_ms, 1e-9):>9.2f}")
        fps_cl, fps_cv = 1000 / r["cl.step"], 1000 / r["cv.step"]
        print(f"  pipeline: {fps_cl:.1f} fps OpenCL, {fps_cv:.1f} fps OpenCV;")
        live, out = r["cl.live"], r["live_output"]
        print(f"  live step {live:.2f} ms ({1000 / live:.1f} fps): scene maps kept, {out} out;")
        print(f"  same work: mean |v_OpenCL - v_OpenCV| = {r['check']:.2e}")
    return 0
