"""The options of `gazehdr`'s subcommands: argparse only, so `gazehdr --help` stays light
(every heavy import is made by the subcommand that needs it, in `gazehdr.cli`)."""

from __future__ import annotations

import argparse

from gazehdr.drivers import registry
from gazehdr.drivers.cli_args import screen_size_arg


def add_model_options(p: argparse.ArgumentParser, whose: str, default: str = "") -> None:
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


def add_size_and_backend(p: argparse.ArgumentParser, size: tuple[int, int], what: str) -> None:
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


def configure_render(p: argparse.ArgumentParser) -> None:
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
    add_size_and_backend(p, (640, 360), "frame size")
    p.add_argument(
        "--seed",
        type=int,
        help="seeds noise, dither and scan path (default: the seed a recorded session ran "
        "with, else 0)",
    )
    add_model_options(p, "", "a recorded session's, else the paper's")
    add_preset_options(p, "a recorded session's, else the paper's: 'paper'")
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="where a recorded session's uploaded scenes are (default: $GAZEHDR_DATA_DIR or "
        "~/.local/share/gazehdr)",
    )
    add_scale_option(p)
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
        "--batch", metavar="MANIFEST.toml", help="logs x models x presets (gazehdr docs cli)"
    )
    batch.add_argument(
        "--workers", type=int, metavar="N", help="local cluster's worker processes (default: cores)"
    )
    batch.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="an existing Dask cluster's scheduler, tcp://HOST:PORT",
    )


def add_scale_option(p: argparse.ArgumentParser) -> None:
    """--scale, the luminance of a scene file's unit (render and serve)."""
    p.add_argument(
        "--scale",
        type=float,
        metavar="CD_PER_UNIT",
        help="cd/m^2 per unit of the scene file (default: its whiteLuminance, else an estimate; "
        "docs/server.md)",
    )


def add_preset_options(p: argparse.ArgumentParser, default: str) -> None:
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


def configure_serve(p: argparse.ArgumentParser) -> None:
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
        "connected), replay:PATH (a recording, EyeLink ASC, BIDS dataset or run, or one of the "
        "server's recordings by name: imported into DATA_DIR/recordings and followed), or a "
        "track: "
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
    add_preset_options(p, "'paper'")
    add_scale_option(p)
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
    add_model_options(p, " of new sessions (the viewer's panel changes it)")
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


def figure_numbers(text: str) -> list[int]:
    try:
        return [int(n) for n in text.split(",") if n.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected figure numbers such as 4,5,10, got {text!r}"
        ) from None


def configure_figures(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="directory for PNGs and index.html")
    add_size_and_backend(p, (320, 180), "frame size of the simulations")
    p.add_argument(
        "--only",
        type=figure_numbers,
        metavar="N,N,...",
        help="only these of the paper's figures, from 4 to 12 (default: all)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the acuity noise (default: 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def configure_scenes(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="where uploaded scenes are (default: $GAZEHDR_DATA_DIR or ~/.local/share/gazehdr)",
    )


def configure_docs(p: argparse.ArgumentParser) -> None:
    p.add_argument("page", nargs="?", help="a page's name, e.g. server, cli, model")
