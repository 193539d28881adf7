"""Driving a `Session` as `gazehdr.live` does, without its event loop or threads."""

from __future__ import annotations

import time
from typing import Any

from gazehdr.protocol import Control
from gazehdr.scenes.library import SceneLibrary
from gazehdr.session import Frame, Session, SessionSettings


def new_session(settings: SessionSettings, name: str = "test", **options: Any) -> Session:
    return Session(name, settings, SceneLibrary(), clock=time.perf_counter, **options)


def tick(
    session: Session, dt: float, controls: list[tuple[Control, float]]
) -> tuple[Frame, list[dict[str, Any]]]:
    """One step after `controls` arrived: as `LiveSession.submit` routes them, the viewer's
    pointer and eyes go to the session's pointer, everything else is a control of the step.
    The JSON notes only: scene maps (bytes) are left out."""
    queued = [(c, at) for c, at in controls if not session.pointer.take(c, at)]
    frame, notes = session.tick(dt, queued)
    return frame, [n for n in notes if isinstance(n, dict)]
