"""No uploaded scene, and no request about one, takes the server down or stalls it.

An upload is decoded, and reduced to its level for the server's frames, in a worker process
(gazehdr.scenes.sandbox, gazehdr.scenes.level): the server holds frame-sized pixels only. An
upload's description is taken once and kept, so a GET never decodes. Decodes are bounded in
number (gazehdr.scenes.library.DecodeSlots), scene requests run on threads of their own with a
cap per client (gazehdr.app.SceneWork), and no refusal names a path of the server's.

The real-server tests run `gazehdr serve` in a subprocess and upload an 8192×8192 EXR of zeros
(RGB half, ZIP: 0.4 MB on disk, 768 MiB as float32 RGB). Each docstring names the mutation the
test fails on.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
import pytest
import websockets

from gazehdr.scenes import library as library_module
from gazehdr.scenes.decoding import SceneError
from gazehdr.scenes.image import ImageScene
from gazehdr.scenes.level import level_size, reduce, session_frames
from gazehdr.scenes.library import SceneBusyError, SceneLibrary
from gazehdr.session import SIZE_STEP, fit_size
from gazehdr.sim.layout import fit_to_frame

TOKEN = "scene-limits"
SIZE = (160, 96)  # the measured servers' frame size
BIG = 8192
FRAMES = session_frames((160, 96), fit_size, SIZE_STEP)  # a 160×96 server's


@pytest.fixture(scope="module")
def big_exr(tmp_path_factory) -> Path:
    """8192² zeros, RGB half, ZIP compression: small on disk, 768 MiB decoded."""
    path = tmp_path_factory.mktemp("big") / "zeros.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": np.zeros((BIG, BIG, 3), np.float16)}).write(str(path))
    return path


def _small_exr(path: Path, shape: tuple[int, int] = (24, 40)) -> bytes:
    rgb = np.random.default_rng(0).random((*shape, 3), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": rgb}).write(str(path))
    return path.read_bytes()


@pytest.fixture
def served(tmp_path: Path):
    """`gazehdr serve` in a subprocess (so that its memory is its own): (url, process)."""
    argv = [sys.executable, "-m", "gazehdr", "serve", "--port", "0",
            "--size", f"{SIZE[0]}x{SIZE[1]}", "--fps", "10", "--backend", "reference",
            "--data-dir", str(tmp_path / "data"), "--token", TOKEN]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    server = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    try:
        assert server.stdout is not None
        url = next(m[1] for line in server.stdout if (m := re.search(r"open (http://\S+)/ ", line)))
        threading.Thread(target=server.stdout.read, daemon=True).start()  # never blocks it
        yield url, server
    finally:
        server.terminate()
        server.wait(timeout=30)


def _request(
    method: str, url: str, body: bytes | None = None, auth: bool = True
) -> tuple[int, Any]:
    req = urllib.request.Request(url, data=body, method=method)
    if auth:
        req.add_header("Authorization", f"Bearer {TOKEN}")
    if method == "PATCH":
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def peak_rss_mib(pid: int) -> float:
    """The process's peak resident memory so far (VmHWM), MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM")


async def _show(url: str, scene: str, timeout: float = 90.0) -> str:
    """A viewer that asks for `scene`: "frames" once a frame of it came, "refused: ..." (an
    error note) or "closed: ..." (the server closed the connection)."""
    try:
        return await _ask_for(url, scene, timeout)
    except websockets.ConnectionClosed as e:
        return f"closed: {e}"


async def _ask_for(url: str, scene: str, timeout: float) -> str:
    ws_url = url.replace("http://", "ws://") + "/ws/view"
    auth = {"Authorization": f"Bearer {TOKEN}"}
    async with websockets.connect(ws_url, max_size=None, additional_headers=auth) as ws:
        await ws.send(json.dumps({"type": "scene", "name": scene}))
        showing = False
        async with asyncio.timeout(timeout):
            while True:
                message = await ws.recv()
                if isinstance(message, bytes):
                    if showing:
                        return "frames"
                    continue
                note = json.loads(message)
                if note["type"] == "state" and note["scene"] == scene:
                    showing = True
                elif note["type"] == "error" and note.get("in") == "scene":
                    return f"refused: {note['message']}"


