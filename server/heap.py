"""The C heap of a long-running server (glibc): what keeps a session's memory after it ends.

glibc keeps freed heap pages for reuse, and gives each thread that contends for the heap an
arena of its own (up to 8 per core). A session's frames and scene copies are many megabytes
freed in small pieces among other allocations, on the session's stepping thread, so without
help the server stays near its peak after sessions end. Two calls fix that, both no-ops where
the C library is not glibc. Measured with tests/session_memory.py (docs/server.md#memory).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Callable

M_ARENA_MAX = -8  # mallopt's parameter number (glibc malloc.h)
#: Arenas the server's threads share. 2 took the memory after 8 sessions of 640×360 back to
#: within 2% of idle, where the default left it 6-19% above (ours: measured, one run each).
ARENAS = 2


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name) if name else None
    except OSError:
        return None


def _function(name: str) -> Callable[..., int] | None:
    libc = _libc()
    return getattr(libc, name, None) if libc is not None else None


def limit_arenas(arenas: int = ARENAS) -> bool:
    """At most `arenas` malloc arenas for the process; call before the threads start. False
    where this is not glibc."""
    mallopt = _function("mallopt")
    return mallopt is not None and mallopt(M_ARENA_MAX, arenas) == 1


def trimmer() -> Callable[[], None] | None:
    """glibc's `malloc_trim(0)` (every arena's free pages back to the system), or None."""
    trim = _function("malloc_trim")
    return None if trim is None else (lambda: trim(0))
