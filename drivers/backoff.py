"""Connecting with exponential back-off: what a live source does while its tracker (a HID
device, Pupil Capture) is not there. One loop for every source, its clock and sleep injectable,
its messages on the caller's logger (the one `gazehdr daemon` prints for that source)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def retry(
    attempt: Callable[[], T],
    *,
    name: str,
    missing: str,
    closed: Callable[[], bool],
    log: logging.Logger,
    initial_s: float,
    max_s: float,
    give_up_after_s: float | None,
    sleep: Callable[[float], None],
    clock: Callable[[], float],
) -> T | None:
    """`attempt()` until it returns; after each OSError a line, "NAME not available (why);
    retrying in S s", and a wait that doubles from `initial_s` up to `max_s`. None once
    `closed()`; OSError "no MISSING for S s: why" when `give_up_after_s` (seconds of `clock`)
    have passed."""
    delay = initial_s
    start = clock()
    while not closed():
        try:
            return attempt()
        except OSError as e:
            waited = clock() - start
            if give_up_after_s is not None and waited >= give_up_after_s:
                raise OSError(f"no {missing} for {waited:.1f} s: {e}") from e
            log.info("%s not available (%s); retrying in %.2f s", name, e, delay)
            sleep(delay)
            delay = min(delay * 2.0, max_s)
    return None
