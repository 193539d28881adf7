"""Uploads are decoded in a worker process (gazehdr.scenes.sandbox): a decoder
that crashes, runs out of memory or hangs costs that request only, with a clear 4xx, and the
server goes on serving. Against a real `gazehdr serve` process, through the real upload route;
the crash is the worker's test hook (GAZEHDR_TEST_DECODE_FAULTS), honoured in the worker only."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from gazehdr.scenes.decoding import SceneError
from gazehdr.scenes.library import SceneLibrary
from gazehdr.scenes.sandbox import FAULT_ENV


def _exr(path: Path) -> bytes:
    rgb = np.random.default_rng(0).random((24, 32, 3), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": rgb}).write(str(path))
    return path.read_bytes()


TOKEN = "decode-worker-test"


def _request(method: str, url: str, body: bytes | None = None) -> tuple[int, dict]:
    req = urllib.request.Request(url, data=body, method=method)
    req.add_header("Authorization", f"Bearer {TOKEN}")  # writes need the credential
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


@pytest.fixture
def faulty_server(tmp_path: Path):
    """`gazehdr serve` whose decode worker honours the test hook, with a 3 s time limit."""
    argv = [sys.executable, "-m", "gazehdr", "serve", "--port", "0", "--size", "64x36",
            "--backend", "reference", "--data-dir", str(tmp_path / "data"),
            "--token", TOKEN]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1", FAULT_ENV: "1", "GAZEHDR_DECODE_TIME_S": "3"}
    server = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=env)  # fmt: skip
    try:
        assert server.stdout is not None
        url = next(m[1] for line in server.stdout if (m := re.search(r"open (http://\S+)/ ", line)))
        yield url, server
    finally:
        server.terminate()
        server.wait(timeout=30)


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("abort", "the decoder crashed (signal SIGABRT) on this file"),
        ("segv", "the decoder crashed (signal SIGSEGV) on this file"),
        ("alloc", "decoding ran out of memory (limit 3072 MiB)"),
        ("hang", "decoding took longer than 3 s; the file was refused"),
    ],
)
def test_a_decoder_crash_costs_only_its_upload(faulty_server, tmp_path, fault, message) -> None:
    url, server = faulty_server
    good = _exr(tmp_path / "good.exr")
    status, body = _request(
        "PUT", f"{url}/api/scenes/bad", good + f"GAZEHDR-FAULT:{fault}\n".encode()
    )
    assert (status, body) == (422, {"detail": f"upload 'bad': {message}"})
    assert server.poll() is None  # the server lives, and answers
    assert _request("GET", f"{url}/api/health")[1]["status"] == "ok"
    assert "bad" not in _request("GET", f"{url}/api/scenes")[1]["scenes"]
    assert _request("PUT", f"{url}/api/scenes/good", good) == (201, {"name": "good"})
    described = _request("GET", f"{url}/api/scenes/good")[1]  # opened in a worker too
    assert (described["format"], described["width"], described["height"]) == ("exr", 32, 24)


def test_an_upload_opened_in_the_worker_is_the_file_decoded_here(tmp_path) -> None:
    """What a session gets from the worker (pixels through a .npy file) is what the decoder
    gives in this process, bit for bit; a file that is no image is refused with its reason."""
    from gazehdr.scenes.image import ImageScene

    library = SceneLibrary(tmp_path)
    library.store("pic", [_exr(tmp_path / "pic.exr")])
    opened = library.open("pic")
    here = ImageScene.open(library.uploads()["pic"])
    assert np.array_equal(opened.pixels, here.pixels) and opened.scale == here.scale
    assert opened.decoded.notes == here.decoded.notes and opened.source == here.source
    with pytest.raises(SceneError, match=r"upload 'junk': .*not an HDR image"):
        library.store("junk", [b"P5 not an image"])
    with pytest.raises(SceneError, match="upload 'cut': "):
        library.store("cut", [_exr(tmp_path / "cut.exr")[:200]])
