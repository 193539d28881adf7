"""`gazehdr experiment run PRESET|FILE --out DIR`: serve the experiment's page (and print its
address), or with `--headless --simulated-observer ...` run it without a browser through the
same trial code (docs/experiments.md, docs/cli.md)."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from pathlib import Path

from gazehdr.drivers.cli_args import screen_size_arg
from gazehdr.experiment import commands as analysis_commands
from gazehdr.experiment.design import PRESETS, load_design
from gazehdr.experiment.observer import SimulatedObserver


def parse_pse(text: str) -> dict[str, float]:
    """`control=0,manipulated=0.1` → {condition: log10 PSE}; names the part that is wrong."""
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name or not math.isfinite(number):
            raise ValueError(
                f"--simulated-observer {part!r}: give CONDITION=PSE (log10 units), "
                "e.g. control=0,manipulated=0.1"
            )
        out[name.strip()] = number
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gazehdr experiment")
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    analysis_commands.add_parsers(sub)  # analyse, recovery
    run = sub.add_parser(
        "run",
        help="serve an experiment's page, or run it headless with a simulated observer",
        description=f"Presets: {', '.join(f'{k} (Sec. {v})' for k, v in PRESETS.items())}.",
    )
    run.add_argument("design", metavar="PRESET|FILE", help="a preset name, 4.1, 4.2, or a .toml")
    run.add_argument("--out", required=True, type=Path, help="the BIDS dataset root for results")
    run.add_argument("--seed", type=int, default=None, help="trial order (default: new per run)")
    run.add_argument(
        "--size",
        type=screen_size_arg,
        default=None,
        help="frame WIDTHxHEIGHT (default: the design's)",
    )
    run.add_argument("--backend", default="opencl", choices=("opencl", "reference"))
    run.add_argument(
        "--headless", action="store_true", help="no browser: needs --simulated-observer"
    )
    run.add_argument(
        "--simulated-observer", metavar="COND=PSE,...", help="e.g. control=0,manipulated=0.1"
    )
    run.add_argument("--sigma", type=float, default=0.08, help="simulated observer's slope (log10)")
    run.add_argument("--lapse", type=float, default=0.02, help="simulated observer's lapse rate")
    run.add_argument(
        "--observer", default="sim", help="observer id of a headless run (default: sim)"
    )
    run.add_argument("--run", type=int, default=None, help="BIDS run number")
    run.add_argument("--host", default="127.0.0.1")
    run.add_argument("--port", type=int, default=8000)
    run.add_argument("--token", default=None, help="bearer token (default: $GAZEHDR_TOKEN or new)")
    run.add_argument("--no-auth", action="store_true", help="ask no credential (loopback only!)")
    return parser  # fmt: skip


def main(argv: Sequence[str] | None = None, data_dir: Path | None = None) -> int:
    """`gazehdr experiment ...`; `data_dir` is serve's (`gazehdr.cli` passes it)."""
    args = build_parser().parse_args(argv)
    if args.action != "run":
        return args.experiment_run(args)
    design = load_design(args.design)
    if args.headless:
        if not args.simulated_observer:
            raise ValueError("--headless needs --simulated-observer: nobody else can answer")
        if any("palette" in b.repeats for b in design.blocks):
            raise ValueError(
                f"{args.design} has palette trials, which the simulated observer cannot answer: "
                "serve it to people (drop --headless), or call run_headless with a palette_chooser"
            )
        from gazehdr.experiment.runner import run_headless

        observer = SimulatedObserver(
            parse_pse(args.simulated_observer), args.sigma, args.lapse, seed=args.seed or 0
        )
        path = run_headless(
            design, observer, args.out, seed=args.seed or 0, size=args.size or (96, 54),
            observer_id=args.observer, backend=args.backend, run=args.run,
        )  # fmt: skip
        print(path)
        return 0
    if args.simulated_observer:
        raise ValueError("--simulated-observer answers only --headless runs")
    from gazehdr.experiment.service import ExperimentConfig
    from gazehdr.serve import serve

    if data_dir is None:
        raise ValueError("serving needs serve's data folder: run it as 'gazehdr experiment'")
    experiment = ExperimentConfig(design, args.out, args.size, args.backend, args.seed)
    return serve(
        host=args.host, port=args.port, scene="flash", scale=None, gaze="mouse", fps=30.0,
        size=(640, 360), fit_viewport=True, params_file=None,
        token=args.token or os.environ.get("GAZEHDR_TOKEN") or None, data_dir=data_dir,
        allow_origins=(), encoding="f16", backend=args.backend, seed=0, auth=not args.no_auth,
        experiment=experiment,
    )  # fmt: skip
