"""Scenes: EXR loading (formats, scale, caps, bad files) and the built-in procedural scenes."""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from gazehdr.scenes import open_scene
from gazehdr.scenes.decoding import MAX_PIXELS, SceneError
from gazehdr.scenes.exr import write_exr
from gazehdr.scenes.image import ImageScene, decode
from gazehdr.scenes.procedural import (
    BUILTIN,
    COLORCHECKER_SRGB8,
    LUMA,
    AdaptationCross,
    CheckerNight,
    Flash,
    Lamp,
    srgb_to_linear,
)

COMPRESSIONS = [
    c for c in OpenEXR.Compression.__members__.values() if c.name != "NUM_COMPRESSION_METHODS"
]
#: Worst relative error of the lossy codecs on the smooth test image (0 = lossless).
LOSSY = {"PXR24": 1e-4, "B44": 0.02, "B44A": 0.02, "DWAA": 0.03, "DWAB": 0.03, "LJ2K": 0.05}
#: Luminance weights OpenEXR derives from the Rec.709 chromaticities (its computeYw).
YW_709 = np.array([0.212639, 0.715169, 0.072192])
#: ACES AP0 chromaticities and the published AP0 → linear Rec.709 matrix (Bradford adaptation).
AP0 = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767)
AP0_TO_REC709 = np.array(
    [
        [2.52168619, -1.13413099, -0.38755520],
        [-0.27647991, 1.37271909, -0.09623917],
        [-0.01537806, -0.15297534, 1.16835340],
    ]
)


def hdr_image(height: int = 24, width: int = 40) -> np.ndarray:
    """Smooth, four decades (0.1..1000), tinted: exact for lossless codecs, fair for lossy."""
    y, x = np.mgrid[0:height, 0:width]
    lum = 10 ** (-1 + 4 * x / (width - 1)) * (1 + 0.2 * np.sin(y / 3))
    return (lum[..., None] * np.array([1.0, 0.8, 0.6])).astype(np.float32)


def write_channels(path: Path, channels: dict[str, np.ndarray], **header: object) -> Path:
    OpenEXR.File({"type": OpenEXR.scanlineimage, **header}, channels).write(str(path))
    return path


