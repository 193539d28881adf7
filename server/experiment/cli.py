"""`gazehdr experiment run PRESET|FILE --out DIR`: serve the experiment's page (and print its
address), or with `--headless` run it without a browser through the same trial code, answered by
simulated observers: the model observer (it judges the frames; what it answers is the model's
prediction, printed beside the paper's results) or the echo observer (`--simulated-observer
echo --pse ...`: it answers from the PSEs it is given, a pipeline check) (docs/experiments.md,
docs/cli.md)."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from pathlib import Path

from gazehdr.drivers.cli_args import screen_size_arg
from gazehdr.drivers.errors import InputError
from gazehdr.experiment import commands as analysis_commands
from gazehdr.experiment.brightness import BLOCH_S, HK_METHODS
from gazehdr.experiment.design import PRESETS, load_design
from gazehdr.experiment.observer import WEBER, EchoObserver, ModelObserver


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
            raise InputError(
                f"--pse {part!r}: give CONDITION=PSE (log10 units), e.g. control=0,manipulated=0.1"
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
        "--headless",
        action="store_true",
        help="no browser: simulated observers answer (the model observer by default)",
    )
    run.add_argument(
        "--simulated-observer",
        choices=("model", "echo"),
        default="model",
        help="model: judges the frames shown, its answers a prediction (default); echo: "
        "answers from the PSEs given with --pse, a pipeline check",
    )
    run.add_argument(
        "--observers",
        type=int,
        default=None,
        metavar="N",
        help="simulated observers, seeds --seed, --seed+1, ... (default: the paper's 11 for "
        "4.1, 10 for 4.2; 1 for other designs)",
    )
    run.add_argument(
        "--weber",
        type=float,
        default=WEBER,
        help=f"model observer's Weber fraction (default: {WEBER})",
    )
    run.add_argument(
        "--window",
        type=float,
        default=BLOCH_S,
        metavar="S",
        help="model observer's summation window, s; inf: the whole interval "
        f"(default: {BLOCH_S:g}, Bloch's critical duration)",
    )
    run.add_argument(
        "--hk",
        choices=tuple(HK_METHODS),
        default="VAC",
        help="model observer's Helmholtz-Kohlrausch estimate (Nayatani 1997; default: VAC)",
    )
    run.add_argument(
        "--pse", metavar="COND=PSE,...", help="echo observer's PSEs, e.g. control=0,manipulated=0.1"
    )
    run.add_argument("--sigma", type=float, default=0.08, help="echo observer's slope (log10)")
    run.add_argument(
        "--lapse", type=float, default=None, help="lapse rate (default: 0.02 echo, 0 model)"
    )
    run.add_argument(
        "--observer",
        default="sim",
        help="observer id of a headless run; with several, the prefix of sim01, sim02, ... "
        "(default: sim)",
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
        return _headless(args, design)
    for given, flag in ((args.pse, "--pse"), (args.observers, "--observers")):
        if given is not None:
            raise InputError(f"{flag} is for --headless runs: people answer the page")
    from gazehdr.experiment.service import ExperimentConfig
    from gazehdr.serve import serve

    if data_dir is None:
        raise InputError("serving needs serve's data folder: run it as 'gazehdr experiment'")
    experiment = ExperimentConfig(design, args.out, args.size, args.backend, args.seed)
    return serve(
        host=args.host, port=args.port, scene="flash", scale=None, gaze="mouse", fps=30.0,
        size=(640, 360), fit_viewport=True, params_file=None,
        token=args.token or os.environ.get("GAZEHDR_TOKEN") or None, data_dir=data_dir,
        allow_origins=(), encoding="f16", backend=args.backend, seed=0, auth=not args.no_auth,
        experiment=experiment,
    )  # fmt: skip


def _headless(args: argparse.Namespace, design) -> int:
    """Simulated observers through the trial code, then the group's PSEs and rank-sum beside
    the paper's (the analysis needs the experiment extra: without it, only the results)."""
    if any("palette" in b.repeats for b in design.blocks):
        raise InputError(
            f"{args.design} has palette trials, which a simulated observer cannot answer: "
            "serve it to people (drop --headless), or call run_headless with a palette_chooser"
        )
    echo = args.simulated_observer == "echo"
    if echo and not args.pse:
        raise InputError("--simulated-observer echo needs --pse CONDITION=PSE,...: it answers "
                         "from the PSEs it is given")  # fmt: skip
    if not echo and args.pse:
        raise InputError("the model observer takes no PSE: it judges the frames "
                         "(--pse is for --simulated-observer echo)")  # fmt: skip
    from gazehdr.experiment import prediction

    if echo:
        pse, lapse = parse_pse(args.pse), 0.02 if args.lapse is None else args.lapse

        def make(seed: int):
            return EchoObserver(pse, args.sigma, lapse, seed=seed)
    else:
        lapse = 0.0 if args.lapse is None else args.lapse

        def make(seed: int):
            return ModelObserver(args.weber, args.window, args.hk, lapse, seed=seed)

    text = make(0).describe()  # checks the parameters before anything runs
    n = prediction.participants(design) if args.observers is None else args.observers
    paths = prediction.run_group(
        design, make, args.out, observers=n, seed=args.seed or 0, size=args.size or (96, 54),
        backend=args.backend, prefix=args.observer, run=args.run,
    )  # fmt: skip
    for path in paths:
        print(path)
    try:
        analysis_commands._need_extra()
    except ValueError as e:
        print(f"no PSE summary: {e}")
        return 0
    group = prediction.analyse_group(paths, design.name)
    noiseless = None
    if not echo:
        noiseless = prediction.noiseless_pse(design, make(0), args.size or (96, 54), args.backend)
    print(prediction.summary(design, group, text, model=not echo, noiseless=noiseless))
    return 0