async def hello_seconds(url: str) -> float:
    """Wall time from connecting a new viewer to its hello."""
    ws_url = url.replace("http://", "ws://") + "/ws/view"
    auth = {"Authorization": f"Bearer {TOKEN}"}
    start = time.perf_counter()
    async with websockets.connect(ws_url, max_size=None, additional_headers=auth) as ws:
        while True:
            message = await ws.recv()
            if isinstance(message, str) and json.loads(message)["type"] == "hello":
                return time.perf_counter() - start


def viewers_of_a_huge_upload(url: str, pid: int, big: Path, viewers: int) -> tuple[list, float]:
    """Upload `big`, have `viewers` viewers open it at once: their outcomes, the peak RSS."""
    assert _request("PUT", f"{url}/api/scenes/big", big.read_bytes()) == (201, {"name": "big"})

    async def crowd() -> list[str]:
        return list(await asyncio.gather(*(_show(url, "big") for _ in range(viewers))))

    outcomes = asyncio.run(crowd())
    return outcomes, peak_rss_mib(pid)


def gets_and_a_hello(url: str, big: Path, gets: int) -> tuple[list, float]:
    """Upload `big`; `gets` public GETs of it at once and a new viewer meanwhile: each GET's
    (status, body, seconds), and the seconds the viewer waited for its hello."""
    assert _request("PUT", f"{url}/api/scenes/big", big.read_bytes()) == (201, {"name": "big"})
    answers: list[tuple[int, Any, float]] = []

    def get() -> None:
        start = time.perf_counter()
        status, body = _request("GET", f"{url}/api/scenes/big", auth=False)
        answers.append((status, body, time.perf_counter() - start))

    threads = [threading.Thread(target=get) for _ in range(gets)]
    for t in threads:
        t.start()
    hello = asyncio.run(hello_seconds(url))
    for t in threads:
        t.join(timeout=300)
    return answers, hello


# --- on a real server ---------------------------------------------------------------------------


def test_two_viewers_of_a_huge_upload_keep_the_server_small(big_exr, served) -> None:
    """The 8192² upload opened by two viewers at once: both get frames of it (or a clear
    refusal), and the server's peak RSS stays under 1 GB (it is ~0.25 GB; fitting the file in
    the server took 7.2 GB for one viewer).

    Mutation guarded: fitting in the server again (the worker handing back the file's
    full-size pixels: `level_size` returning None, or `open_level` not reducing)."""
    url, server = served
    outcomes, peak = viewers_of_a_huge_upload(url, server.pid, big_exr, viewers=2)
    assert peak < 1024, f"server peak RSS {peak:.0f} MiB ({outcomes})"
    assert all(o == "frames" or o.startswith("refused: ") for o in outcomes), outcomes
    assert "frames" in outcomes, outcomes
    assert server.poll() is None


def test_public_gets_of_a_huge_upload_do_not_delay_a_new_viewer(big_exr, served) -> None:
    """Six public GETs of the 8192² upload at once: each is answered from the description
    taken at upload (at once, 200, the file's size), and a new viewer's hello meanwhile comes
    within 2 s (before: 57.7 s, the GETs decoding on the threads that start sessions).

    Mutation guarded: decoding on every GET (`SceneLibrary.describe` opening the file: the
    GETs wait seconds for a decode or are refused as busy)."""
    url, server = served
    answers, hello = gets_and_a_hello(url, big_exr, gets=6)
    assert [status for status, _, _ in answers] == [200] * 6, answers
    assert all((b["width"], b["height"], b["format"]) == (BIG, BIG, "exr") for _, b, _ in answers)
    slowest = max(seconds for _, _, seconds in answers)
    assert slowest < 2.0, f"a GET took {slowest:.1f} s"
    assert hello < 2.0, f"the hello took {hello:.1f} s"
    assert server.poll() is None


