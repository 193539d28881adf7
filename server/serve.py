"""`gazehdr serve`: check the configuration up front, then run the app under uvicorn."""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import math
import os
import secrets
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np
import uvicorn

from gazehdr import heap
from gazehdr.app import ServerConfig, create_app
from gazehdr.drivers import registry
from gazehdr.drivers.daemon import run_daemon
from gazehdr.drivers.errors import InputError
from gazehdr.gaze import is_tracker_source
from gazehdr.protocol import SIM_OUTPUT, Encoding
from gazehdr.scenes import builtin_names, open_scene
from gazehdr.security import LOOPBACK_NAMES, WILDCARD_HOSTS, policy_for
from gazehdr.session import GAZE_SOURCES, SessionSettings
from gazehdr.sim import Simulator
from gazehdr.sim.layout import check_frame_size
from gazehdr.sim.level_stack import LEVEL_STACK_AFTER_FRAMES
from gazehdr.sim.models import Models
from gazehdr.sim.params import MAX_BANDS
from gazehdr.sim.presets import DEFAULT_PRESET, describe, load_params
from gazehdr.ws_protocol import FrameWritingProtocol

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
    afterimage: str = "jacobs",
    acuity: str = "stochastic",
    split: str | None = None,
    record: bool = False,
    late_gaze: bool = True,
    lsl_outlet: str | None = None,
    layer: str | None = None,
    auth: bool = True,
    allow_hosts: tuple[str, ...] = (),
    preset: str = DEFAULT_PRESET,
    experiment: object = None,
) -> ServerConfig:
    """Everything `serve` would run with, or a ValueError naming what is wrong."""
    if lsl_outlet is not None:
        _check_lsl(lsl_outlet)
    if not (math.isfinite(fps) and 0 < fps <= 240):
        raise InputError(f"fps must be in (0, 240], got {fps}")
    if not 0 <= port <= 65535:
        raise InputError(f"port must be in [0, 65535], got {port}")
    check_frame_size(*size)
    if gaze.startswith("replay:"):  # a recording of the server's, or any PATH import reads
        from gazehdr.drivers.replay import library_recording

        gaze = "replay:" + library_recording(gaze, data_dir / "recordings")
    elif gaze not in GAZE_SOURCES and not is_tracker_source(gaze):
        raise InputError(
            f"gaze source {gaze!r}: choose {', '.join(GAZE_SOURCES)}, remote:TRACKER or "
            "replay:PATH (a recording, a BIDS dataset, or one of the server's recordings)"
        )
    model = Models(afterimage, acuity)  # unknown names: a ValueError listing the choices
    right = Models.parse(split) if split else None  # the right pane's, in split view
    params = load_params(preset, params_file)
    loaded = {}
    if scene not in builtin_names():
        opened = open_scene(scene, scale=scale, layer=layer)  # fails now, with the file's error
        loaded[opened.name] = opened
        scene = opened.name
    settings = SessionSettings(
        width=size[0],
        height=size[1],
        fps=fps,
        scene=scene,
        gaze_source=gaze,
        model=model,
        split=right,
        params=params,
        seed=seed,
        backend=backend,
        encoding=Encoding[encoding],
        fit_viewport=fit_viewport,
        record=record,
        late_gaze=late_gaze,
    )
    return ServerConfig(
        host=host,
        port=port,
        session=settings,
        token=token or secrets.token_urlsafe(24),
        data_dir=data_dir,
        scenes=loaded,
        allow_origins=allow_origins,
        lsl_outlet=lsl_outlet,
        auth=auth,
        allow_hosts=allow_hosts,
        experiment=experiment,
    )


def _check_lsl(name: str) -> None:
    """--lsl-outlet needs a name and pylsl with its liblsl, checked before the server starts."""
    if not name.strip():
        raise InputError("--lsl-outlet needs a stream name")
    from gazehdr.drivers.lsl import load_pylsl

    try:
        load_pylsl()
    except ImportError as e:
        raise InputError(f"--lsl-outlet: LSL outlet unavailable: {e}") from None


def uvicorn_server(app, host: str, port: int, log_level: str = "info") -> uvicorn.Server:
    """The one way we run uvicorn: the websockets library's sans-I/O core, which waits for the
    socket to drain before each send (a slow viewer then skips frames, see server/live.py),
    large frames written with one copy (ws_protocol.py).
    Per-message deflate is off: browsers ask for it, and zlib on megabytes of float16 noise
    per frame cost more CPU than the simulation (bench-live: 3.9 fps with it at 1280×720).
    Proxy headers are off (docs/security.md)."""
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        ws=FrameWritingProtocol,
        ws_max_size=WS_MAX_MESSAGE,
        ws_per_message_deflate=False,
        # A client's address is its socket's: X-Forwarded-For is not believed (uvicorn does
        # from 127.0.0.1 by default), so no client picks the address its failures count against.
        proxy_headers=False,
        access_log=False,
        log_level=log_level,
    )
    return uvicorn.Server(config)


