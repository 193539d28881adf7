"""`gazehdr fuzz`: run fuzz targets, each in its own child process, for a time or a count.

Each target's child (`gazehdr.fuzz.worker`) is libFuzzer under atheris. It reads a scratch
corpus (where it keeps new inputs) and the repository's seeds, `tests/fuzz_corpus/TARGET/`
(read only: the seeds, and the reproducers of every crash found so far, so each run replays
them first). A crash stops the child; its input is kept as `OUT/crashes/TARGET/crash-SHA1`
(`timeout-`, `oom-` for a hang or a memory blow-up) with libFuzzer's log beside it, and with
`--keep-going` the target is started again until its budget is spent. The exit status is 1
when any target crashed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from gazehdr.drivers.cli_args import OneLineParser
from gazehdr.fuzz.targets import TARGETS

#: The repository's corpus, when running from a checkout (tests/ is not installed).
REPO_CORPUS = Path(__file__).resolve().parents[2] / "tests" / "fuzz_corpus"
_RUNS = re.compile(r"stat::number_of_executed_units:\s*(\d+)")
_DONE = re.compile(r"Done (\d+) runs in")
_ARTIFACT = re.compile(r"Test unit written to (\S+)")


@dataclass
class Result:
    target: str
    runs: int = 0
    seconds: float = 0.0
    crashes: list[tuple[Path, str]] = field(default_factory=list)  # distinct: (reproducer, what)


def _what(log: str) -> tuple[str, str]:
    """(signature, one line saying what the crash was), from the child's output: the
    signature (the exception's type and the innermost frame of our code) tells a new crash
    from one found already."""
    if "Uncaught Python exception" in log:
        tail = log.split("Uncaught Python exception", 1)[1].splitlines()
        frames = [ln.strip() for ln in tail if ln.strip().startswith("File ")]
        ours = [f for f in frames if "/site-packages/" not in f and "/lib/python" not in f]
        error = next((ln for ln in tail if re.match(r"^[\w.]*(Error|Exception|Exit)\b", ln)), "")
        where = (ours or frames or [""])[-1]
        kind = error.split(":", 1)[0] or "Python exception"
        return f"{kind} {where}", f"{error[:200]} ({where})"
    for pattern in (r"ERROR: libFuzzer: (.*)", r"==\d+== ERROR: (.*)"):
        m = re.search(pattern, log)
        if m:
            what = m.group(1).strip()
            return re.sub(r"\d+", "N", what), what
    return "died", "the child died without a libFuzzer report"


def run_target(
    name: str,
    out: Path,
    *,
    runs: int | None,
    seconds: float | None,
    timeout_s: int = 10,
    rss_mb: int = 2048,
    keep_going: bool = False,
    corpus: Path | None = REPO_CORPUS,
    quiet: bool = False,
    seed: int | None = None,
) -> Result:
    """Fuzz one target until `runs` inputs or `seconds` have been spent (crashes included)."""
    target = TARGETS[name]
    result = Result(name)
    work = out / "corpus" / name
    crashes = out / "crashes" / name
    logs = out / "logs"
    for d in (work, crashes, logs):
        d.mkdir(parents=True, exist_ok=True)
    seeds = corpus / name if corpus is not None else None
    seen: set[str] = set()
    start = time.monotonic()
    for attempt in range(1000):
        args = [
            sys.executable, "-m", "gazehdr.fuzz.worker", name,
            f"-artifact_prefix={crashes}/", f"-timeout={timeout_s}", f"-rss_limit_mb={rss_mb}",
            f"-max_len={target.max_len}", "-print_final_stats=1",
            str(work),
        ]  # fmt: skip
        if seeds is not None and seeds.is_dir():
            args.append(str(seeds))
        if seed is not None:
            args.append(f"-seed={seed + attempt}")
        if runs is not None:
            args.append(f"-runs={max(runs - result.runs, 0)}")
        if seconds is not None:
            left = seconds - (time.monotonic() - start)
            args.append(f"-max_total_time={max(int(left), 1)}")
        log_path = logs / f"{name}-{attempt}.log"
        with (
            open(log_path, "w+") as log_file,
            tempfile.TemporaryDirectory(prefix="gazehdr-fuzz-") as scratch,
        ):
            env = {**os.environ, "GAZEHDR_FUZZ_SCRATCH": scratch}
            proc = subprocess.run(
                args, stdout=log_file, stderr=subprocess.STDOUT, env=env, check=False
            )
            log_file.seek(0)
            log = log_file.read()
        done = _RUNS.findall(log) or _DONE.findall(log)
        result.runs += int(done[-1]) if done else 0
        if proc.returncode != 0:
            found = _ARTIFACT.findall(log)
            reproducer = Path(found[-1]) if found else log_path
            signature, what = _what(log)
            if found:
                shutil.copy(log_path, reproducer.with_name(reproducer.name + ".log"))
            if signature not in seen:
                seen.add(signature)
                result.crashes.append((reproducer, what))
                if not quiet:
                    print(f"{name}: CRASH {what}\n  reproducer: {reproducer}", flush=True)
        spent = time.monotonic() - start
        out_of_budget = (runs is not None and result.runs >= runs) or (
            seconds is not None and spent >= seconds - 1
        )
        if proc.returncode == 0 or not keep_going or out_of_budget:
            break
    result.seconds = time.monotonic() - start
    return result


def fuzz_main(argv: Sequence[str] | None = None) -> int:
    parser = OneLineParser(
        prog="gazehdr fuzz",
        description="Fuzz gazehdr's parsers with atheris (libFuzzer), each target in a child "
        "process. Targets: " + ", ".join(f"{t.name} ({t.what})" for t in TARGETS.values()),
        epilog="A crash is any exception but the target's documented errors, a hang past "
        "--timeout, memory past --rss-mb, or the child's death (a C++ crash). Examples:\n"
        "  gazehdr fuzz exr hid --runs 100000 --out fuzz-out\n"
        "  gazehdr fuzz --seconds 60 --keep-going",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("targets", nargs="*", metavar="TARGET", help="default: all")
    budget = parser.add_mutually_exclusive_group(required=True)
    budget.add_argument("--seconds", type=float, help="time per target")
    budget.add_argument("--runs", type=int, help="inputs per target (the corpus included)")
    parser.add_argument("--out", type=Path, help="crashes, logs, the grown corpus (default: temp)")
    parser.add_argument("--corpus", type=Path, default=REPO_CORPUS, help="seeds: DIR/TARGET/")
    parser.add_argument("--timeout", type=int, default=10, help="seconds per input (default 10)")
    parser.add_argument("--rss-mb", type=int, default=2048, help="memory limit (default 2048)")
    parser.add_argument("--keep-going", action="store_true", help="restart a target on a crash")
    args = parser.parse_args(argv)
    unknown = [t for t in args.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(TARGETS)}")
    out = args.out or Path(tempfile.mkdtemp(prefix="gazehdr-fuzz-out-"))
    crashed = 0
    for name in args.targets or list(TARGETS):
        r = run_target(
            name, out, runs=args.runs, seconds=args.seconds, timeout_s=args.timeout,
            rss_mb=args.rss_mb, keep_going=args.keep_going, corpus=args.corpus,
        )  # fmt: skip
        crashed += bool(r.crashes)
        print(f"{name}: {r.runs} inputs in {r.seconds:.0f} s, {len(r.crashes)} distinct crash(es)")
    print(f"output: {out}")
    return 1 if crashed else 0
