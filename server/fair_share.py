"""Each connection's fair share of the server: what one viewer (`/ws/view`) or daemon
(`/ws/gaze`) sends cannot take the event loop or the sessions' steps from the others.

Pure: every call says what time it is. The endpoints (`gazehdr.app`, `gazehdr.gaze_link`) ask
`admit` before they parse a message; over the connection's rate they stop reading it for as
long as its bucket needs to refill, so the socket's flow control holds the sender back: nothing
is dropped, and a flood costs the server one wait, not a parse and a reply per message (a
malformed-text flood took another session from 28.7 to 12.5 fps with 240k error replies). Messages
that make a session do work (a reset settles the retina, a parameter or model change rebuilds
the eye) pass a second, slower bucket. Error replies pass a third: a client that errs now and
then hears of each error, a flood of errors gets a few replies a second, each saying how many
were left out.
"""

from __future__ import annotations

from gazehdr.drivers.ratelimit import TokenBucket

#: Messages a second a viewer sends: its pointer at the display's rate (up to 240 Hz), an
#: ack per frame, a few controls. Four times that; a burst of two seconds.
VIEW_RATE = 1000.0
VIEW_BURST = 2000.0
#: What makes a session work: a reset (the next step settles the retina: about fifty blurs of
#: its state), a parameter, scene, model, source or frame-size change (the eye is rebuilt). A
#: person clicking the panel sends a few a second at most.
WORK_RATE = 4.0
WORK_BURST = 12.0
#: Messages a second a daemon's connection is read at, parsed or not: above the sum of the
#: per-kind limits on what parses (`gaze_link`: samples, events, echoes), which go on holding a
#: real daemon back; this bounds what does not parse.
DAEMON_RATE = 5000.0
DAEMON_BURST = 10000.0
#: Error replies a second, and at once.
ERROR_RATE = 2.0
ERROR_BURST = 10.0


class ConnectionShare:
    """One connection's budget: `admit` before parsing, `work` for messages that make a
    session work, `error` before replying with an error. Seconds on any clock that never
    goes back (the endpoints use `time.monotonic`)."""

    def __init__(
        self,
        rate: float,
        burst: float,
        work_rate: float = WORK_RATE,
        work_burst: float = WORK_BURST,
    ) -> None:
        self.messages = TokenBucket(rate, burst)
        self.work_bucket = TokenBucket(work_rate, work_burst)
        self.error_bucket = TokenBucket(ERROR_RATE, ERROR_BURST)
        self.errors_left_out = 0

    def admit(self, now: float) -> float:
        """Take a message's token: 0 if there was one, else nothing is taken and the seconds
        until there is one are returned: stop reading for that long, then ask again."""
        return _wait(self.messages, now)

    def work(self, now: float) -> float:
        """As `admit`, for a message that makes the session work."""
        return _wait(self.work_bucket, now)

    def error(self, now: float) -> int | None:
        """Whether to send an error reply now: None if not (it is counted), else how many
        were left out before it (to say so in the reply)."""
        if not self.error_bucket.admit(1, now):
            self.errors_left_out += 1
            return None
        left_out, self.errors_left_out = self.errors_left_out, 0
        return left_out


def _wait(bucket: TokenBucket, now: float) -> float:
    """Take one token: 0 if there was one; else the seconds until there is."""
    if bucket.admit(1, now):
        return 0.0
    return (1.0 - bucket.level) / bucket.rate + 1e-6  # past the token, not a rounding short


def error_text(message: str, left_out: int) -> str:
    """An error reply's text, with the errors left out since the last one."""
    if not left_out:
        return message
    return f"{message} ({left_out} more errors since the last one were not answered)"
