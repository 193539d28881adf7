"""Shared fixtures: a real uvicorn server on loopback, started per test with the given settings."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from gazehdr.app import ServerConfig
from gazehdr.gaze import TrackerFeed
from gazehdr.serve import BackgroundServer
from gazehdr.session import SessionSettings

SESSION_FIELDS = {f.name for f in dataclasses.fields(SessionSettings)}


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[Callable[..., BackgroundServer]]:
    """Factory: `live_server(scene="flash", size=(320, 180), token="t", ...)`.

    Keywords are `SessionSettings` fields (plus `size`) or `ServerConfig` fields. Defaults
    suit a 2-core CI machine: 160×96 frames at 20 fps, session ends when its viewer leaves.
    """
    started: list[BackgroundServer] = []

    def start(**overrides: Any) -> BackgroundServer:
        width, height = overrides.pop("size", (160, 96))
        session = {"width": width, "height": height, "fps": 20.0}
        server: dict[str, Any] = {"data_dir": tmp_path / "data", "session_grace_s": 0.0}
        for key, value in overrides.items():
            (session if key in SESSION_FIELDS else server)[key] = value
        config = ServerConfig(session=SessionSettings(**session), **server)
        live = BackgroundServer(config)
        started.append(live)
        return live

    yield start
    for live in started:
        live.stop()


def sole_tracker(server: BackgroundServer) -> TrackerFeed:
    """The one tracker a test's daemon streamed to `server` as."""
    (feed,) = server.hub.trackers.feeds()
    return feed


def samples_received(server: BackgroundServer) -> int:
    """Samples `server` received from its daemons so far (0 before any has connected)."""
    return sum(feed.samples for feed in server.hub.trackers.feeds())