def test_no_refusal_names_a_path_of_the_server(served, tmp_path: Path) -> None:
    """Every refusal the scene routes (and a viewer asking for a scene) can give, for a bad
    upload, a bad name, a bad layer, an unknown scene and an upload damaged on disk, says what
    is wrong without the data directory's absolute path (or any other path of the server's).

    Mutation guarded: the library passing the decoder's message on as it is (it names the
    file: `SceneLibrary._scrub` returning `message` unchanged)."""
    url, server = served
    data = str((tmp_path / "data").resolve())
    good = _small_exr(tmp_path / "good.exr")
    assert _request("PUT", f"{url}/api/scenes/pic", good)[0] == 201
    assert _request("PUT", f"{url}/api/scenes/other", good)[0] == 201
    refusals = [
        _request("PUT", f"{url}/api/scenes/junk", b"P5 not an image"),
        _request("PUT", f"{url}/api/scenes/cut", good[:200]),
        _request("PUT", f"{url}/api/scenes/pic", good),  # exists
        _request("PUT", f"{url}/api/scenes/.hidden", good),
        _request("GET", f"{url}/api/scenes/nothing-here", auth=False),
        _request("PATCH", f"{url}/api/scenes/pic", json.dumps({"layer": "specular"}).encode()),
        _request("PATCH", f"{url}/api/scenes/pic", json.dumps({"kind": "bright"}).encode()),
    ]
    damaged = tmp_path / "data" / "scenes" / "other.exr"
    damaged.write_bytes(good[:300])  # another file now: described anew, and it fails
    refusals.append(_request("GET", f"{url}/api/scenes/other", auth=False))
    refusals.append(_request("PATCH", f"{url}/api/scenes/other", b'{"scale": 2}'))
    viewer = asyncio.run(_show(url, "other"))
    said = [body["detail"] for _, body in refusals] + [viewer]
    for message in said:
        assert data not in message and str(tmp_path) not in message, message
        assert ".exr" not in message and "/scenes" not in message.replace("/api/scenes", ""), (
            message
        )
    assert [status for status, _ in refusals] == [422, 422, 409, 400, 404, 422, 422, 422, 422]
    assert "scene 'other': corrupted or truncated EXR" in said[-1], said[-1]
    assert server.poll() is None


# --- in this process ------------------------------------------------------------------------


def test_a_level_covers_every_frame_a_session_can_have() -> None:
    """The level an image is reduced to is at least its fit in every frame a session can
    have (its own size, or any viewport's `fit_size`), so a session never enlarges it; and
    it is no larger than the largest of those frames.

    Mutation guarded: `session_frames` leaving out the viewport sizes (only the budget: a
    square image's level is then too small for a square viewport's frame)."""
    rng = np.random.default_rng(1)
    for budget in [(160, 96), (640, 360), (1280, 720), (64, 36)]:
        frames = session_frames(budget, fit_size, SIZE_STEP)
        for w, h in [(8192, 8192), (8192, 1024), (300, 9000), (4000, 3000), (65536, 1)]:
            level = level_size(w, h, frames) or (w, h)
            for aspect in [*np.exp(rng.uniform(-7, 7, 400)).tolist(), w / h, 1.0]:
                fw, fh = fit_size(budget, (aspect, 1.0))
                s = min(fw / w, fh / h)
                fit = (max(1, round(w * s)), max(1, round(h * s)))
                assert fit[0] <= level[0] and fit[1] <= level[1], (budget, (w, h), (fw, fh))
            assert level[0] * level[1] <= max(fw * fh for fw, fh in frames), (budget, (w, h))


