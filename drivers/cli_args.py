"""What the `gazehdr` command lines share about their arguments: the parser whose usage errors
are one line, and the argument types of a screen's size and of a positive length.

It lives in `drivers` because both sides use it: the top-level command line (`gazehdr.cli`),
`gazehdr import`/`export` (`gazehdr.drivers.formats`) and `gazehdr daemon`
(`gazehdr.drivers.daemon_cli`); `drivers` never imports the server side.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from typing import Any, NoReturn


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line usage errors, `NAME: error: MESSAGE (see 'PROG --help')` and
    status 2: the message and where to get help, no usage dump.

    NAME is `error_prog`, else the parser's own `prog`: `gazehdr`'s subcommands all start their
    errors with `gazehdr`, `gazehdr import` with its own name. A subparser gets the class, not
    the keyword: pass `error_prog` to `add_parser` as well.
    """

    def __init__(self, *args: Any, error_prog: str | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.error_prog = error_prog

    def error(self, message: str) -> NoReturn:
        name = self.error_prog or self.prog
        sys.stderr.write(f"{name}: error: {message} (see '{self.prog} --help')\n")
        raise SystemExit(2)


def screen_size_arg(text: str) -> tuple[int, int]:
    """argparse type of a size `WxH` in pixels (`x`, `X` or `×`): a screen's (`gazehdr import`,
    `gazehdr daemon`) or a frame's (`gazehdr serve`, `render`, `experiment`)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 1920x1080, got {text!r}")
    return int(match[1]), int(match[2])


def size_list_arg(text: str) -> list[tuple[int, int]]:
    """argparse type of sizes `WxH,WxH,...` (the benchmarks' `--sizes`), each as
    `screen_size_arg` reads it."""
    return [screen_size_arg(part) for part in text.split(",")]


def positive_arg(text: str) -> float:
    """argparse type of a positive number, such as a length in metres."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value
