"""The `gazehdr` command line: one small function per subcommand, listed in `COMMANDS`.

Only the standard library, `drivers` and the options (`cli_options`) are imported up front;
each subcommand imports what it needs when it runs, so `gazehdr --help` (and `gazehdr daemon` on
a tracker machine without pyopencl) works on a minimal install. A refusal (`GazehdrError`)
prints one line, `gazehdr: error: …`, and exits with status 2; anything else is a bug, shown
with its traceback (status 3); `main` returns the status instead of exiting.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from gazehdr import __version__
from gazehdr import cli_options as options
from gazehdr.drivers import registry
from gazehdr.drivers.cli_args import OneLineParser
from gazehdr.drivers.errors import GazehdrError

PROG = "gazehdr"


class UsageError(GazehdrError):
    """A mistake in what the user asked for; reported in one line with status 2."""


def _data_dir(given: str | None) -> Path:
    return Path(given or os.environ.get("GAZEHDR_DATA_DIR") or Path.home() / ".local/share/gazehdr")


# --- render -----------------------------------------------------------------------------------


def _render_defaults() -> dict[str, object]:
    """The render options' defaults: a batch manifest's values replace these, not given ones."""
    p = argparse.ArgumentParser()
    options.configure_render(p)
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


def _docs(args: argparse.Namespace, extra: list[str]) -> int:
    from importlib import resources

    folder = resources.files("gazehdr.docs")
    pages = sorted(p.name.removesuffix(".md") for p in folder.iterdir() if p.name.endswith(".md"))
    if args.page is None:
        print(f"{folder}: {', '.join(pages)} (README is the index)")
        return 0
    name = args.page.removesuffix(".md")
    if name not in pages:
        raise UsageError(f"no page {args.page!r}; the pages: {', '.join(pages)}")
    print(folder / f"{name}.md")
    return 0


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
        options.configure_serve,
        epilog="examples:\n"
        "  gazehdr serve                      # the demo on http://127.0.0.1:8000\n"
        "  gazehdr serve --scene night.exr --size 1280x720\n"
        "  gazehdr serve --gaze remote --host 0.0.0.0 --token SECRET",
    ),
    "render": Command(
        "render a scene along a gaze track to PNG/EXR frames",
        _render,
        options.configure_render,
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
        options.configure_figures,
        epilog="examples:\n"
        "  gazehdr figures --out figs\n"
        "  gazehdr figures --out figs --only 4,5 --size 640x360",
    ),
    "scenes": Command(
        "list the scenes: built-ins and uploads, with their scale",
        _scenes,
        options.configure_scenes,
    ),
    "docs": Command(
        "where the documentation installed with gazehdr is: its pages, or PAGE's file",
        _docs,
        options.configure_docs,
        epilog="examples:\n  gazehdr docs             # the pages\n  gazehdr docs server",
    ),
}


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Gaze-adaptive HDR display: simulates adaptation, afterimages and mesopic "
        "vision (Jacobs et al. 2015) on an ordinary monitor.",
        epilog="The documentation is installed with gazehdr: 'gazehdr docs' says where.",
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


#: The exit status of a bug: an exception that is no deliberate refusal.
BUG_STATUS = 3


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status: 0 ok, 2 a refusal (bad input, usage, a
    file that cannot be read: one line says why), 3 a bug (its traceback, and how to report
    it), 130 interrupted."""
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        command = COMMANDS[args.command]
        if extra and not command.passthrough:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        return command.run(args, extra)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except (GazehdrError, OSError) as e:
        sys.stderr.write(f"{PROG}: error: {_describe(e)}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: interrupted\n")
        return 130
    except Exception:  # not a refusal of ours: a bug, shown as one
        traceback.print_exc()
        sys.stderr.write(
            f"{PROG}: this is a bug in gazehdr {__version__}, not a mistake of yours: please "
            "report it with the traceback above and the command you ran\n"
        )
        return BUG_STATUS