def test_a_level_is_the_image_area_averaged_and_a_small_image_is_kept_as_it_is() -> None:
    """`reduce` is fit_to_frame's area average (in bands of any size), a smooth image's frame
    fitted from its level is the frame fitted from the file (the same bars, values within 1 %:
    two area averages blur a little more than one), and an image no
    larger than its level is not reduced at all.

    Mutation guarded: a reduction by sampling (every n-th pixel) instead of averaging."""
    import gazehdr.scenes.level as level
    from gazehdr.sim.layout import _resample_axis

    rgb = np.random.default_rng(2).random((900, 1300, 3), dtype=np.float32) * 100
    frames = FRAMES
    size = level_size(1300, 900, frames)
    assert size is not None and size[0] < 1300
    reduced = reduce(rgb, size)
    area = _resample_axis(_resample_axis(rgb, 0, size[1]), 1, size[0])
    np.testing.assert_allclose(reduced, area, rtol=1e-5)
    banded = level.BAND_VALUES
    try:
        level.BAND_VALUES = 5000  # bands of a few rows and pieces of a few columns
        np.testing.assert_allclose(reduce(rgb, size), reduced, rtol=1e-5)
    finally:
        level.BAND_VALUES = banded
    y, x = np.mgrid[0:900, 0:1300].astype(np.float32)
    smooth = np.stack([100 + 50 * np.sin(x / 97), 100 + y / 9, 100 + 50 * np.cos(y / 61)], -1)
    from_level, direct = fit_to_frame(reduce(smooth, size), 160, 96), fit_to_frame(smooth, 160, 96)
    assert np.array_equal(from_level == 0, direct == 0)
    np.testing.assert_allclose(from_level, direct, rtol=1e-2)
    assert level_size(160, 96, frames) is None and level_size(100, 60, frames) is None


def test_a_level_keeps_darkness_and_1e8_cd_m2_beside_each_other() -> None:
    """The level of a scene half at 1e8 cd/m² and half at 1e-3, with a black block: the bright
    half stays 1e8, the dark half within 1 % of 1e-3 (the running sums are float64, in bands,
    so the bright half's sum does not swamp the dark), black stays 0, nothing is negative or
    not finite. Guards: float32 running sums (the dark half off by far more than 1 %)."""
    rgb = np.full((600, 4000, 3), 1e-3, np.float32)
    rgb[:, :2000] = 1e8
    rgb[100:300, 3000:3400] = 0.0
    out = reduce(rgb, (1000, 150))
    assert np.isfinite(out).all() and out.min() >= 0.0
    np.testing.assert_allclose(out[:, :499], 1e8, rtol=1e-6)
    dark = out[:, 510:]
    np.testing.assert_allclose(dark[(dark > 0)], 1e-3, rtol=1e-2)
    assert (out[30:70, 755:845] == 0.0).all()  # inside the black block's image


def test_an_upload_is_opened_at_its_level_and_described_without_decoding(tmp_path) -> None:
    """A library for 160×96 frames opens a 1200×800 upload at its level, 152×102 (its
    description, scale and estimate those of the file), shares it between sessions, and
    describes it afterwards without a decode; a small upload opens exactly as decoded here.

    Mutation guarded: describing an upload by decoding it (`describe` calling `open`)."""
    library = SceneLibrary(tmp_path, frames=FRAMES)
    library.store("wide", [_small_exr(tmp_path / "wide.exr", (800, 1200))])
    library.store("small", [_small_exr(tmp_path / "small.exr")])
    here = ImageScene.open(library.uploads()["wide"])
    scene = library.open("wide")
    assert isinstance(scene, ImageScene)
    assert scene.pixels.shape == (102, 152, 3) and scene.decoded.file_size == (1200, 800)
    assert scene.describe() == here.describe() and scene.scale == here.scale
    again = library.open("wide")
    assert again.decoded is scene.decoded  # one level for every session showing it
    small = library.open("small")
    assert np.array_equal(small.pixels, ImageScene.open(library.uploads()["small"]).pixels)

    def no_decode(*args: Any, **kw: Any) -> Any:
        raise AssertionError("decoded")

    original = library_module.check_upload, library_module.open_level
    library_module.check_upload = library_module.open_level = no_decode
    try:
        assert library.describe("wide") == {"name": "wide", "origin": "upload", **here.describe()}
        assert library.configure("wide", {"kind": "office"})["kind"] == "office"
        assert library.describe("wide")["scale_source"] == "estimate"
    finally:
        library_module.check_upload, library_module.open_level = original


def test_a_file_named_at_start_is_kept_at_its_level() -> None:
    """A scene decoded in the server's process (`serve --scene FILE`) is kept at its level for
    the server's frames once the library has it, described and scaled as the file.

    Mutation guarded: the library keeping a configured scene's full pixels (no `keep_level`)."""
    from gazehdr.scenes.decoding import Decoded

    rgb = np.random.default_rng(3).random((800, 1200, 3), dtype=np.float32)
    scene = ImageScene("wide", Decoded(rgb, "exr"))
    described = scene.describe()
    library = SceneLibrary(None, {"wide": scene}, frames=FRAMES)
    assert scene.pixels.shape == (102, 152, 3) and scene.describe() == described
    assert library.describe("wide")["width"] == 1200


