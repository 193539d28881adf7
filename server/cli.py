"""The `gazehdr` command line: one small function per subcommand, listed in `COMMANDS`.

Only the standard library and `drivers` are imported up front; each subcommand imports what it
needs when it runs, so `gazehdr --help` (and later `gazehdr daemon` on a tracker machine
without pyopencl) works on a minimal install. Errors the user can fix print one line,
`gazehdr: error: …`, and exit with status 2; `main` returns the status instead of exiting.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from gazehdr import __version__
from gazehdr.drivers import registry
from gazehdr.drivers.cli_args import OneLineParser, screen_size_arg

PROG = "gazehdr"


class UsageError(Exception):
    """A mistake in what the user asked for; reported in one line with status 2."""


def _add_model_options(p: argparse.ArgumentParser, whose: str, default: str = "") -> None:
    """--afterimage and --acuity; `default` words the default when it is not the paper's."""
    p.add_argument(
        "--afterimage",
        metavar="NAME",
        help=f"afterimage model{whose}: jacobs, ritschel, mikamo or none "
        f"(default: {default or 'jacobs'})",
    )
    p.add_argument(
        "--acuity",
        metavar="NAME",
        help=f"acuity model{whose}: stochastic, none, gaussian, bilateral or thompson "
        f"(default: {default or 'stochastic'})",
    )


def _data_dir(given: str | None) -> Path:
    return Path(given or os.environ.get("GAZEHDR_DATA_DIR") or Path.home() / ".local/share/gazehdr")


# --- render -----------------------------------------------------------------------------------


def _add_size_and_backend(p: argparse.ArgumentParser, size: tuple[int, int], what: str) -> None:
    p.add_argument(
        "--size",
        type=screen_size_arg,
        default=size,
        metavar="WxH",
        help=f"{what} (default: {size[0]}x{size[1]})",
    )
    p.add_argument(
        "--backend",
        choices=("opencl", "reference"),
        default="opencl",
        help="PyOpenCL kernels or the NumPy reference (default: opencl)",
    )


def _configure_render(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scene",
        metavar="SCENE",
        nargs="?",
        help="built-in scene name or HDR image file: .exr, .hdr, .pfm (default with a session "
        "log: the scenes it recorded, looked up among the built-ins and DATA_DIR's uploads)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the frames")
    p.add_argument(
        "--gaze",
        default="synthetic",
        metavar="SPEC",
        help=f"{registry.describe(registry.TRACK)}; a recorded viewing session also brings "
        "its scene, parameter and model changes and resets, unless SCENE, --params or a model "
        "option replaces them (default: synthetic)",
    )
    p.add_argument("--seconds", type=float, help="duration (default: a session log's, else 6)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default: 30)")
    _add_size_and_backend(p, (640, 360), "frame size")
    p.add_argument(
        "--seed",
        type=int,
        help="seeds noise, dither and scan path (default: the seed a recorded session ran "
        "with, else 0)",
    )
    _add_model_options(p, "", "a recorded session's, else the paper's")
    _add_preset_options(p, "a recorded session's, else the paper's: 'paper'")
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="where a recorded session's uploaded scenes are (default: $GAZEHDR_DATA_DIR or "
        "~/.local/share/gazehdr)",
    )
    p.add_argument(
        "--scale",
        type=float,
        metavar="CD_PER_UNIT",
        help="cd/m^2 per unit of the scene file (default: its whiteLuminance, else an "
        "estimate; docs/server.md)",
    )
    p.add_argument("--exr", action="store_true", help="also write undithered float32 EXR")
    p.add_argument(
        "--video",
        action="store_true",
        help="also write DIR/render.apng, the frames as one lossless animated PNG",
    )
    p.add_argument("--overwrite", action="store_true", help="replace frames already in DIR")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    batch = p.add_argument_group(
        "batch rendering (many logs as Dask tasks, each into its own folder under --out)"
    )
    batch.add_argument(
        "--logs", nargs="+", metavar="LOG", help="session logs to render, files or globs"
    )
    batch.add_argument(
        "--batch", metavar="MANIFEST.toml", help="logs x models x presets (docs/cli.md)"
    )
    batch.add_argument(
        "--workers", type=int, metavar="N", help="local cluster's worker processes (default: cores)"
    )
    batch.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="an existing Dask cluster's scheduler, tcp://HOST:PORT",
    )


