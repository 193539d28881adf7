"""Radiance .hdr and PFM (server/scenes/hdr.py), EXR layers, uploads and `gazehdr scenes`.

Test files are written by OpenCV, or byte by byte from the formats' specifications, never by
gazehdr's own code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

from gazehdr.scenes.decoding import SceneError
from gazehdr.scenes.image import ImageScene, decode
from gazehdr.scenes.library import SceneExistsError, SceneLibrary


def _rgbe(path: Path, rgb: np.ndarray, header: str = "") -> tuple[bytes, np.ndarray]:
    """An RGBE file by OpenCV; returns its pixel bytes (flat scanlines) and what they hold."""
    cv2.imwrite(str(path), rgb[..., ::-1])
    held = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]
    data = path.read_bytes()
    body = data[data.index(b"\n\n") + 2 :]
    pixels = body[body.index(b"\n") + 1 :]
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n" + header.encode() + b"\n" + body)
    return pixels, held


IMG = np.arange(4 * 6 * 3, dtype=np.float32).reshape(4, 6, 3) + 1.0


@pytest.mark.parametrize(
    ("line", "turn"),
    [
        ("-Y 4 +X 6", lambda a: a),
        ("+Y 4 +X 6", lambda a: a[::-1]),
        ("-Y 4 -X 6", lambda a: a[:, ::-1]),
        ("+Y 4 -X 6", lambda a: a[::-1, ::-1]),
        ("+X 4 -Y 6", lambda a: a.transpose(1, 0, 2)),
        ("-X 4 -Y 6", lambda a: a.transpose(1, 0, 2)[:, ::-1]),
        ("+X 4 +Y 6", lambda a: a.transpose(1, 0, 2)[::-1]),
        ("-X 4 +Y 6", lambda a: a.transpose(1, 0, 2)[::-1, ::-1]),
    ],
)
def test_rgbe_orientations(tmp_path: Path, line: str, turn) -> None:
    """The scanlines as stored (a 4×6 array, first axis first) under each resolution line:
    +Y rows go bottom up, -X columns right to left, X first stores columns (Radiance's
    convention). The image read is the stored array turned accordingly."""
    path = tmp_path / "o.hdr"
    _, held = _rgbe(path, IMG)
    data = path.read_bytes().replace(b"-Y 4 +X 6", line.encode())
    path.write_bytes(data)
    np.testing.assert_array_equal(decode(path).rgb, turn(held))


def test_rgbe_exposure_colorcorr_primaries(tmp_path: Path) -> None:
    path = tmp_path / "e.hdr"
    _, held = _rgbe(path, IMG, "EXPOSURE=2\nEXPOSURE=4\nCOLORCORR=1 2 1\n")
    got = decode(path)
    np.testing.assert_allclose(got.rgb, held / 8 / np.array([1, 2, 1]), rtol=1e-6)
    assert "divided out" in got.notes[0]
    rec2020 = "PRIMARIES=0.708 0.292 0.170 0.797 0.131 0.046 0.3127 0.3290\n"
    _rgbe(path, np.ones((4, 6, 3), np.float32), rec2020)
    np.testing.assert_allclose(decode(path).rgb, 1.0, rtol=1e-3)  # white stays white
    _rgbe(path, IMG, "EXPOSURE=-1\n")
    with pytest.raises(SceneError, match="EXPOSURE must be positive"):
        decode(path)
    _rgbe(path, IMG, "FORMAT=32-bit_rle_xyze\n")  # the later FORMAT line wins: XYZ
    assert "XYZE" in decode(path).notes[0]


@pytest.mark.parametrize(
    ("mangle", "message"),
    [
        (lambda d: d[:-7], "truncated RGBE pixel data"),
        (lambda d: d.replace(b"-Y 4 +X 6", b"-Y 4 +Y 6"), "resolution line"),
        (lambda d: d.replace(b"\n\n", b"\n"), "no blank line"),
        (lambda d: d.replace(b"-Y 4 +X 6", b"-Y 99999 +X 99999"), "limit of"),
        (lambda d: d.replace(b"FORMAT=32-bit_rle_rgbe", b"FORMAT=png"), "FORMAT 'png'"),
    ],
)
def test_bad_rgbe(tmp_path: Path, mangle, message: str) -> None:
    path = tmp_path / "bad.hdr"
    _rgbe(path, IMG)
    path.write_bytes(mangle(path.read_bytes()))
    with pytest.raises(SceneError, match=message):
        decode(path)


def test_pfm_by_the_specification(tmp_path: Path) -> None:
    """Rows bottom to top; a positive scale is big-endian; grey is repeated."""
    path = tmp_path / "g.pfm"
    path.write_bytes(b"Pf\n2 2\n1.0\n" + np.array([1, 2, 3, 4], ">f4").tobytes())
    np.testing.assert_array_equal(decode(path).rgb[..., 0], [[3, 4], [1, 2]])
    cv2.imwrite(str(path), IMG[..., ::-1])
    np.testing.assert_array_equal(decode(path).rgb, IMG)
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(SceneError, match="truncated PFM"):
        decode(path)
    path.write_bytes(b"PF\n100000 100000\n-1\n")
    with pytest.raises(SceneError, match="limit of"):  # refused before reading pixels
        decode(path)


def test_exr_layers_and_parts(tmp_path: Path) -> None:
    rgb = np.ones((4, 5, 3), np.float32)

    def part(name: str, channels: dict) -> OpenEXR.Part:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        return OpenEXR.Part({**header, "name": name}, channels)

    path = tmp_path / "layers.exr"
    diffuse = {f"diffuse.{c}": rgb[..., 0] * 2 for c in "RGB"}
    OpenEXR.File(
        [part("beauty", {"RGB": rgb, **diffuse}), part("depth", {"Y": rgb[..., 0] * 7})]
    ).write(str(path))
    first = decode(path)
    assert first.layers == ("beauty", "beauty/diffuse", "depth") and first.layer == "beauty"
    assert decode(path, "beauty/diffuse").rgb.max() == 2 and decode(path, "depth").rgb.min() == 7
    with pytest.raises(SceneError, match="no layer 'specular'; the file has 'beauty'"):
        decode(path, "specular")


def test_library_settings_overwrite_and_the_cli(tmp_path: Path) -> None:
    pfm = tmp_path / "in.pfm"
    cv2.imwrite(str(pfm), IMG[..., ::-1])
    library = SceneLibrary(tmp_path / "data")
    library.store("pic", [pfm.read_bytes()])
    with pytest.raises(
        SceneExistsError, match=r"overwrite \(PUT /api/scenes/pic\?overwrite=true\)"
    ):
        library.store("pic", [pfm.read_bytes()])
    scene = library.open("pic")
    assert isinstance(scene, ImageScene) and scene.scale.source == "estimate"
    version = library.version("pic")
    library.configure("pic", {"scale": 42.0})
    assert library.version("pic") > version
    assert library.refresh("pic", scene) is scene and scene.scale.value == 42.0  # not re-read
    library.store("pic", [pfm.read_bytes()[:-4] + b"\0\0\0\0"], overwrite=True)
    assert library.refresh("pic", scene) is not scene  # the file was replaced: read anew
    assert library.describe("pic")["scale_source"] == "estimate"  # its settings went with it
    library.configure("pic", {"scale": 7.0})
    library.store("guessed", [pfm.read_bytes()])  # no settings: the scale is an estimate
    out = subprocess.run(
        [sys.executable, "-m", "gazehdr", "scenes", "--data-dir", str(tmp_path / "data")],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "flash" in out and "pic" in out and "pfm 6×4 · 7 cd/m² per unit (user: given" in out
    (guessed,) = [line for line in out.splitlines() if line.startswith("guessed ")]
    assert "(estimate: median luminance" in guessed and guessed.count("estimate:") == 1, guessed


def test_patch_switches_an_upload_layer_on_a_real_server(live_server, tmp_path: Path) -> None:
    """PATCH /api/scenes/NAME against uvicorn: another EXR layer reaches a session showing the
    scene (its scene map, read over /ws/view); bad layers and scales are 422 naming the scene
    and never a server path, a built-in 422, an unknown name 404."""
    import asyncio
    import json
    import math

    import websockets

    from gazehdr.protocol import SCENE_MAGIC, decode_scene_map
    from tests.test_server import http

    ones = np.ones((24, 40), np.float32)  # the frame's 5:3, so the map has no bars
    path = tmp_path / "ml.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    beauty = {"RGB": np.stack([ones] * 3, -1), **{f"diffuse.{c}": ones * 3 for c in "RGB"}}
    OpenEXR.File([OpenEXR.Part({**header, "name": "beauty"}, beauty)]).write(str(path))
    srv = live_server(size=(160, 96))
    url = f"{srv.url}/api/scenes/ml"
    assert http("PUT", url, path.read_bytes(), **srv.auth)[0] == 201

    def patch(target: str, values: object) -> tuple[int, dict]:
        body = json.dumps(values).encode()
        return http("PATCH", target, body, **{"Content-Type": "application/json"}, **srv.auth)

    status, info = patch(url, {"scale": 100.0})
    assert status == 200 and info["layers"] == ["", "diffuse"]  # RGB, diffuse.RGB
    assert info["layer"] == "" and info["scale"] == 100.0

    async def radiance(want: float, change: dict | None = None) -> float:
        """The median radiance of the scene maps a session showing `ml` sends (after PATCHing
        `change`, if given): the first near `want`, else the last one seen within 20 s (maps
        made before a change took effect may come first)."""
        async with websockets.connect(f"{srv.ws_url}/ws/view", additional_headers=srv.auth) as ws:
            await ws.send(json.dumps({"type": "scene", "name": "ml"}))
            await ws.send(json.dumps({"type": "scene_maps", "send": True}))
            if change is not None:
                assert (await asyncio.to_thread(patch, url, change))[0] == 200
            loop = asyncio.get_running_loop()
            deadline, value = loop.time() + 20.0, math.nan
            while loop.time() < deadline:
                message = await asyncio.wait_for(ws.recv(), 30)
                if isinstance(message, bytes) and message[:4] == SCENE_MAGIC:
                    value = float(np.median(decode_scene_map(message).radiance))
                    if abs(value - want) < 1e-3 * want:
                        break
            return value

    assert asyncio.run(radiance(100.0)) == pytest.approx(100.0, rel=1e-3)
    status, info = patch(url, {"layer": "diffuse"})
    assert status == 200 and info["layer"] == "diffuse" and info["scale"] == 100.0
    assert asyncio.run(radiance(300.0)) == pytest.approx(300.0, rel=1e-3)
    assert asyncio.run(radiance(100.0, {"layer": None})) == pytest.approx(100.0, rel=1e-3)

    refused = [
        (url, {"layer": "specular"}, 422, "scene 'ml': no layer 'specular'"),
        (url, {"layer": 3}, 422, "layer must be a layer name"),
        (url, {"scale": -1}, 422, "scale"),
        (url, {"scale": "bright"}, 422, "scale"),
        (url, {"gain": 2}, 422, "unknown scene setting(s) gain"),
        (f"{srv.url}/api/scenes/flash", {"scale": 2.0}, 422, "built-in"),
        (f"{srv.url}/api/scenes/nosuch", {"scale": 2.0}, 404, "no scene named 'nosuch'"),
    ]
    for target, values, code, words in refused:
        status, body = patch(target, values)
        assert status == code and words in body["detail"], (values, status, body)
        assert str(tmp_path) not in body["detail"] and ".exr" not in body["detail"], body
    status, info = http("GET", url)
    assert status == 200 and info["layer"] == "" and info["scale"] == 100.0  # unchanged
