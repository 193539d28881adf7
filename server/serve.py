"""`gazehdr serve`: check the configuration up front, then run the app under uvicorn."""

from __future__ import annotations

import math
import secrets
from pathlib import Path

import uvicorn

from server.app import ServerConfig, create_app
from server.protocol import Encoding
from server.scenes import builtin_names
from server.scenes.exr import ExrScene
from server.session import SessionSettings
from server.sim import Params
from server.sim.layout import check_frame_size

#: Largest WebSocket message a client may send (uvicorn closes with 1009 beyond it).
WS_MAX_MESSAGE = 1024 * 1024


def build_config(
    *,
    host: str,
    port: int,
    scene: str,
    scale: float | None,
    gaze: str,
    fps: float,
    size: tuple[int, int],
    fit_viewport: bool,
    params_file: str | None,
    token: str | None,
    data_dir: Path,
    allow_origins: tuple[str, ...],
    encoding: str,
    backend: str,
    seed: int,
) -> ServerConfig:
    """Everything `serve` would run with, or a ValueError naming what is wrong."""
    if not (math.isfinite(fps) and 0 < fps <= 240):
        raise ValueError(f"fps must be in (0, 240], got {fps}")
    if not 0 <= port <= 65535:
        raise ValueError(f"port must be in [0, 65535], got {port}")
    check_frame_size(*size)
    params = Params()
    if params_file:
        try:
            params = Params.load(params_file)
        except (TypeError, ValueError) as e:
            raise ValueError(f"parameter preset {params_file}: {e}") from None
    loaded = {}
    if scene not in builtin_names():
        exr = ExrScene.open(scene, scale=scale)  # fails now, with the file's own error
        loaded[exr.name] = exr
        scene = exr.name
    settings = SessionSettings(
        width=size[0],
        height=size[1],
        fps=fps,
        scene=scene,
        gaze_source=gaze,
        params=params,
        seed=seed,
        backend=backend,
        encoding=Encoding[encoding],
        fit_viewport=fit_viewport,
    )
    return ServerConfig(
        host=host,
        port=port,
        session=settings,
        token=token or secrets.token_urlsafe(24),
        data_dir=data_dir,
        scenes=loaded,
        allow_origins=allow_origins,
    )


def serve(**options) -> int:
    config = build_config(**options)
    app = create_app(config)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=config.host,
            port=config.port,
            ws="websockets-sansio",
            ws_max_size=WS_MAX_MESSAGE,
            access_log=False,
            log_level="info",
        )
    )
    shown = f"[{config.host}]" if ":" in config.host else config.host
    s = config.session
    print(f"gazehdr: open http://{shown}:{config.port}/ (scene {s.scene}, gaze {s.gaze_source})")
    print(f"gazehdr: gaze daemon token: {config.token}")
    server.run()
    return 0
