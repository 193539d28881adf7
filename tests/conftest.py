"""Shared fixtures: a real uvicorn server on loopback, started per test with the given settings."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import uvicorn

from server.app import ServerConfig, create_app
from server.serve import WS_MAX_MESSAGE
from server.session import SessionSettings

SESSION_FIELDS = {f.name for f in dataclasses.fields(SessionSettings)}


class LiveServer:
    """`create_app(config)` served by uvicorn on 127.0.0.1 and a free port, in a thread."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.app = create_app(config)
        self.server = uvicorn.Server(
            uvicorn.Config(
                self.app,
                host="127.0.0.1",
                port=0,
                ws="websockets-sansio",
                ws_max_size=WS_MAX_MESSAGE,
                log_level="warning",
                access_log=False,
            )
        )
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        self.port = self.server.servers[0].sockets[0].getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}"
        self.token = config.token

    @property
    def hub(self):
        return self.app.state.hub

    @property
    def metrics(self):
        return self.app.state.metrics

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=15)


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[Callable[..., LiveServer]]:
    """Factory: `live_server(scene="flash", size=(320, 180), token="t", ...)`.

    Keywords are `SessionSettings` fields (plus `size`) or `ServerConfig` fields. Defaults
    suit a 2-core CI machine: 160×96 frames at 20 fps, session ends when its viewer leaves.
    """
    started: list[LiveServer] = []

    def start(**overrides: Any) -> LiveServer:
        width, height = overrides.pop("size", (160, 96))
        session = {"width": width, "height": height, "fps": 20.0}
        server: dict[str, Any] = {"data_dir": tmp_path / "data", "session_grace_s": 0.0}
        for key, value in overrides.items():
            (session if key in SESSION_FIELDS else server)[key] = value
        config = ServerConfig(session=SessionSettings(**session), **server)
        live = LiveServer(config)
        started.append(live)
        return live

    yield start
    for live in started:
        live.stop()
