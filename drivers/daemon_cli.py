"""`gazehdr daemon ...`: the command line of the gaze daemon (`gazehdr.drivers.daemon`).

It owns the flags (`build_parser`; the screen's through `gazehdr.drivers.cli_args`, as
`gazehdr import` reads them), where a long-running daemon records by default
(`$GAZEHDR_RECORD_DIR`), the logging to stderr, the exit status, and the signals: SIGTERM and
Ctrl-C stop the daemon as `Daemon.stop()` does, the buffer draining for at most
`SIGNAL_DRAIN_S`, with its summary. `gazehdr daemon` (`gazehdr.cli`) runs `daemon_main`.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from typing import Any

from gazehdr.drivers import registry
from gazehdr.drivers.cli_args import OneLineParser, positive_arg, screen_size_arg
from gazehdr.drivers.daemon import Daemon, UnauthorizedError
from gazehdr.drivers.delivery import DEFAULT_BUFFER, DEFAULT_MAX_INFLIGHT, DaemonError, DaemonStats
from gazehdr.drivers.fixations import DETECTORS
from gazehdr.drivers.registry import SourceUnavailableError, open_source
from gazehdr.drivers.samples import ScreenGeometry
from gazehdr.drivers.sources import SourceInfo

log = logging.getLogger("gazehdr.daemon")  # the daemon's own logger: one handler shows both

#: After SIGTERM or Ctrl-C, how long the buffer may still drain: well inside the 10 s that
#: `docker stop` waits before SIGKILL, so the summary is printed and the log closed.
SIGNAL_DRAIN_S = 3.0
RECORD_DIR_ENV = "GAZEHDR_RECORD_DIR"


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="gazehdr daemon",
        description="Stream gaze from a tracker (or a recording, or a synthetic scan path) to a "
        "gazehdr server; sessions that follow its tracker (gaze source remote:TRACKER, the name "
        "its hello gives) follow its fixations. SIGTERM and "
        f"Ctrl-C stop it after at most {SIGNAL_DRAIN_S:g} s more of delivery, with a summary.",
        epilog="examples:\n"
        "  gazehdr daemon --source synthetic --server ws://127.0.0.1:8000 --token T\n"
        "  gazehdr daemon --source replay:session.jsonl@2 --server ws://HOST:8000\n"
        "  gazehdr daemon --source hid --record today.jsonl   # token from $GAZEHDR_TOKEN\n"
        "  gazehdr daemon --source hid --screen 2560x1440 --distance 0.65 --record-dir /data\n"
        "  gazehdr daemon --source lsl:Tobii --lsl-outlet --server ws://HOST:8000",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--source",
        default="synthetic",
        help=f"{registry.describe(registry.STREAM)} (default: synthetic). hid waits for a "
        "tracker to be plugged in, pupil for Pupil Capture to answer",
    )
    p.add_argument(
        "--server",
        default=os.environ.get("GAZEHDR_SERVER"),
        help="the server, ws://HOST:PORT (default: $GAZEHDR_SERVER)",
    )
    p.add_argument(
        "--token",
        default=os.environ.get("GAZEHDR_TOKEN"),
        help="bearer token 'gazehdr serve' printed (default: $GAZEHDR_TOKEN)",
    )
    record = p.add_mutually_exclusive_group()
    record.add_argument(
        "--record", metavar="FILE", help="also write every sample and event here (a new file)"
    )
    record.add_argument(
        "--record-dir",
        metavar="DIR",
        help="also write every sample and event to a new DIR/gaze-YYYYmmddTHHMMSSZ.jsonl (UTC) "
        f"each run (default: ${RECORD_DIR_ENV}, unless --record is given)",
    )
    p.add_argument(
        "--name",
        metavar="NAME",
        help="the tracker's name on the server, which sessions follow it by (gaze source "
        "remote:NAME); give each station its own (default: the source's, e.g. 'synthetic (seed "
        "0)' or the HID tracker's product)",
    )
    p.add_argument(
        "--lsl-outlet",
        nargs="?",
        const="gazehdr",
        metavar="NAME",
        help="also publish on Lab Streaming Layer, for LabRecorder: the samples as a Gaze stream "
        "NAME (default: gazehdr) and the fixation and blink events as a Markers stream "
        "'NAME events' (needs gazehdr[lsl])",
    )
    p.add_argument(
        "--min-confidence",
        type=_confidence_arg,
        metavar="C",
        help=f"{' and '.join(registry.with_confidence())} sources: a sample whose confidence is "
        "below C (0 to 1) is invalid (default 0.6, Pupil Player's own)",
    )
    p.add_argument("--detector", choices=sorted(DETECTORS), default="ivt", help="default: ivt")
    p.add_argument(
        "--screen",
        type=screen_size_arg,
        metavar="WxH",
        help="the tracked screen's size in pixels (default 1920x1080)",
    )
    p.add_argument(
        "--diagonal",
        type=positive_arg,
        metavar="M",
        help="its diagonal in metres (default: a HID tracker's calibrated size, else 0.6)",
    )
    p.add_argument(
        "--distance",
        type=positive_arg,
        metavar="M",
        help="viewing distance in metres (default 1.0)",
    )
    p.add_argument(
        "--buffer",
        type=int,
        default=DEFAULT_BUFFER,
        metavar="N",
        help=f"items (samples and events) kept while the server is away, the oldest dropped "
        f"first (default: {DEFAULT_BUFFER}); with the up to {DEFAULT_MAX_INFLIGHT} sent but not "
        f"yet acknowledged, at most N + {DEFAULT_MAX_INFLIGHT} items are held in memory",
    )
    p.add_argument("--rate", type=float, metavar="HZ", help="synthetic source's sampling rate")
    p.add_argument(
        "--accuracy-deg",
        type=positive_arg,
        metavar="DEG",
        help="the tracker's accuracy in degrees (calibration or data sheet), sent in the hello: "
        "the server's sessions take it as tracker_accuracy_deg (default: not sent)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    return p


def _confidence_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 1, got {text!r}") from None
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 1, got {text!r}")
    return value


def _screen_flags(args: argparse.Namespace) -> dict[str, float]:
    """--screen, --diagonal, --distance as `ScreenGeometry` fields (see `open_source`)."""
    screen: dict[str, float] = {}
    if args.screen is not None:
        screen["screen_width_px"], screen["screen_height_px"] = args.screen
    if args.diagonal is not None:
        screen["screen_diagonal_m"] = args.diagonal
    if args.distance is not None:
        screen["viewing_distance_m"] = args.distance
    return screen


def _warn_unused_screen(info: SourceInfo, screen: Mapping[str, float]) -> None:
    used = asdict(info.geometry)
    kept = [f"{name} {used[name]:g}" for name, value in screen.items() if used[name] != value]
    if kept:
        log.warning(
            "the recording's own screen geometry is used (%s): --screen, --diagonal and "
            "--distance fill in only what a recording does not record",
            ", ".join(kept),
        )


def _lsl_outlet(name: str, info: SourceInfo) -> Any:
    """The daemon's LSL outlets (`gazehdr.drivers.lsl.outlet`), publishing `info`'s gaze."""
    try:
        from gazehdr.drivers.lsl.outlet import GazeOutlets, default_source_id

        return GazeOutlets(
            name,
            source_id=default_source_id("daemon", name),
            geometry=info.geometry,
            model=info.name,
            application="gazehdr daemon",
            rate_hz=info.rate_hz,
            monotonic=info.live,
        )
    except ImportError as e:
        raise SourceUnavailableError(f"LSL outlet unavailable: {e}") from None


async def _run_until_signalled(daemon: Daemon) -> tuple[DaemonStats, int | None]:
    """Run `daemon`; SIGTERM or Ctrl-C stops it as `stop()` does, the buffer draining for at
    most `SIGNAL_DRAIN_S`; a second one stops it at once. Returns the stats and the signal."""
    loop = asyncio.get_running_loop()
    got: list[int] = []

    def on_signal(signum: int) -> None:
        log.warning("%s: stopping%s", signal.Signals(signum).name, " now" if got else "")
        daemon.stop(drain_timeout=0.0 if got else SIGNAL_DRAIN_S)
        got.append(signum)

    installed = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(signum, on_signal, signum)
        except (NotImplementedError, RuntimeError):  # Windows, or not the main thread
            continue
        installed.append(signum)
    try:
        stats = await daemon.run()
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)
    return stats, got[0] if got else None


def daemon_main(argv: Sequence[str] | None = None) -> int:
    """`gazehdr daemon ...`: 0 when the source ended or SIGTERM stopped it, 1 on a failing
    source, 2 on bad input or a refused token, 130 on Ctrl-C."""
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = "gazehdr daemon"
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{prog}: %(message)s"))
    loggers = (
        log,
        logging.getLogger("gazehdr.drivers.hid"),
        logging.getLogger("gazehdr.drivers.pupil"),
        logging.getLogger("gazehdr.drivers.lsl"),
    )  # the tracker's (or stream's) waits, unplugs and losses, too
    before = [(logger.level, logger.propagate) for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(logging.WARNING if args.quiet else logging.INFO)
        logger.propagate = False
    signalled: int | None = None
    outlet: Any = None
    try:
        if not args.server:
            parser.error("--server (or $GAZEHDR_SERVER) is required")
        if not args.token:
            parser.error("--token (or $GAZEHDR_TOKEN) is required")
        if args.buffer < 1:
            parser.error(f"--buffer must be a positive number of items, got {args.buffer}")
        record_dir = args.record_dir
        if record_dir is None and args.record is None:
            record_dir = os.environ.get(RECORD_DIR_ENV) or None
        screen = _screen_flags(args)
        try:
            replace(ScreenGeometry(), **screen)
        except ValueError as e:  # --screen 0x1080; --diagonal and --distance are checked already
            parser.error(f"--screen: {e}")
        options = {} if args.min_confidence is None else {"min_confidence": args.min_confidence}
        source = open_source(args.source, rate_hz=args.rate, screen=screen, wait=True, **options)
        _warn_unused_screen(source.info, screen)
        if args.lsl_outlet is not None:
            outlet = _lsl_outlet(args.lsl_outlet, source.info)
        daemon = Daemon(
            source,
            args.server,
            args.token,
            record=args.record,
            record_dir=record_dir,
            detector=args.detector,
            buffer=args.buffer,
            status_interval=10.0,
            name=args.name,
            outlet=outlet,
            accuracy_deg=args.accuracy_deg,
        )
        stats, signalled = asyncio.run(_run_until_signalled(daemon))
    except UnauthorizedError as e:
        sys.stderr.write(f"{prog}: error: {e}\n")
        return 2
    except (DaemonError, SourceUnavailableError, ValueError, OSError) as e:
        what = f"{e.filename}: {e.strerror}" if isinstance(e, OSError) and e.strerror else str(e)
        sys.stderr.write(f"{prog}: error: {what}\n")
        return 2
    except KeyboardInterrupt:  # before the daemon ran (waiting for a tracker)
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130
    finally:
        if outlet is not None:
            outlet.close(wait=True)
        for logger, (level, propagate) in zip(loggers, before, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)
            logger.propagate = propagate
    sys.stderr.write(f"{prog}: {stats.summary()}\n")
    if stats.source_error:
        sys.stderr.write(f"{prog}: error: source failed: {stats.source_error}\n")
        return 1
    return 130 if signalled == signal.SIGINT else 0