def _add_preset_options(p: argparse.ArgumentParser, default: str) -> None:
    from gazehdr.sim.presets import PRESETS

    p.add_argument(
        "--preset",
        choices=list(PRESETS),
        help="the model's parameters: 'paper' (Appendix A, the paper's results) or 'visible' "
        f"(ours: afterimages visible on a plain monitor; docs/model.md) (default: {default})",
    )
    p.add_argument(
        "--params",
        metavar="PARAMS.json",
        help="parameter values over the preset (a JSON object; partial is fine)",
    )


def _render_defaults() -> dict[str, object]:
    """The render options' defaults: a batch manifest's values replace these, not given ones."""
    p = argparse.ArgumentParser()
    _configure_render(p)
    return vars(p.parse_args(["--out", "-"]))


def _render_request(args: argparse.Namespace, **fields: object) -> object:
    """The render options of `args` as a `RenderRequest` (`fields` replace some)."""
    from gazehdr.render import RenderRequest

    width, height = args.size
    values = dict(
        gaze=args.gaze, scene=args.scene, seconds=args.seconds, fps=args.fps, width=width,
        height=height, seed=args.seed, backend=args.backend, afterimage=args.afterimage,
        acuity=args.acuity, preset=args.preset, params=args.params,
        data_dir=str(_data_dir(args.data_dir)),
        scale=args.scale, exr=args.exr, video=args.video,
    )  # fmt: skip
    return RenderRequest(**(values | fields))


def _render(args: argparse.Namespace, extra: list[str]) -> int:
    if args.logs or args.batch:  # many logs, as Dask tasks (docs/cli.md, "Batch rendering")
        try:
            import dask.distributed  # noqa: F401 -- imported where it runs; here only checked
        except ModuleNotFoundError as e:
            raise UsageError(
                f"render --logs/--batch needs {e.name}: pip install 'gazehdr[batch]'"
            ) from None
        from gazehdr import batch

        return batch.main(args, _render_request, parser_defaults=_render_defaults())
    from gazehdr.render import render_request

    summary = render_request(
        _render_request(args), args.out, progress=not args.quiet, overwrite=args.overwrite
    )
    print(f"wrote {summary.frames} frames to {summary.out_dir} in {summary.wall_seconds:.1f} s")
    return 0


# --- serve ------------------------------------------------------------------------------------


