"""What an object with a life cycle raises when it is called in a state that does not allow the
call: `Delivery` (the daemon's core) and the HID source name their states with an `enum.Enum`
and refuse such a call before changing anything, so that nothing they hold is lost; the Pupil
and LSL sources name their connection's (`Link`)."""

from __future__ import annotations

import enum


class InvalidStateError(RuntimeError):
    """`owner.method()` was called in `state`, which does not allow it; `why` says what does."""

    def __init__(self, owner: str, method: str, state: enum.Enum, why: str) -> None:
        super().__init__(f"{owner}.{method}() in state {state.name}: {why}")
        self.method, self.state = method, state


class Link(enum.Enum):
    """A live source's connection (the Pupil and LSL sources): connect only when DISCONNECTED."""

    DISCONNECTED = enum.auto()
    CONNECTED = enum.auto()
    CLOSED = enum.auto()