class UvicornThread:
    """`app` under `uvicorn_server` on 127.0.0.1, in a thread, started when this returns.

    It listens on a free port the system picks, or on `sock`: a listening socket that the
    caller keeps open (the server gets a duplicate, closed when it stops), so that servers
    started on it one after another are found at one address, which nobody can take between.
    """

    def __init__(self, app, sock: socket.socket | None = None) -> None:
        self.app = app
        listener = bind("127.0.0.1", 0) if sock is None else sock.dup()
        self.port = listener.getsockname()[1]
        self.server = uvicorn_server(app, "127.0.0.1", self.port, log_level="warning")
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [listener]}, daemon=True
        )
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=15)


class BackgroundServer(UvicornThread):
    """`create_app(config)` as a `UvicornThread`: for tests and benchmarks."""

    def __init__(self, config: ServerConfig, sock: socket.socket | None = None) -> None:
        super().__init__(create_app(config), sock)
        self.config = config
        self.token = config.token
        #: What a script sends with a write or a private read (`gazehdr.security`).
        self.auth = {"Authorization": f"Bearer {config.token}"}
        self.hub = self.app.state.hub
        self.metrics = self.app.state.metrics


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on `host`:`port` (0: a free port the system picks), IPv4 or IPv6
    as `host` says. Binding before anything is printed means a busy port is an error up front,
    and the URL printed is the real one."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(2048)
    except OSError as e:
        sock.close()
        raise InputError(f"cannot listen on {host} port {port}: {e.strerror or e}") from None
    sock.set_inheritable(True)
    return sock


