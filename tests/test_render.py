"""Offline rendering: the dither rule, the render loop, and the `gazehdr` command line."""

from __future__ import annotations

import math
import sys
import types
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from gazehdr.cli import main
from gazehdr.dither import dither8
from gazehdr.drivers.synthetic import FixedGaze
from gazehdr.render import render
from gazehdr.sim.models import ACUITY_MODELS, AFTERIMAGE_MODELS

TINY = ["--size", "64x36", "--seconds", "0.1", "--fps", "30", "--backend", "reference", "--quiet"]


def _frames(out: Path, suffix: str = ".png") -> list[Path]:
    return sorted(out.glob(f"frame_*{suffix}"))


# --- dither -----------------------------------------------------------------------------------


def test_dither_picks_only_the_two_neighbouring_codes() -> None:
    rng = np.random.default_rng(0)
    v = rng.random((120, 160, 3), dtype=np.float32)
    codes = dither8(v, np.random.default_rng(1)).astype(np.int64)
    low = np.floor(np.float32(255) * v).astype(np.int64)  # same float32 arithmetic as dither8
    assert codes.dtype == np.int64 and set(np.unique(codes - low)) == {0, 1}


def test_dither_mean_over_frames_is_the_value() -> None:
    # 32×32×3 values spread over the whole range, with every fraction of a code value.
    v = np.linspace(0, 1, 32 * 32 * 3, dtype=np.float32).reshape(32, 32, 3)
    rng = np.random.default_rng(2)
    frames = 400
    mean = sum(dither8(v, rng).astype(np.float64) for _ in range(frames)) / frames
    target = 255.0 * v.astype(np.float64)
    # Each entry's mean is a Bernoulli mean plus floor(255 v): sd = sqrt(p(1-p)/400) <= 0.025
    # code values. 5 sd bounds every one of the 3072 entries (a 3072 × 6e-7 chance to fail by
    # luck under the normal approximation; the seed is fixed anyway); the global mean of all
    # 1.2 M decisions is held to 3 sd.
    assert np.abs(mean - target).max() <= 5 * 0.5 / math.sqrt(frames)
    assert abs((mean - target).mean()) <= 3 * 0.5 / math.sqrt(frames * v.size)


def test_dither_decisions_are_independent() -> None:
    # v half-way between codes: every entry rounds up with probability 1/2.
    v = np.full((32, 32, 3), 100.5 / 255, dtype=np.float32)
    rng = np.random.default_rng(3)
    up = np.stack([dither8(v, rng) for _ in range(100)]).astype(np.float64) - 100  # F×H×W×3
    assert set(np.unique(up)) == {0.0, 1.0}
    assert abs(up.mean() - 0.5) < 0.01
    # With n pairs, independent decisions give |r| < 4/sqrt(n) except with chance ~6e-5.
    pairs = {
        "red vs green": (up[..., 0], up[..., 1]),
        "green vs blue": (up[..., 1], up[..., 2]),
        "left vs right neighbour": (up[:, :, :-1], up[:, :, 1:]),
        "upper vs lower neighbour": (up[:, :-1], up[:, 1:]),
        "frame vs next frame": (up[:-1], up[1:]),
    }
    for name, (a, b) in pairs.items():
        r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
        assert abs(r) < 4 / math.sqrt(a.size), name


def test_dither_clips_and_refuses_nan() -> None:
    rng = np.random.default_rng(4)
    v = np.array([[[-0.5, 0.0, 1.0], [1.0, 2.0, 0.0]]], dtype=np.float32)
    assert dither8(v, rng).tolist() == [[[0, 0, 255], [255, 255, 0]]]
    with pytest.raises(ValueError, match="NaN"):
        dither8(np.array([[[0.5, np.nan, 0.5]]]), rng)


# --- render loop ------------------------------------------------------------------------------