def raw_exr(
    path: Path,
    width: int,
    height: int,
    planes: list[tuple[str, np.ndarray, int]],
    extra: bytes = b"",
) -> Path:
    """An uncompressed scanline EXR of HALF channels written byte by byte, for what the OpenEXR
    package cannot write: subsampled channels and a chromaticities attribute.

    `planes` are (name, samples, sampling) sorted by name, sampling the same in x and y.
    """

    def attr(name: str, kind: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 1, 0, s, s) for n, _, s in planes)
    box = struct.pack("<4i", 0, 0, width - 1, height - 1)
    header = b"\x76\x2f\x31\x01" + struct.pack("<i", 2)
    header += attr("channels", "chlist", chlist + b"\0") + attr("compression", "compression", b"\0")
    header += attr("dataWindow", "box2i", box) + attr("displayWindow", "box2i", box)
    header += attr("lineOrder", "lineOrder", b"\0") + attr(
        "pixelAspectRatio", "float", struct.pack("<f", 1)
    )
    header += attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
    header += attr("screenWindowWidth", "float", struct.pack("<f", 1)) + extra + b"\0"
    chunks = []
    for y in range(height):
        data = b"".join(p[y // s].astype("<f2").tobytes() for _, p, s in planes if y % s == 0)
        chunks.append(struct.pack("<ii", y, len(data)) + data)
    offsets = np.cumsum([len(header) + 8 * height] + [len(c) for c in chunks[:-1]])
    path.write_bytes(header + struct.pack(f"<{height}Q", *offsets) + b"".join(chunks))
    return path


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Photopic luminance Y (Rec.709 weights)."""
    return rgb.astype(np.float64) @ LUMA


# --- EXR: formats ------------------------------------------------------------------------------


def test_every_listed_compression_is_tested() -> None:
    names = {c.name.removesuffix("_COMPRESSION") for c in COMPRESSIONS}
    assert {"NO", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB"} <= names


@pytest.mark.parametrize("half", [False, True], ids=["float", "half"])
@pytest.mark.parametrize("compression", COMPRESSIONS, ids=lambda c: c.name)
def test_round_trip(tmp_path: Path, compression: OpenEXR.Compression, half: bool) -> None:
    img = hdr_image()
    write_exr(tmp_path / "img.exr", img, half=half, compression=compression)
    rgb = decode(tmp_path / "img.exr").rgb
    expected = img.astype(np.float16).astype(np.float32) if half else img
    assert rgb.dtype == np.float32 and rgb.shape == img.shape
    assert rgb.flags.c_contiguous
    tol = LOSSY.get(compression.name.removesuffix("_COMPRESSION"), 0.0)
    np.testing.assert_allclose(rgb, expected, rtol=tol, atol=0)


def test_scene_fields_and_render(tmp_path: Path) -> None:
    img = hdr_image()
    write_exr(tmp_path / "sunset.exr", img, white_luminance=1.0)
    scene = open_scene(str(tmp_path / "sunset.exr"))
    assert isinstance(scene, ImageScene)
    assert (scene.name, scene.animated, scene.scale.value) == ("sunset", False, 1.0)
    frame = scene.render(3.0, 1920, 1080)  # the size asked for is the simulator's business
    np.testing.assert_array_equal(frame, img)


def test_tiled_and_offset_data_window(tmp_path: Path) -> None:
    img = hdr_image()
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 16
    header = {"type": OpenEXR.tiledimage, "tiles": tiles, "compression": OpenEXR.ZIP_COMPRESSION}
    OpenEXR.File(header, {"RGB": img}).write(str(tmp_path / "tiled.exr"))
    np.testing.assert_array_equal(decode(tmp_path / "tiled.exr").rgb, img)
    window = (np.array([10, 20], np.int32), np.array([49, 43], np.int32))
    path = write_channels(tmp_path / "offset.exr", {"RGB": img}, dataWindow=window)
    np.testing.assert_array_equal(decode(path).rgb, img)


def test_rgba_ignores_alpha(tmp_path: Path) -> None:
    rgba = np.concatenate([hdr_image(), np.full((24, 40, 1), 0.25, np.float32)], axis=-1)
    path = write_channels(tmp_path / "rgba.exr", {"RGBA": rgba})
    np.testing.assert_array_equal(decode(path).rgb, rgba[..., :3])


def test_mixed_half_and_float_channels(tmp_path: Path) -> None:
    img = hdr_image()
    # (The package writes strided arrays wrongly: hand it contiguous planes.)
    g, b = np.ascontiguousarray(img[..., 1]), np.ascontiguousarray(img[..., 2])
    channels = {"R": img[..., 0].astype(np.float16), "G": g, "B": b}
    pixels = decode(write_channels(tmp_path / "mixed.exr", channels)).rgb
    np.testing.assert_array_equal(pixels[..., 1:], img[..., 1:])
    np.testing.assert_array_equal(pixels[..., 0], img[..., 0].astype(np.float16))


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
def test_luminance_only_is_grey(tmp_path: Path, dtype: type) -> None:
    y = hdr_image()[..., 0].astype(dtype)
    pixels = decode(write_channels(tmp_path / "y.exr", {"Y": y})).rgb
    for k in range(3):
        np.testing.assert_array_equal(pixels[..., k], y.astype(np.float32))


def _luminance_chroma(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenEXR's Y, RY = (R - Y)/Y, BY = (B - Y)/Y."""
    y = rgb @ YW_709
    return y, (rgb[..., 0] - y) / y, (rgb[..., 2] - y) / y


def test_luminance_chroma_full_resolution(tmp_path: Path) -> None:
    rgb = hdr_image().astype(np.float64)
    y, ry, by = _luminance_chroma(rgb)
    channels = {"Y": y.astype(np.float32), "RY": ry.astype(np.float32), "BY": by.astype(np.float32)}
    pixels = decode(write_channels(tmp_path / "yc.exr", channels)).rgb
    np.testing.assert_allclose(pixels, rgb, rtol=1e-5)


def test_luminance_chroma_subsampled(tmp_path: Path) -> None:
    # A constant colour, so that the 2×2 chroma samples reconstruct it exactly.
    rgb = np.array([3.0, 2.0, 1.0])
    y, ry, by = _luminance_chroma(rgb[None, :])
    lum = np.linspace(1, 64, 6 * 8).reshape(6, 8)
    planes = [
        ("BY", np.full((3, 4), by[0]), 2),
        ("RY", np.full((3, 4), ry[0]), 2),
        ("Y", lum * y[0], 1),
    ]
    pixels = decode(raw_exr(tmp_path / "yc.exr", 8, 6, planes)).rgb
    stored_y = (lum * y[0]).astype(np.float16).astype(np.float64)
    np.testing.assert_allclose(pixels, stored_y[..., None] * rgb / y[0], rtol=3e-3)


def test_chromaticities_are_converted_to_rec709(tmp_path: Path) -> None:
    # Linear-ramp greys and a pure AP0 red: neutrals stay neutral, red lands where published.
    lum = np.linspace(1, 2, 4)
    planes = [
        ("B", np.array([[0.0, *lum[1:]]]), 1),
        ("G", np.array([[0.0, *lum[1:]]]), 1),
        ("R", np.array([[1.0, *lum[1:]]]), 1),
    ]
    chroma = b"chromaticities\0chromaticities\0" + struct.pack("<i8f", 32, *AP0)
    pixels = decode(raw_exr(tmp_path / "aces.exr", 4, 1, planes, chroma)).rgb
    np.testing.assert_allclose(pixels[0, 0], AP0_TO_REC709[:, 0], atol=1e-4)
    for k in range(1, 4):
        np.testing.assert_allclose(pixels[0, k], np.float16(lum[k]), rtol=1e-5)


def test_nan_and_inf_pass_through(tmp_path: Path) -> None:
    img = hdr_image()
    img[0, 0] = [np.nan, np.inf, -np.inf]
    write_exr(tmp_path / "bad.exr", img)
    pixels = decode(tmp_path / "bad.exr").rgb
    assert np.isnan(pixels[0, 0, 0]) and pixels[0, 0, 1] == np.inf and pixels[0, 0, 2] == -np.inf
    np.testing.assert_array_equal(pixels[1:], img[1:])


# --- EXR: scale --------------------------------------------------------------------------------


def test_white_luminance_scales_and_explicit_scale_overrides(tmp_path: Path) -> None:
    img = hdr_image()
    path = write_channels(tmp_path / "w.exr", {"RGB": img}, whiteLuminance=250.0)
    from_file = ImageScene.open(path)
    assert (from_file.scale.value, from_file.scale.source) == (250.0, "file")
    np.testing.assert_allclose(from_file.pixels, img * 250, rtol=1e-6)
    explicit = ImageScene.open(path, scale=2.0)
    assert (explicit.scale.value, explicit.scale.source) == (2.0, "user")
    np.testing.assert_allclose(explicit.pixels, img * 2, rtol=1e-6)
    np.testing.assert_allclose(open_scene(str(path), scale=3.0).render(0, 1, 1), img * 3, rtol=1e-6)


def test_scale_without_white_luminance_is_an_estimate(tmp_path: Path) -> None:
    """A relative file: the median luminance goes to the kind's metered luminance (EV 15 for
    daylight: 2^15 · 12.5 / 100 = 4096 cd/m²), and says so; the user's scale replaces it, and
    going back (None) restores it without reading the file again."""
    img = hdr_image()
    write_exr(tmp_path / "plain.exr", img)
    scene = ImageScene.open(tmp_path / "plain.exr")
    median = np.median(img @ np.array([0.2126, 0.7152, 0.0722], np.float32))
    assert scene.scale.source == "estimate" and scene.scale.kind == "daylight"
    assert scene.scale.value == pytest.approx(4096.0 / median, rel=1e-5)
    assert "estimate" in scene.scale.note and "EV 15" in scene.scale.note
    scene.set_scale(0.5)
    assert (scene.scale.value, scene.scale.source) == (0.5, "user")
    np.testing.assert_allclose(scene.render(0, 1, 1), img / 2)
    scene.set_scale(None, "interior")  # EV 6: 8 cd/m²
    assert scene.scale.value == pytest.approx(8.0 / median, rel=1e-5)
    assert ImageScene.open(tmp_path / "plain.exr", kind="moonlight").scale.kind == "moonlight"


def test_estimate_kind_from_the_name(tmp_path: Path) -> None:
    write_exr(tmp_path / "night.exr", hdr_image())
    write_exr(tmp_path / "Kitchen-interior_2k.exr", hdr_image())
    assert ImageScene.open(tmp_path / "night.exr").scale.kind == "street"
    assert ImageScene.open(tmp_path / "Kitchen-interior_2k.exr").scale.kind == "interior"
    with pytest.raises(ValueError, match="unknown scene kind 'cave'; one of daylight"):
        ImageScene.open(tmp_path / "night.exr", kind="cave")


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf])
def test_bad_scale(tmp_path: Path, scale: float) -> None:
    write_exr(tmp_path / "s.exr", hdr_image())
    with pytest.raises(SceneError, match="scale"):
        ImageScene.open(tmp_path / "s.exr", scale=scale)