def kernel_cache_dir() -> str:
    """Where PoCL keeps the kernels it built: `POCL_CACHE_DIR`, else the user's cache folder.
    Entries are keyed by the kernels' source, build options and device, so they outlive an
    upgrade of gazehdr that leaves the kernels as they were, and never serve stale ones."""
    if os.environ.get("POCL_CACHE_DIR"):
        return os.environ["POCL_CACHE_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "pocl", "kcache")


#: Steps of `build_kernels`: the first settles; a scene that stays moves the acuity to its level
#: stack after LEVEL_STACK_AFTER_FRAMES frames, one level a frame, and then picks from it.
WARM_UP_STEPS = 1 + LEVEL_STACK_AFTER_FRAMES + MAX_BANDS + 1


def build_kernels(settings: SessionSettings) -> float:
    """Build (or load from the cache) the kernels of a session as new viewers get it, before
    the address is printed, so that the first viewer sees a picture at once instead of a page
    waiting for a build, and no kernel is first launched (with an empty cache, built: 60-80 ms
    each) while it watches: WARM_UP_STEPS steps of its model at its frame size, a still black
    scene. Seconds taken."""
    started = time.monotonic()
    sim = Simulator(
        settings.width, settings.height, params=settings.params, backend=settings.backend,
        seed=settings.seed, afterimage=settings.model.afterimage, acuity=settings.model.acuity,
    )  # fmt: skip
    sim.load_scene(np.zeros((settings.height, settings.width, 3), np.float32))
    for _ in range(WARM_UP_STEPS):
        sim.step(1.0 / settings.fps, output=SIM_OUTPUT.get(settings.encoding, "float16"))
    return time.monotonic() - started


def local_host(host: str) -> str:
    """The address this machine's own browser opens: the bound one, or loopback for a
    wildcard (0.0.0.0 is no address a browser can open)."""
    if host in WILDCARD_HOSTS:
        return "::1" if host == "::" else "127.0.0.1"
    return host


def reachable_hosts(host: str) -> list[str]:
    """The addresses another machine opens: the bound one, or for a wildcard every address of
    this machine's that is not loopback (its hostname's, and the one it routes from), as IP
    literals, which a wildcard-bound server answers to (a name would need --allow-host)."""
    if host not in WILDCARD_HOSTS:
        return [host]
    found: list[str] = []
    families = (socket.AF_INET,) if host in ("0.0.0.0", "") else (socket.AF_INET, socket.AF_INET6)
    candidates: list[str] = []
    with contextlib.suppress(OSError):
        for family, *_, address in socket.getaddrinfo(socket.gethostname(), None):
            if family in families:
                candidates.append(str(address[0]))
    for family, probe in ((socket.AF_INET, "192.0.2.1"), (socket.AF_INET6, "2001:db8::1")):
        if family not in families:
            continue
        with contextlib.suppress(OSError), socket.socket(family, socket.SOCK_DGRAM) as udp:
            udp.connect((probe, 9))  # no packet is sent: this only asks for the route
            candidates.append(str(udp.getsockname()[0]))
    for name in candidates:
        ip = ipaddress.ip_address(name.split("%")[0])
        if not (ip.is_loopback or ip.is_link_local or ip.is_unspecified) and name not in found:
            found.append(name)
    return found or [local_host(host)]


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def access_lines(config: ServerConfig, urls: list[str]) -> list[str]:
    """What `serve` says about who may do what (docs/security.md); `urls` are the server's
    addresses for other machines."""
    hosts = ", ".join(sorted(policy_for(config).hosts))
    lines = [f"requests must name this server as one of: {hosts}"]
    if config.host in WILDCARD_HOSTS:
        lines[0] += ", or any IP address of it"
    if config.allow_origins:
        lines.append(f"pages of these origins may use it too: {', '.join(config.allow_origins)}")
    if not config.auth:
        lines.append(
            "--no-auth: NO CREDENTIAL is asked: anyone who can reach this address can change "
            "parameters, upload and configure scenes and recordings, read recordings (gaze) and "
            "sessions, join any session and stream gaze as a tracker"
        )
        return lines
    lines.append(f"token (gaze daemon; scripts: Authorization: Bearer TOKEN): {config.token}")
    if config.host not in LOOPBACK_NAMES:
        shown = " or ".join(f"{url}/?token={config.token}" for url in urls)
        lines.append(f"from another machine, open the viewer once as {shown}")
    return lines


def check_tracker_spec(spec: str) -> None:
    """A ValueError unless `spec` names a kind of source that streams (`serve --tracker`)."""
    name = spec.partition(":")[0]
    if not any(k.name == name for k in registry.kinds(registry.STREAM)):
        raise InputError(f"--tracker {spec!r}: not a stream; choose {registry.choices('stream')}")


def start_tracker(spec: str, url: str, token: str, record_dir: Path) -> threading.Thread:
    """Stream the source `spec` names to this server as a gaze daemon on another machine
    would (`gazehdr.drivers.daemon`, over /ws/gaze on loopback), from a thread of its own: a
    tracker read where the server runs reaches sessions the one way every tracker does, and
    is recorded to `record_dir` (replayable as `replay:NAME`) like any daemon's."""

    def run() -> None:
        try:
            source = registry.open_source(spec, wait=True)
            stats = asyncio.run(run_daemon(source, url, token, record_dir=record_dir))
            print(f"gazehdr: tracker {spec}: {stats.summary()}", file=sys.stderr)
        except Exception as e:  # the server goes on without this tracker; say why
            print(f"gazehdr: tracker {spec}: error: {e}", file=sys.stderr)

    thread = threading.Thread(target=run, name=f"tracker {spec}", daemon=True)
    thread.start()
    return thread


def serve(*, trackers: tuple[str, ...] = (), **options) -> int:
    """Run the server; `trackers` are source specs streamed to it from this process."""
    config = build_config(**options)
    for spec in trackers:
        check_tracker_spec(spec)
    heap.limit_arenas()  # before any session's thread: memory goes back when sessions end
    sock = bind(config.host, config.port)  # a port in use fails now, not after the build
    app = create_app(config)  # and a viewer with a file missing
    print(
        "gazehdr: building the simulation's kernels (the first start on a machine takes up to a "
        f"minute; they are kept in {kernel_cache_dir()})…",
        flush=True,
    )
    print(f"gazehdr: kernels ready in {build_kernels(config.session):.1f} s", flush=True)
    server = uvicorn_server(app, config.host, config.port)
    port = sock.getsockname()[1]
    urls = [f"http://{_url_host(h)}:{port}" for h in reachable_hosts(config.host)]
    here = f"http://{_url_host(local_host(config.host))}:{port}"
    s = config.session
    print(
        f"gazehdr: open {here}/ (scene {s.scene}, gaze {s.gaze_source}, "
        f"parameters {describe(s.params)})"
    )
    for line in access_lines(config, urls):
        print(f"gazehdr: {line}", flush=True)
    shown = _url_host(local_host(config.host))
    if config.experiment is not None:
        e = config.experiment
        print(f"gazehdr: experiment {e.design.name!r} at http://{shown}:{port}/experiment, "
              f"results to {e.out_dir}", flush=True)  # fmt: skip
    if s.record:
        print(f"gazehdr: recording each session to {config.data_dir / 'recordings'}", flush=True)
    if config.lsl_outlet is not None:
        name = config.lsl_outlet
        print(f"gazehdr: publishing each session on LSL: '{name}', '{name} events'", flush=True)
    loopback = "[::1]" if ":" in config.host else "127.0.0.1"
    for spec in trackers:
        start_tracker(spec, f"ws://{loopback}:{port}", config.token, config.data_dir / "recordings")
        print(f"gazehdr: tracker {spec} streams to this server (gaze source remote:NAME)")
    server.run(sockets=[sock])
    return 0