def _configure_serve(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default: 8000)")
    p.add_argument(
        "--scene",
        default="flash",
        metavar="SCENE",
        help="built-in or HDR image file: .exr, .hdr, .pfm (default: flash)",
    )
    p.add_argument(
        "--gaze",
        default="mouse",
        metavar="SOURCE",
        help="gaze of new sessions: mouse (the viewer's pointer), remote:TRACKER (the gaze "
        "daemon whose hello names TRACKER), remote (the tracker, once exactly one is "
        "connected), or a track: "
        + ", ".join(f"{k.name} ({k.track.help})" for k in registry.named_tracks() if k.track)
        + " (default: mouse)",
    )
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default: 30)")
    p.add_argument(
        "--size",
        type=screen_size_arg,
        default=(640, 360),
        metavar="WxH",
        help="frame pixel budget; the frame takes the viewer's aspect ratio (default: 640x360)",
    )
    p.add_argument("--fixed-size", action="store_true", help="never fit the frame to the viewer")
    p.add_argument(
        "--no-late-gaze",
        action="store_true",
        help="show each frame from the gaze its step started with, not the newest one read once "
        "the step is simulated (offline renders of recordings then match the live frames)",
    )
    _add_preset_options(p, "'paper'")
    p.add_argument(
        "--scale",
        type=float,
        metavar="CD_PER_UNIT",
        help="cd/m^2 per unit of the scene file (default: its whiteLuminance, else an estimate; "
        "docs/server.md)",
    )
    p.add_argument("--layer", metavar="NAME", help="the EXR layer to show (default: the first)")
    p.add_argument(
        "--token",
        help="bearer token for the gaze daemon and scripts (default: $GAZEHDR_TOKEN or a new one)",
    )
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="where uploaded scenes go (default: $GAZEHDR_DATA_DIR or ~/.local/share/gazehdr)",
    )
    p.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="ORIGIN",
        help="another origin (scheme://host:port) whose pages may use this server (CORS, "
        "/ws/view); repeatable",
    )
    p.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="another name clients may reach this server by (the Host header), besides "
        "127.0.0.1, localhost, [::1] and --host; repeatable (docs/security.md)",
    )
    p.add_argument(
        "--no-auth",
        action="store_true",
        help="ask no credential for anything (a lab's closed network only: anyone who reaches "
        "the server can change it and read recordings; Host and Origin are still checked)",
    )
    p.add_argument(
        "--encoding",
        choices=("f16", "rgb10a2"),
        default="rgb10a2",
        help="frame pixels: rgb10a2 (10 bits, 4 bytes/px; default: fewer bytes, faster in a "
        "browser) or f16 (half floats, 6 bytes/px, finer in the darks)",
    )
    p.add_argument("--backend", choices=("opencl", "reference"), default="opencl")
    _add_model_options(p, " of new sessions (the viewer's panel changes it)")
    p.add_argument(
        "--split",
        metavar="AFTERIMAGE[+ACUITY]",
        help="start new sessions in split view with this model in the right pane, e.g. "
        "ritschel or jacobs+thompson (the left pane: --afterimage, --acuity)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the acuity noise (default: 0)")
    p.add_argument(
        "--record",
        action="store_true",
        help="record each session (gaze followed, scene, parameter and model changes) as a "
        "session log in DATA_DIR/recordings, replayable in the viewer and by 'gazehdr render'",
    )
    p.add_argument(
        "--tracker",
        action="append",
        default=[],
        metavar="SOURCE",
        help="also stream this gaze source to the server from this process, as 'gazehdr daemon' "
        f"would, recorded to DATA_DIR/recordings (repeatable): {registry.choices(registry.STREAM)}"
        "; sessions follow it as remote:NAME, or with --gaze remote",
    )
    p.add_argument(
        "--lsl-outlet",
        nargs="?",
        const="gazehdr",
        metavar="NAME",
        help="publish the gaze each session follows on Lab Streaming Layer, for LabRecorder: a "
        "Gaze stream NAME (default: gazehdr) and a Markers stream 'NAME events' (fixations, "
        "blinks, scene and parameter changes) per session (needs gazehdr[lsl])",
    )