def test_bad_white_luminance_is_ignored_and_said(tmp_path: Path) -> None:
    path = write_channels(tmp_path / "w.exr", {"RGB": hdr_image()}, whiteLuminance=-5.0)
    scene = ImageScene.open(path)
    assert scene.scale.source == "estimate"
    assert scene.describe()["notes"] == ["whiteLuminance -5.0 ignored: not a positive number"]
    assert ImageScene.open(path, scale=1.0).scale.value == 1.0


# --- EXR: size cap -----------------------------------------------------------------------------


def test_pixel_cap(tmp_path: Path) -> None:
    write_exr(tmp_path / "small.exr", hdr_image(10, 20))
    assert decode(tmp_path / "small.exr", max_pixels=200).rgb.shape == (10, 20, 3)
    with pytest.raises(SceneError, match=r"small\.exr.*20×10.*200 pixels.*limit of 199"):
        ImageScene.open(tmp_path / "small.exr", max_pixels=199)
    assert MAX_PIXELS == 8192 * 8192


def test_huge_header_refused_before_pixels_are_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A valid header claiming 100000×100000 pixels over a few bytes of data: refused from the
    header alone (a pixel read would have failed as truncated, or tried to allocate 120 GB)."""
    write_exr(tmp_path / "src.exr", hdr_image(4, 4), compression="none")
    data = (tmp_path / "src.exr").read_bytes()
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    huge = tmp_path / "huge.exr"
    huge.write_bytes(data[:at] + struct.pack("<4i", 0, 0, 99_999, 99_999) + data[at + 16 :])

    reads = []
    real_file = OpenEXR.File

    def spy(*args: object, **kwargs: object) -> object:
        reads.append(kwargs.get("header_only", False))
        return real_file(*args, **kwargs)

    monkeypatch.setattr(OpenEXR, "File", spy)
    with pytest.raises(SceneError, match=r"huge\.exr.*100000×100000.*10,000,000,000 pixels"):
        ImageScene.open(huge)
    assert reads == [True]


# --- EXR: bad files ----------------------------------------------------------------------------


def _valid_exr(tmp_path: Path) -> bytes:
    write_exr(tmp_path / "valid.exr", hdr_image(), compression="zip")
    return (tmp_path / "valid.exr").read_bytes()


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (lambda d: b"", "empty"),
        (lambda d: np.random.default_rng(7).bytes(4096), "not an HDR image this viewer reads"),
        (lambda d: d[:4], "truncated"),
        (lambda d: d[:60], "truncated"),
        (lambda d: d[: len(d) // 2], "truncated"),
        (lambda d: d[:-40], "truncated"),
    ],
    ids=["empty", "random", "magic-only", "cut-header", "cut-half", "cut-tail"],
)
def test_bad_file(tmp_path: Path, content: Callable[[bytes], bytes], reason: str) -> None:
    path = tmp_path / "broken file.exr"
    path.write_bytes(content(_valid_exr(tmp_path)))
    with pytest.raises(SceneError, match=reason) as info:
        ImageScene.open(path)
    assert str(path) in str(info.value)


def test_every_truncation_is_a_scene_error(tmp_path: Path) -> None:
    data = _valid_exr(tmp_path)
    path = tmp_path / "cut.exr"
    for n in range(0, len(data), max(1, len(data) // 50)):
        path.write_bytes(data[:n])
        with pytest.raises(SceneError, match=r"cut\.exr"):
            ImageScene.open(path)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match=r"nothere\.exr: no such file"):
        ImageScene.open(tmp_path / "nothere.exr")
    (tmp_path / "dir.exr").mkdir()
    with pytest.raises(SceneError, match=r"dir\.exr: is a directory"):
        ImageScene.open(tmp_path / "dir.exr")


def test_no_usable_channels(tmp_path: Path) -> None:
    path = write_channels(tmp_path / "depth.exr", {"Z": np.ones((4, 4), np.float32)})
    with pytest.raises(SceneError, match=r"depth\.exr: no usable channels.*found Z"):
        ImageScene.open(path)
    ids = np.ones((4, 4), np.uint32)
    path = write_channels(tmp_path / "ids.exr", {"R": ids, "G": ids, "B": ids})
    with pytest.raises(SceneError, match=r"ids\.exr: channel R holds uint32"):
        ImageScene.open(path)


# --- EXR: writing ------------------------------------------------------------------------------


def test_write_exr_checks_and_leaves_no_temporary(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="H×W×3"):
        write_exr(tmp_path / "a.exr", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="half"):
        write_exr(tmp_path / "a.exr", np.full((2, 2, 3), 1e7, np.float32), half=True)
    with pytest.raises(ValueError, match="unknown EXR compression"):
        write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)), compression="gzip")
    with pytest.raises(OSError, match="no-such-dir"):
        write_exr(tmp_path / "no-such-dir" / "a.exr", np.zeros((2, 2, 3)))
    write_exr(tmp_path / "a.exr", hdr_image(), compression="PIZ")
    write_exr(tmp_path / "a.exr", hdr_image() * 2, compression="none")  # replaces it
    assert os.listdir(tmp_path) == ["a.exr"]
    np.testing.assert_array_equal(decode(tmp_path / "a.exr").rgb, hdr_image() * 2)


# --- procedural scenes -------------------------------------------------------------------------

SIZES = [(64, 36), (320, 180)]


def at(frame: np.ndarray, x: float, y: float) -> float:
    """Luminance of the pixel holding frame fractions (x, y)."""
    h, w = frame.shape[:2]
    return float(luminance(frame[min(int(y * h), h - 1), min(int(x * w), w - 1)]))


def test_builtin_names() -> None:
    assert set(BUILTIN) == {"flash", "lamp", "checker-night", "adaptation-cross"}
    for name in BUILTIN:
        assert open_scene(name).name == name


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_procedural_frames_are_sane_and_deterministic(name: str, size: tuple[int, int]) -> None:
    w, h = size
    scene = BUILTIN[name]()
    for t in (0.0, 1.05, 6.5):
        frame = scene.render(t, w, h)
        assert frame.shape == (h, w, 3) and frame.dtype == np.float32
        assert frame.flags.c_contiguous
        assert np.isfinite(frame).all() and (frame >= 0).all()
        np.testing.assert_array_equal(frame, BUILTIN[name]().render(t, w, h))
        frame[:] = -1  # callers get their own copy
        assert (scene.render(t, w, h) >= 0).all()


def test_procedural_size_checks() -> None:
    with pytest.raises(ValueError, match="positive"):
        Lamp().render(0.0, 0, 10)
    with pytest.raises(TypeError, match="integers"):
        Lamp().render(0.0, 64.0, 36)  # type: ignore[arg-type]
    assert Lamp().render(0.0, np.int64(64), np.int32(36)).shape == (36, 64, 3)
    with pytest.raises(ValueError, match="pixels"):
        Lamp().render(0.0, 100_000, 100_000)


def test_flash_timing() -> None:
    flash = Flash()
    assert flash.animated
    on = [1.0, 1.06, 1.1249, 5.0, 5.1, 9.0, 401.0]
    off = [0.0, 0.999, 1.125, 1.5, 4.999, 5.125, 8.99]
    assert all(flash.flash_on(t) for t in on)
    assert not any(flash.flash_on(t) for t in off)
    # Exactly 1/8 s per period, sampled at 10 kHz over two periods.
    ts = 1.0 + np.arange(80_000) / 10_000
    assert sum(flash.flash_on(float(t)) for t in ts) == 2 * 1250
    custom = Flash(period=2.0, first=0.5, duration=0.25)
    assert custom.flash_on(2.6) and not custom.flash_on(2.75)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_flash_luminances(size: tuple[int, int]) -> None:
    flash = Flash()
    cx, cy = flash.flash_centre
    dark, lit = flash.render(0.5, *size), flash.render(1.05, *size)
    y_dark, y_lit = luminance(dark), luminance(lit)
    assert y_dark.max() <= 2.0 * (1 + 1e-6)
    assert 0.5 <= np.median(y_dark) <= 2.0 and y_dark.std() > 0.1  # a textured wall, not blank
    assert at(lit, cx, cy) == pytest.approx(1e7, rel=1e-6)
    np.testing.assert_allclose(lit[int(cy * size[1]), int(cx * size[0])], 1e7, rtol=1e-6)
    assert y_lit.max() == pytest.approx(1e7, rel=1e-6)
    assert at(dark, cx, cy) < 2.0
    # Only the flash and its halo change; far away the frames are identical.
    changed = np.abs(y_lit - y_dark) > 0
    assert changed.mean() < 0.05
    assert np.array_equal(dark[:, : size[0] // 4], lit[:, : size[0] // 4])


def test_flash_halo() -> None:
    flash = Flash()
    w, h = 1280, 720
    cx, cy = flash.flash_centre
    frame = flash.render(1.0, w, h)
    hw = flash.flash_half_size[0]
    # Beside the head the glow falls from 1e5 to 1e4 evenly in log across the halo.
    col = int((cx + (hw + flash.halo_radius / 2) * h / w) * w)
    d = ((col + 0.5) / w - cx) * w / h - hw
    assert 0.4 < d / flash.halo_radius < 0.6
    assert at(frame, (col + 0.5) / w, cy) == pytest.approx(
        1e5 * 0.1 ** (d / flash.halo_radius), rel=1e-3
    )
    assert 1e4 <= at(frame, cx + (hw + 0.002) * h / w, cy) <= 1e5
    assert at(frame, cx + (hw + flash.halo_radius + 0.01) * h / w, cy) < 2.0


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_lamp_span(size: tuple[int, int]) -> None:
    lamp = Lamp()
    frame = lamp.render(0.0, *size)
    y = luminance(frame)
    assert y.min() == pytest.approx(0.1, rel=0.01)
    assert y.max() == pytest.approx(1e6, rel=0.01)
    assert not lamp.animated


def test_lamp_regions() -> None:
    lamp = Lamp()
    frame = lamp.render(0.0, 640, 360)
    y = luminance(frame)
    bx, by = lamp.bulb_centre
    py = lamp.book_centre[1]
    assert 1e3 <= at(frame, bx, by - 0.1) <= 1e4  # shade
    assert 0.1 <= at(frame, 0.01, 0.01) <= 0.2  # far corner of the wall
    page = y[int((py - 0.1) * 360) : int((py + 0.1) * 360), int(0.4 * 640) : int(0.47 * 640)]
    assert 70 <= np.percentile(page, 90) <= 110  # paper
    assert page.min() < 10  # ink lines
    rows = page.mean(axis=1)
    assert rows.max() / rows.min() > 2  # lines of text, not a uniform grey


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_checker_night(size: tuple[int, int]) -> None:
    chart = CheckerNight()
    frame = chart.render(0.0, *size)
    rects = chart.patch_rects(*size)
    assert len(rects) == 24
    white = rects[18]
    assert white[0] == min(r[0] for r in rects) and white[1] == max(r[1] for r in rects)
    for rect, rgb in zip(rects, chart.patch_rgb, strict=True):
        centre = frame[
            int((rect[1] + rect[3]) / 2 * size[1]), int((rect[0] + rect[2]) / 2 * size[0])
        ]
        np.testing.assert_allclose(centre, rgb, rtol=1e-5)
    white_centre = ((white[0] + white[2]) / 2, (white[1] + white[3]) / 2)
    assert at(frame, *white_centre) == pytest.approx(0.05, rel=0.01)
    assert at(frame, 0.01, 0.01) == pytest.approx(0.005, rel=1e-4)  # dark grey ground


def test_checker_night_colours() -> None:
    assert srgb_to_linear(np.array([0, 255])).tolist() == [0.0, 1.0]
    assert float(srgb_to_linear(np.array(128))) == pytest.approx(0.21586, abs=1e-5)
    chart = CheckerNight(white_luminance=1.0)
    rgb = chart.patch_rgb
    assert float(luminance(rgb[18])) == pytest.approx(1.0)
    # White (243, 243, 242) decodes to Y = 0.895667 (worked by hand from the sRGB EOTF).
    np.testing.assert_allclose(
        rgb, srgb_to_linear(np.array(COLORCHECKER_SRGB8)) / 0.895667, rtol=1e-5
    )
    np.testing.assert_allclose(CheckerNight().patch_rgb, rgb * 0.05)
    assert (rgb[14, 0] > rgb[14, 1:]).all() and (rgb[12, 2] > rgb[12, :2]).all()  # red, blue


def test_adaptation_cross() -> None:
    scene = AdaptationCross()
    assert scene.animated and scene.switch_at == 6.0
    assert scene.grey_luminance == pytest.approx(math.sqrt(300 * 30))
    before, after = scene.render(5.999, 320, 180), scene.render(6.0, 320, 180)
    assert [
        at(before, x, y) for x, y in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]
    ] == (pytest.approx([300, 30, 30, 300], rel=1e-5))
    for x, y in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]:
        assert at(after, x, y) == pytest.approx(94.868, rel=1e-4)
    arm = scene.cross_size * 0.5
    for frame in (before, after):
        assert at(frame, 0.5 + arm * 180 / 320, 0.5) < 10 and at(frame, 0.5, 0.5 - arm) < 10
    assert at(scene.render(0.0, 64, 36), 0.5, 0.5) == pytest.approx(1.0)  # never sub-pixel
    early = AdaptationCross(switch_at=2.0, light_luminance=1000, dark_luminance=10)
    assert at(early.render(2.0, 64, 36), 0.1, 0.1) == pytest.approx(100, rel=1e-5)
    assert at(early.render(1.9, 64, 36), 0.1, 0.1) == pytest.approx(1000, rel=1e-5)


@pytest.mark.parametrize(
    "make",
    [
        lambda: Flash(period=0.0),
        lambda: Flash(duration=5.0),
        lambda: Flash(flash_luminance=math.nan),
        lambda: Lamp(bulb_luminance=-1.0),
        lambda: CheckerNight(white_luminance=0.0),
        lambda: AdaptationCross(dark_luminance=0.0),
    ],
)
def test_bad_parameters(make: Callable[[], object]) -> None:
    with pytest.raises(ValueError, match="must be"):
        make()


@pytest.mark.parametrize("name", ["flash", "adaptation-cross", "lamp"])
def test_next_change_is_exactly_where_the_state_changes(name: str) -> None:
    scene = open_scene(name)
    for t in np.linspace(0.0, 13.0, 521):
        change = scene.next_change(float(t))
        if change is None:
            assert all(scene.state_at(u) == scene.state_at(t) for u in (t + 1, t + 100))
            continue
        assert change > t
        inside = np.linspace(t, change, 7)[:-1]
        assert all(scene.state_at(float(u)) == scene.state_at(float(t)) for u in inside)
        assert scene.state_at(change) != scene.state_at(float(t))
