"""Shared fixtures: a real uvicorn server on loopback, started per test with the given settings;
LSL outlets withdrawn safely after a test; the suite's two speeds (`pytest -m quick`, the daily
subset; plain `pytest`, everything); and the suite's skip policy: under CI (CI set) a skipped
test fails the run."""

from __future__ import annotations

import dataclasses
import fcntl
import os
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from gazehdr.app import ServerConfig
from gazehdr.gaze import TrackerFeed
from gazehdr.serve import BackgroundServer, bind
from gazehdr.session import SessionSettings

SESSION_FIELDS = {f.name for f in dataclasses.fields(SessionSettings)}


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    """A listening socket on a free loopback port, held for the whole test. Servers started on
    it (`live_server(sock=listener)`, or a process handed its descriptor) one after another are
    found where the last one was, and no other program can take the port in between. While no
    server runs, connections wait in its backlog rather than being refused."""
    sock = bind("127.0.0.1", 0)
    yield sock
    sock.close()


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[Callable[..., BackgroundServer]]:
    """Factory: `live_server(scene="flash", size=(320, 180), token="t", ...)`.

    Keywords are `SessionSettings` fields (plus `size`) or `ServerConfig` fields, and `sock`: a
    listening socket to serve on (`listener`) instead of a free port. Defaults suit a 2-core CI
    machine: 160×96 frames at 20 fps, session ends when its viewer leaves.
    """
    started: list[BackgroundServer] = []

    def start(**overrides: Any) -> BackgroundServer:
        width, height = overrides.pop("size", (160, 96))
        sock = overrides.pop("sock", None)
        session = {"width": width, "height": height, "fps": 20.0}
        server: dict[str, Any] = {"data_dir": tmp_path / "data", "session_grace_s": 0.0}
        for key, value in overrides.items():
            (session if key in SESSION_FIELDS else server)[key] = value
        config = ServerConfig(session=SessionSettings(**session), **server)
        live = BackgroundServer(config, sock)
        started.append(live)
        return live

    yield start
    for live in started:
        live.stop()


@pytest.fixture
def lsl_outlet() -> Iterator[Callable[[Any], Any]]:
    """Factory: `lsl_outlet(info)`, a real pylsl outlet, destroyed after the test once its
    consumers have left (tests/lsl_loopback.py `Publisher`: liblsl may crash otherwise)."""
    from lsl_loopback import Publisher  # imported here: it sets LSLAPICFG before liblsl loads

    publisher = Publisher()
    yield publisher.outlet
    publisher.withdraw_all()


def sole_tracker(server: BackgroundServer) -> TrackerFeed:
    """The one tracker a test's daemon streamed to `server` as."""
    (feed,) = server.hub.trackers.feeds()
    return feed


def samples_received(server: BackgroundServer) -> int:
    """Samples `server` received from its daemons so far (0 before any has connected)."""
    return sum(feed.samples for feed in server.hub.trackers.feeds())


#: Modules left out of the quick subset, whole: a real browser, processes of their own (a
#: daemon, a fuzzer, a built wheel, a Dask cluster, a decode worker), floods and huge uploads on
#: a real server, the experiments' and figures' renders, the OpenAPI fuzzing of schemathesis.
SLOW_MODULES = frozenset({
    "test_browser.py", "test_browser_inspect.py", "test_browser_video.py", "test_browser_warp.py",
    "test_experiment_browser.py", "test_palette.py", "test_packaging.py", "test_fuzz.py",
    "test_lsl.py", "test_batch.py", "test_bench.py", "test_scene_limits.py", "test_fair_share.py",
    "test_decode_worker.py", "test_figures.py", "test_daemon.py", "test_hid.py", "test_gaze.py",
    "test_model_observer.py", "test_experiment_run.py", "test_experiment_analysis.py",
    "test_video.py", "test_limits.py", "test_security.py", "test_live_pipeline.py",
    "test_pupil.py", "test_xdf.py", "test_bids_dataset.py", "test_recording.py",
})  # fmt: skip


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "quick: the daily subset (`pytest -m quick`, under 2 minutes on 2 cores)"
    )
    config.addinivalue_line("markers", "slow: left out of the quick subset")
    config.addinivalue_line(
        "markers",
        "alone: compares rates measured over real seconds, so runs while no other xdist worker"
        " runs a test",
    )


def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder this whole run shares: under xdist the workers' common parent of their
    basetemps, else the run's own basetemp."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(autouse=True)
def _machine_turn(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[None]:
    """A readers-writer lock across xdist workers: every test holds it shared, an `alone` test
    exclusively, so a rate it measures over real seconds (frames during a flood against frames
    just before) is not skewed by the other worker's load changing in between. Writers go
    first: a test waiting for its turn alone holds the turnstile, and no new test starts past
    it until that one has run."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    alone = request.node.get_closest_marker("alone") is not None
    folder = run_folder(tmp_path_factory)
    with open(folder / "turnstile.lock", "a") as turnstile, open(folder / "turn.lock", "a") as turn:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(turn, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(turnstile, fcntl.LOCK_UN)
        yield  # the turn is let go when its file closes


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test is `quick` unless its module is slow, it is marked `slow`, or it runs the
    NumPy reference backend (the oracle: float64, minutes in all; the OpenCL run of the same
    test stays quick)."""
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        slow = (
            Path(str(item.fspath)).name in SLOW_MODULES
            or any(item.get_closest_marker(m) for m in ("slow", "docker", "hid_kernel"))
            or any(isinstance(v, str) and v == "reference" for v in params.values())
        )
        item.add_marker(pytest.mark.slow if slow else pytest.mark.quick)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """Under CI a skip is a failure, with its reason: CI has everything every test needs (the
    browser, the OpenCL device, the tools), so a test that skips there has stopped testing."""
    outcome = yield
    report: pytest.TestReport = outcome.get_result()
    if os.environ.get("CI") and report.skipped and not hasattr(report, "wasxfail"):
        _fail_the_skip(report)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Iterator[None]:
    """The same for a whole module skipped at collection (`importorskip`, `allow_module_level`)."""
    outcome = yield
    report: pytest.CollectReport = outcome.get_result()
    if os.environ.get("CI") and report.skipped:
        _fail_the_skip(report)


def _fail_the_skip(report: pytest.TestReport | pytest.CollectReport) -> None:
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    report.outcome = "failed"
    report.longrepr = f"skipped under CI, which must run every test: {reason}"