def _serve(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.serve import serve
    from gazehdr.sim.presets import DEFAULT_PRESET

    token = args.token or os.environ.get("GAZEHDR_TOKEN") or None
    return serve(
        host=args.host,
        port=args.port,
        scene=args.scene,
        scale=args.scale,
        layer=args.layer,
        gaze=args.gaze,
        fps=args.fps,
        size=args.size,
        fit_viewport=not args.fixed_size,
        late_gaze=not args.no_late_gaze,
        preset=args.preset or DEFAULT_PRESET,
        params_file=args.params,
        token=token,
        data_dir=_data_dir(args.data_dir),
        allow_origins=tuple(args.allow_origin),
        allow_hosts=tuple(args.allow_host),
        auth=not args.no_auth,
        encoding=args.encoding,
        backend=args.backend,
        afterimage=args.afterimage or "jacobs",
        acuity=args.acuity or "stochastic",
        split=args.split,
        seed=args.seed,
        record=args.record,
        trackers=tuple(args.tracker),
        lsl_outlet=args.lsl_outlet,
    )


# --- bench ------------------------------------------------------------------------------------


def _bench(args: argparse.Namespace, extra: list[str]) -> int:
    try:
        bench = importlib.import_module("gazehdr.bench.pipeline")
    except ModuleNotFoundError as e:
        if e.name in ("gazehdr.bench", "gazehdr.bench.pipeline"):
            raise UsageError("the bench command is not part of this installation") from None
        raise UsageError(f"bench needs the module {e.name!r}: install gazehdr[bench]") from None
    return int(bench.main(extra) or 0)


def _bench_live(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.bench.live import main as bench_live

    return bench_live(extra)


# --- import / export --------------------------------------------------------------------------


def _import(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.drivers.formats import import_main

    return import_main(extra)


def _experiment(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.experiment.cli import main as experiment_main

    return experiment_main(extra, data_dir=_data_dir(None))


def _export(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.drivers.formats import export_main

    return export_main(extra)


def _daemon(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.drivers.daemon_cli import daemon_main

    return daemon_main(extra)


def _fuzz(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.fuzz.runner import fuzz_main

    return fuzz_main(extra)


def _devices(args: argparse.Namespace, extra: list[str]) -> int:
    from gazehdr.drivers.hid.devices import devices_main

    return devices_main(extra)


# --- figures ----------------------------------------------------------------------------------


def _figure_numbers(text: str) -> list[int]:
    try:
        return [int(n) for n in text.split(",") if n.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected figure numbers such as 4,5,10, got {text!r}"
        ) from None


def _configure_figures(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="directory for PNGs and index.html")
    _add_size_and_backend(p, (320, 180), "frame size of the simulations")
    p.add_argument(
        "--only",
        type=_figure_numbers,
        metavar="N,N,...",
        help="only these of the paper's figures, from 4 to 12 (default: all)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the acuity noise (default: 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _figures(args: argparse.Namespace, extra: list[str]) -> int:
    import importlib.util

    if importlib.util.find_spec("matplotlib") is None:
        raise UsageError("figures needs matplotlib: pip install 'gazehdr[figures]'")
    from gazehdr.figures import Context, make_figures, select
    from gazehdr.sim.layout import check_frame_size

    if args.seed < 0:
        raise UsageError(f"seed must be a non-negative integer, got {args.seed}")
    check_frame_size(*args.size)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"output {out} exists and is not a directory")
    figures = select(args.only)
    ctx = Context(out, *args.size, args.backend, args.seed)
    summary = make_figures(ctx, figures, progress=not args.quiet)
    print(f"wrote {len(summary.files)} files to {out} in {summary.seconds:.1f} s")
    for key, why in summary.failed.items():
        sys.stderr.write(f"{PROG}: error: Fig. {key} not made: {why}\n")
    return 1 if summary.failed else 0


# --- scenes -----------------------------------------------------------------------------------


def _configure_scenes(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="where uploaded scenes are (default: $GAZEHDR_DATA_DIR or ~/.local/share/gazehdr)",
    )


def _scenes(args: argparse.Namespace, extra: list[str]) -> int:
    """The built-ins, then each upload with its format, size and scale (and its source)."""
    from gazehdr.scenes import builtin_names
    from gazehdr.scenes.decoding import SceneError
    from gazehdr.scenes.library import SceneLibrary

    library = SceneLibrary(_data_dir(args.data_dir))
    for name in builtin_names():
        print(f"{name:24} built-in  cd/m² as drawn")
    for name in sorted(library.uploads()):
        try:
            d = library.describe(name)
        except SceneError as e:
            print(f"{name:24} upload    unreadable: {e}")
            continue
        size = f"{d['width']}×{d['height']}"
        layer = f" layer {d['layer']}" if d["layer"] else ""
        source, note = d["scale_source"], d["scale_note"]
        if not note.startswith(f"{source}:"):  # an estimate's note says "estimate: …" itself
            note = f"{source}: {note}"
        print(
            f"{name:24} upload    {d['format']} {size}{layer} · {d['scale']:.4g} cd/m² per unit "
            f"({note})"
        )
    return 0


# --- dispatch ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Command:
    help: str
    run: Callable[[argparse.Namespace, list[str]], int]
    configure: Callable[[argparse.ArgumentParser], None] | None = None
    #: Unknown arguments go to `run` instead of being an error (for wrapped tools).
    passthrough: bool = False
    epilog: str | None = None


COMMANDS: dict[str, Command] = {
    "serve": Command(
        "serve the live viewer: the simulation in a browser, the mouse as gaze",
        _serve,
        _configure_serve,
        epilog="examples:\n"
        "  gazehdr serve                      # the demo on http://127.0.0.1:8000\n"
        "  gazehdr serve --scene night.exr --size 1280x720\n"
        "  gazehdr serve --gaze remote --host 0.0.0.0 --token SECRET",
    ),
    "render": Command(
        "render a scene along a gaze track to PNG/EXR frames",
        _render,
        _configure_render,
        epilog="examples:\n"
        "  gazehdr render flash --out out/flash\n"
        "  gazehdr render night.exr --gaze 0.3,0.6 --seconds 10 --exr --out out/night\n"
        "  gazehdr render lamp --gaze gaze.csv --backend reference --out out/lamp",
    ),
    "bench": Command("benchmark the simulator (arguments pass through)", _bench, passthrough=True),
    "bench-live": Command(
        "benchmark the live server with a real browser (arguments pass through)",
        _bench_live,
        passthrough=True,
    ),
    "import": Command(
        "convert a recording (a BIDS dataset's run, EyeLink .asc, Pupil gaze_positions.csv, "
        "Tobii .tsv) into a session log (arguments pass through; see 'gazehdr import --help')",
        _import,
        passthrough=True,
    ),
    "experiment": Command(
        "the paper's Sec. 4 experiments: 'run PRESET|FILE --out DIR' serves the page (or runs "
        "headless with a simulated observer), 'analyse RESULTS...' fits PSEs into an HTML report, "
        "'recovery' checks the fit recovers a simulated observer's PSE (see "
        "'gazehdr experiment --help')",
        _experiment,
        passthrough=True,
    ),
    "export": Command(
        "write a session log as a run of a BIDS eye-tracking dataset (see 'gazehdr export --help')",
        _export,
        passthrough=True,
    ),
    "daemon": Command(
        f"stream gaze ({registry.choices(registry.STREAM)}) to a server's /ws/gaze "
        "(arguments pass through; see 'gazehdr daemon --help')",
        _daemon,
        passthrough=True,
    ),
    "devices": Command(
        "list HID eye trackers (usage page 0x12) and why other devices are skipped "
        "(arguments pass through; see 'gazehdr devices --help')",
        _devices,
        passthrough=True,
    ),
    "fuzz": Command(
        "fuzz the parsers (EXR upload, HID, session log, importers, both WebSocket protocols) "
        "with atheris, each target in a child process (see 'gazehdr fuzz --help')",
        _fuzz,
        passthrough=True,
    ),
    "figures": Command(
        "reproduce the paper's Figures 4-12 as PNGs and an index.html",
        _figures,
        _configure_figures,
        epilog="examples:\n"
        "  gazehdr figures --out figs\n"
        "  gazehdr figures --out figs --only 4,5 --size 640x360",
    ),
    "scenes": Command(
        "list the scenes: built-ins and uploads, with their scale", _scenes, _configure_scenes
    ),
}


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Gaze-adaptive HDR display: simulates adaptation, afterimages and mesopic "
        "vision (Jacobs et al. 2015) on an ordinary monitor.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, command in COMMANDS.items():
        p = sub.add_parser(
            name,
            help=command.help,
            description=command.help,
            epilog=command.epilog,
            formatter_class=argparse.RawDescriptionHelpFormatter,
            add_help=not command.passthrough,
            error_prog=PROG,
        )
        if command.configure:
            command.configure(p)
    return parser


def _describe(e: Exception) -> str:
    if isinstance(e, OSError) and e.strerror:
        return f"{e.filename}: {e.strerror}" if e.filename else e.strerror
    return str(e)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 usage or input error)."""
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        command = COMMANDS[args.command]
        if extra and not command.passthrough:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        return command.run(args, extra)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except (UsageError, ValueError, OSError) as e:
        sys.stderr.write(f"{PROG}: error: {_describe(e)}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: interrupted\n")
        return 130
