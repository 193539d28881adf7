"""The one token bucket of gazehdr: the daemon paces what it sends with it
(`gazehdr.drivers.delivery`), the server limits each `/ws/gaze` connection with it
(`gazehdr.app`). It reads no clock: every call says what time it is, so both sides count tokens
the same way and a test can script the time.
"""

from __future__ import annotations

from gazehdr.drivers.errors import InputError


class TokenBucket:
    """`rate` tokens per second on average, at most `burst` at once; starts full.

    Times are seconds on any clock that never goes back (the callers use `time.monotonic`).
    """

    def __init__(self, rate: float, burst: float) -> None:
        if not (rate > 0 and burst >= 1):
            raise InputError(f"rate must be positive and burst at least 1, got {rate}, {burst}")
        self.rate, self.burst = rate, burst
        self.level = burst
        self.at: float | None = None  # when the level was last brought up to date

    def available(self, now: float) -> int:
        """Whole tokens at `now`; nothing is taken."""
        if self.at is not None:  # a full bucket cannot gain: the first call needs no refill
            self.level = min(self.burst, self.level + (now - self.at) * self.rate)
        self.at = now
        return int(self.level)

    def take(self, n: int) -> None:
        """Spend `n` tokens, no more than `available` said there were."""
        self.level -= n

    def admit(self, n: int, now: float) -> int:
        """How many of `n` items may pass at `now`; their tokens are taken."""
        allowed = min(n, self.available(now))
        self.take(allowed)
        return allowed