def test_decodes_beyond_the_limit_are_refused_not_queued(tmp_path, monkeypatch) -> None:
    """With one decode slot and one waiting slot: while a scene decodes, a second session
    asking for it waits for that decode (and shares its level), a third asking for it and one
    asking for another scene are refused at once with SceneBusyError, naming the limit.

    Mutation guarded: no bound on decodes (`DecodeSlots.take` never refusing)."""
    library = SceneLibrary(tmp_path, frames=FRAMES, decodes=1, waiters=1)
    library.store("a", [_small_exr(tmp_path / "a.exr")])
    library.store("b", [_small_exr(tmp_path / "b.exr")])
    release, started = threading.Event(), threading.Event()
    open_level = library_module.open_level

    def slow(*args: Any) -> Any:
        started.set()
        assert release.wait(30)
        return open_level(*args)

    monkeypatch.setattr(library_module, "open_level", slow)
    opened: list[Any] = []
    first = threading.Thread(target=lambda: opened.append(library.open("a")))
    second = threading.Thread(target=lambda: opened.append(library.open("a")))
    first.start()
    assert started.wait(30)
    second.start()
    deadline = time.monotonic() + 30
    while library.slots.busy["waiting"] < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    for name in ("a", "b"):
        with pytest.raises(SceneBusyError, match="decodes 1 scene files at once"):
            library.open(name)
    release.set()
    first.join(30)
    second.join(30)
    assert len(opened) == 2 and opened[0].decoded is opened[1].decoded
    assert library.slots.busy == {"decoding": 0, "waiting": 0}
    assert isinstance(library.open("b"), ImageScene)  # free again


def test_scene_requests_run_on_their_own_threads_with_a_cap_per_client(live_server) -> None:
    """GET /api/scenes/NAME runs on the scene threads (`gazehdr-scenes`), not on the ones that
    start sessions; one client's requests beyond its cap are refused with 503 while its
    others still run, and the count comes back once they are done.

    Mutation guarded: scene routes on the default executor (`asyncio.to_thread`), where
    sessions are built."""
    server = live_server()
    work = server.app.state.scene_work
    library = server.hub.scenes
    threads: list[str] = []
    release = threading.Event()

    def held(name: str) -> dict[str, Any]:
        threads.append(threading.current_thread().name)
        release.wait(30)
        return {"name": name}

    library.describe = held
    answers: list[tuple[int, Any]] = []
    gets = [
        threading.Thread(
            target=lambda: answers.append(_get_public(f"{server.url}/api/scenes/flash"))
        )
        for _ in range(work.per_client)
    ]
    for t in gets:
        t.start()
    # Every one of them admitted (past the pool's threads they queue, counted) before one more:
    # on a busy machine the last of them may reach the server after the first are running.
    deadline, running = time.monotonic() + 30, min(work.per_client, work.pool._max_workers)
    while work.busy < work.per_client or len(threads) < running:
        assert time.monotonic() < deadline, (work.busy, threads)
        time.sleep(0.01)
    status, body = _get_public(f"{server.url}/api/scenes/flash")
    assert status == 503 and "from one client" in body["detail"], body
    release.set()
    for t in gets:
        t.join(30)
    assert [s for s, _ in answers] == [200] * work.per_client
    assert all(name.startswith("gazehdr-scenes") for name in threads), threads
    assert work.busy == 0 and not work.clients


def _get_public(url: str) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def test_errors_of_the_worker_name_the_scene(tmp_path) -> None:
    """A file that fails when opened for a session is refused naming the scene, not its path."""
    library = SceneLibrary(tmp_path)
    library.store("pic", [_small_exr(tmp_path / "pic.exr")])
    path = library.uploads()["pic"]
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(SceneError) as refused:
        library.open("pic")
    assert str(refused.value).startswith("scene 'pic': ") and str(tmp_path) not in str(
        refused.value
    )
