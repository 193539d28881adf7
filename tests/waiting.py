"""Waiting for what a test waits for: an event, polled, with a timeout only as a safety net.

Tests on a shared 2-core machine assert on events, counts and orderings, never on how long
something took; the timeout here is generous and, if it ever runs out, says what never happened.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

#: Seconds before a wait gives up: far beyond what anything takes on a loaded machine.
SAFETY_S = 20.0


async def until(predicate: Callable[[], object], what: str, timeout: float = SAFETY_S) -> None:
    """Return once `predicate()` is true; fail naming `what` after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.01)


def wait_until(predicate: Callable[[], object], what: str, timeout: float = SAFETY_S) -> None:
    """`until`, for code that is not on an event loop."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.01)