class _Box:
    """A bright square on a dim ground; counts how often it is drawn."""

    name = "box"

    def __init__(self, animated: bool) -> None:
        self.animated = animated
        self.times: list[float] = []

    def render(self, t: float, width: int, height: int) -> np.ndarray:
        self.times.append(t)
        rgb = np.full((height, width, 3), 20.0, np.float32)
        rgb[height // 3 : 2 * height // 3, width // 3 : 2 * width // 3] = 3e4 * (1 + t)
        return rgb

    def state_at(self, t: float) -> object:
        return t if self.animated else None  # brightens continuously

    def next_change(self, t: float) -> float | None:
        return None


@pytest.mark.parametrize("animated", [False, True])
def test_static_scenes_load_once_animated_every_frame(tmp_path: Path, animated: bool) -> None:
    scene = _Box(animated)
    summary = render(
        scene,
        FixedGaze(0.3, 0.6),
        seconds=0.1,
        fps=40,
        width=32,
        height=18,
        seed=0,
        backend="reference",
        out_dir=tmp_path,
        progress=False,
    )
    assert summary.frames == 4 and summary.out_dir == tmp_path and summary.wall_seconds > 0
    # Each step sees the scene as it is at the step's start, as a live session's does
    # (gazehdr.eye): the steps ending at 0.05, 0.075 and 0.1 look at it anew.
    assert scene.times == ([0.0, 0.025, 0.05] if animated else [0.0])
    assert [p.name for p in _frames(tmp_path)] == [f"frame_0000{i}.png" for i in range(4)]


def test_render_refuses_to_mix_with_old_frames(tmp_path: Path) -> None:
    kwargs = dict(seconds=0.1, fps=20, width=16, height=16, seed=0, backend="reference")
    render(_Box(False), FixedGaze(), out_dir=tmp_path, progress=False, **kwargs)
    with pytest.raises(ValueError, match=r"already holds frames.*pass --overwrite"):
        render(_Box(False), FixedGaze(), out_dir=tmp_path, progress=False, **kwargs)
    (tmp_path / "notes.txt").write_text("keep me")
    render(_Box(False), FixedGaze(), out_dir=tmp_path, progress=False, overwrite=True, **kwargs)
    assert len(_frames(tmp_path)) == 2 and (tmp_path / "notes.txt").exists()


# --- command line -----------------------------------------------------------------------------


def test_cli_renders_8bit_rgb_frames(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["render", "flash", *TINY, "--out", str(tmp_path / "a")]) == 0
    frames = _frames(tmp_path / "a")
    assert [p.name for p in frames] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    for path in frames:
        with Image.open(path) as image:
            assert image.format == "PNG" and image.mode == "RGB" and image.size == (64, 36)
    assert "wrote 3 frames" in capsys.readouterr().out


def test_cli_is_deterministic_for_a_seed(tmp_path: Path) -> None:
    def run(name: str, seed: int) -> list[bytes]:
        out = tmp_path / name
        assert main(["render", "lamp", *TINY, "--seed", str(seed), "--out", str(out)]) == 0
        return [p.read_bytes() for p in _frames(out)]

    first = run("a", 1)
    assert run("b", 1) == first
    assert run("c", 2) != first


def test_cli_exr_holds_the_undithered_values(tmp_path: Path) -> None:
    out = tmp_path / "exr"
    assert main(["render", "flash", *TINY, "--gaze", "0.3,0.4", "--exr", "--out", str(out)]) == 0
    pngs, exrs = _frames(out), _frames(out, ".exr")
    assert len(pngs) == len(exrs) == 3
    for png, exr in zip(pngs, exrs, strict=True):
        v = OpenEXR.File(str(exr)).channels()["RGB"].pixels
        assert v.dtype == np.float32 and v.shape == (36, 64, 3)
        with Image.open(png) as image:
            codes = np.asarray(image).astype(np.int64)
        low = np.floor(np.float32(255) * np.clip(v, 0, 1)).astype(np.int64)
        assert np.isin(codes - low, (0, 1)).all()


def test_cli_video_is_the_frames_as_one_lossless_animation(tmp_path: Path, capsys) -> None:
    out = tmp_path / "video"
    args = ["render", "flash", *TINY, "--fps", "24", "--seconds", "0.2", "--video"]
    assert main([*args, "--out", str(out)]) == 0
    frames = _frames(out)
    assert len(frames) == 5
    with Image.open(out / "render.apng") as movie:
        assert movie.format == "PNG" and getattr(movie, "is_animated", False)
        assert movie.n_frames == 5 and movie.info.get("loop") == 0
        for k, path in enumerate(frames):
            movie.seek(k)
            assert movie.info["duration"] == pytest.approx(1000 / 24, abs=0.5)
            with Image.open(path) as still:
                np.testing.assert_array_equal(np.asarray(movie.convert("RGB")), np.asarray(still))
    # Without --overwrite the render is refused, and the refusal names the option; with it,
    # the old animation goes with the old frames: nothing is mixed.
    capsys.readouterr()
    assert main([*args, "--out", str(out), "--seconds", "0.1"]) == 2
    assert "already holds frames" in (err := capsys.readouterr().err) and "--overwrite" in err
    assert main([*args, "--out", str(out), "--overwrite", "--seconds", "0.1"]) == 0
    with Image.open(out / "render.apng") as movie:
        assert movie.n_frames == 3


def test_apng_writer_refuses_a_short_or_ragged_animation(tmp_path: Path) -> None:
    from gazehdr.apng import ApngWriter

    frame = np.zeros((4, 6, 3), np.uint8)
    writer = ApngWriter(tmp_path / "short.apng", frames=2, fps=30)
    writer.add(frame)
    with pytest.raises(ValueError, match="1 of 2 frames"):
        writer.close()
    with ApngWriter(tmp_path / "ragged.apng", frames=2, fps=30) as writer:
        writer.add(frame)
        with pytest.raises(ValueError, match="frame 1 is 5x4"):
            writer.add(np.zeros((4, 5, 3), np.uint8))
        writer.add(frame)


def test_cli_reads_a_csv_gaze_track(tmp_path: Path) -> None:
    csv = tmp_path / "gaze.csv"
    csv.write_text("t,x,y,eyes_open\n0,0.2,0.5,1\n0.05,0.8,0.5,0\n")
    assert (
        main(["render", "checker-night", *TINY, "--gaze", str(csv), "--out", str(tmp_path / "o")])
        == 0
    )
    assert len(_frames(tmp_path / "o")) == 3


def test_cli_renders_with_opencl(tmp_path: Path) -> None:
    args = ["render", "flash", "--size", "32x18", "--seconds", "0.05", "--fps", "40", "--quiet"]
    assert main([*args, "--backend", "opencl", "--out", str(tmp_path / "cl")]) == 0
    frames = _frames(tmp_path / "cl")
    assert len(frames) == 2
    with Image.open(frames[-1]) as image:
        assert image.mode == "RGB" and image.size == (32, 18)


MODEL_OPTIONS = [("--afterimage", n) for n in AFTERIMAGE_MODELS if n != "jacobs"] + [
    ("--acuity", n) for n in ACUITY_MODELS if n != "stochastic"
]


@pytest.mark.parametrize(("option", "name"), MODEL_OPTIONS, ids=[n for _, n in MODEL_OPTIONS])
def test_cli_renders_with_each_model(tmp_path: Path, option: str, name: str) -> None:
    """Each model by name gives frames of its own: after 0.5 s on the lamp's glare (and in
    the dim room, where acuity models differ) the last frame is not the default model's."""
    args = ["render", "lamp", *TINY, "--seconds", "0.5", "--fps", "10", "--gaze", "0.45,0.35"]

    def last_frame(out: Path, *extra: str) -> bytes:
        assert main([*args, *extra, "--exr", "--out", str(out)]) == 0
        frames = _frames(out, ".exr")
        assert len(frames) == 5
        return OpenEXR.File(str(frames[-1])).channels()["RGB"].pixels.tobytes()

    assert last_frame(tmp_path / "model", option, name) != last_frame(tmp_path / "default")


def test_cli_help_names_every_model(capsys: pytest.CaptureFixture) -> None:
    for command in ("render", "serve"):
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for name in (*AFTERIMAGE_MODELS, *ACUITY_MODELS):
            assert name in text, (command, name)


def _bad_exr(tmp_path: Path) -> str:
    path = tmp_path / "broken.exr"
    path.write_bytes(b"not an exr at all")
    return str(path)


def _bad_params(tmp_path: Path) -> str:
    path = tmp_path / "preset.json"
    path.write_text('{"n": 0.7, "no_such_parameter": 1}')
    return str(path)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "flash", "--size", "64by36"], "--size: expected WIDTHxHEIGHT"),
        (["render", "flash", "--size", "8x8"], "8x8 is out of range"),
        (["render", "flash", "--size", "8000x100"], "out of range"),
        (["render", "no-such-scene"], "no-such-scene"),
        (["render", "{bad_exr}"], "broken.exr"),
        (["render", "flash", "--fps", "0"], "fps"),
        (["render", "flash", "--seconds", "nan"], "seconds"),
        (["render", "flash", "--seed", "-1"], "seed must be a non-negative integer"),
        (["render", "flash", "--gaze", "1.5,0.5"], "normalised"),
        (["render", "flash", "--gaze", "{tmp}/missing.csv"], "not found"),
        (["render", "flash", "--params", "{bad_params}"], "no_such_parameter"),
        (["render", "flash", "--backend", "cuda"], "invalid choice"),
        (
            ["render", "flash", "--afterimage", "magic"],
            "unknown afterimage model 'magic'; choose one of jacobs, ritschel, mikamo",
        ),
        (
            ["render", "flash", "--acuity", "blurry"],
            "unknown acuity model 'blurry'; choose one of stochastic, none, gaussian, bilateral",
        ),
        (["render", "flash", "--frobnicate"], "unrecognized arguments: --frobnicate"),
        (["render", "flash", "--out", "{tmp}/file.txt/sub"], "file.txt"),
        (["serve", "--acuity", "blurry"], "unknown acuity model 'blurry'; choose one of"),
        (["serve", "--split", "ritschel+sharp"], "unknown acuity model 'sharp'; choose one of"),
        (["launch"], "invalid choice"),
        ([], "required: COMMAND"),
    ],
)
def test_cli_errors_are_one_line_with_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, args: list[str], message: str
) -> None:
    (tmp_path / "file.txt").write_text("")
    fill = {"tmp": tmp_path, "bad_exr": _bad_exr(tmp_path), "bad_params": _bad_params(tmp_path)}
    argv = [a.format(**fill) for a in args]
    if argv[:1] == ["render"] and "--out" not in argv:
        argv += ["--out", str(tmp_path / "out"), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("gazehdr: error: ") and err.count("\n") == 1, err
    assert message in err
    assert not _frames(tmp_path / "out")


def test_cli_lists_scenes(capsys: pytest.CaptureFixture) -> None:
    assert main(["scenes"]) == 0
    names = capsys.readouterr().out.split()
    assert {"flash", "lamp", "checker-night", "adaptation-cross"} <= set(names)


def test_cli_help_names_every_model_and_scene_format(capsys: pytest.CaptureFixture) -> None:
    """The help is written out (the command line imports no model code up front): it must
    name every model the registries accept, and every image format a scene file may be."""
    from gazehdr.scenes.image import SUFFIXES
    from gazehdr.sim.models import ACUITY_MODELS, AFTERIMAGE_MODELS

    for command in ("render", "serve"):
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        # the options' own lines: the last mention of each (the first is the usage line)
        afterimage = text[text.rindex("--afterimage NAME") : text.rindex("--acuity NAME")]
        acuity = text[text.rindex("--acuity NAME") + 13 :]
        acuity = acuity[: acuity.index(" --")]
        assert all(name in afterimage for name in AFTERIMAGE_MODELS), (afterimage, command)
        assert all(name in acuity for name in ACUITY_MODELS), (acuity, command)
        assert all(suffix in text for suffix in SUFFIXES.values()), command
    assert main(["render", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "EXR file" not in text and "per EXR pixel unit" not in text


def test_cli_passes_bench_arguments_through(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[list[str]] = []
    fake = types.ModuleType("gazehdr.bench.pipeline")
    fake.main = lambda argv: seen.append(argv) or 3  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "gazehdr.bench.pipeline", fake)
    assert main(["bench", "--frames", "5", "--help"]) == 3
    assert seen == [["--frames", "5", "--help"]]
