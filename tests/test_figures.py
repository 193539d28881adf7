"""`gazehdr figures`: every file is written, and each figure shows what the paper's caption says.

The command runs once, at a small size, on the OpenCL backend (PoCL in CI); the content checks
read the numbers it stores in figures.json and the PNGs themselves.
"""

from __future__ import annotations

import colorsys
import html
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gazehdr.cli import main
from gazehdr.figures import FIGURES, photos
from gazehdr.sim import Params

SMALL = ["--size", "128x72", "--quiet", "--seed", "3"]


@pytest.fixture(scope="module")
def figs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("figs")
    assert main(["figures", "--out", str(out), *SMALL]) == 0
    return out, json.loads((out / "figures.json").read_text())


def test_every_figure_writes_its_files(figs: tuple[Path, dict]) -> None:
    out, data = figs
    assert set(data) == {f.key for f in FIGURES}
    pngs = [name for fig in data.values() for name in fig["images"]]
    assert len(pngs) >= len(FIGURES) and sorted(p.name for p in out.glob("*.png")) == sorted(pngs)
    index = (out / "index.html").read_text()
    assert set(re.findall(r"<img src='([^']+)'", index)) == set(pngs)
    for fig in FIGURES:
        assert f"<section id='fig{fig.key}'>" in index and "Not made" not in index
    for name in pngs:
        with Image.open(out / name) as img:
            rgb = np.asarray(img.convert("RGB"), np.float64)
        assert rgb.shape[0] > 50 and rgb.shape[1] > 100
        assert rgb.std() > 10, f"{name} is blank"


def test_fig4_bleaching_rises_in_the_flash_and_decays_as_eq5(figs: tuple[Path, dict]) -> None:
    fig = figs[1]["4"]
    t, B = np.array(fig["t"]), np.array(fig["B"])
    assert B[0].max() < 1e-3  # on black before the flash
    end = B[t == 0][0]
    assert end[0] > 0.99 and end[1] > 0.99 and 0.2 < end[2] < 0.5
    after = B[t >= 0]
    assert (np.diff(after, axis=0) <= 1e-6).all()  # only decays once the flash is over
    # B(t) = B(0) exp(-b2 t) in the dark (Eq. 5 with I = 0): half-lives within 5 %.
    expected = np.log(2) / np.array(Params().b2)
    assert np.allclose(fig["half_life_s"], expected, rtol=0.05)


def hue(rgb) -> float:
    """HSV hue of RGB, degrees: 0 red, 60 yellow, 120 green, 180 cyan, 240 blue, 300 magenta."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    return colorsys.rgb_to_hsv(*(rgb / max(rgb.max(), 1e-12)))[0] * 360


def hue_error(a: float, b: float) -> float:
    return abs((a - b + 180) % 360 - 180)


def test_fig5_bright_flashes_start_green_weak_ones_magenta(figs: tuple[Path, dict]) -> None:
    fig = figs[1]["5"]
    share = fig["green_share_at_start"]
    assert share["7"] > share["3"] + 0.3 and share["5"] > share["4"] + 0.3
    for e in ("3", "4", "5", "6", "7"):
        late = np.array(fig["rgb_linear"][e][int(np.searchsorted(fig["times_s"], 4.0))])
        assert late[0] > late[1] and late[2] > late[1], f"10^{e} should fade to magenta"


def test_fig5_hues_on_the_page_start_toward_cyan_and_end_at_the_l_cones_colour(
    figs: tuple[Path, dict],
) -> None:
    """The page lists the hues it measured. As the caption says, the brighter flashes start
    increasingly toward cyan (10^7 within 30 degrees of it on the display). Every row ends at
    the hue of H's first column (in light): the L cones' bleaching lasts longest (smallest b2),
    so the last bleaching term is H (B_L, 0, 0)."""
    out, data = figs
    fig = data["5"]
    display, light = fig["hue_deg"]["display"], fig["hue_deg"]["linear"]
    assert len(fig["hue_times_s"]) == len(display["7"]) and fig["hue_times_s"][-1] >= 7.9
    starts = [display[e][0] for e in ("5", "6", "7")]
    assert starts == sorted(starts) and hue_error(starts[-1], 180) <= 30, starts
    assert np.argmin(Params().b2) == 0
    l_column = hue(np.array(Params().H)[:, 0])
    for e in ("3", "4", "5", "6", "7"):
        assert hue_error(light[e][-1], l_column) <= 30, (e, light[e][-1], l_column)
    section = _section(out, "5")
    for e in ("3", "4", "5", "6", "7"):
        assert f"({display[e][0]:.0f}° on the display, {light[e][0]:.0f}° in light)" in section


def test_fig6_7_ritschel_stays_neutral_ours_and_mikamo_are_coloured(figs: tuple[Path, dict]):
    fig = figs[1]["6-7"]
    sat = fig["spot_saturation"]
    assert sat["ritschel"][0] < 0.05 and sat["jacobs"][0] > 0.3 and max(sat["mikamo"]) > 0.3
    ours = np.array(fig["spot_rgb_linear"]["jacobs"])
    assert ours[0, 1] > ours[0, 0]  # green first (10^7 cd/m^2 flash)
    assert ours[-1].sum() < 0.1 * ours[0].sum()  # faded by 8 s


def test_fig7_photographs_peak_at_the_papers_maximum_radiances(figs: tuple[Path, dict]) -> None:
    """Fig. 7's photographs are shown at 10^3.5 and 10^4.5 cd/m^2 peak, the factor applied
    being the one recorded. Guards: `photos.radiance` scaling by the file's own maximum (before
    it is fitted to the frame, which lowers the peak by 5 % here), or not at all."""
    shown = figs[1]["6-7"]["photos"]
    assert [p.key for p in photos.PHOTOS] == list(shown) == ["courtyard", "studio"]
    for photo, peak_log in zip(photos.PHOTOS, (3.5, 4.5), strict=True):
        fig = shown[photo.key]
        assert fig["peak_cd_m2"] == pytest.approx(10**peak_log, rel=1e-4), photo.key
        fitted = photos.radiance(photo, 128, 72)[0] / fig["scale_factor"]
        assert (fitted @ np.array(Params().w_P)).max() * fig["scale_factor"] == pytest.approx(
            10**peak_log, rel=1e-4
        )
        assert 100 < fig["scale_factor"] < 1000 and fig["bright_pixels"] > 10


def test_fig7_photographs_ours_coloured_by_peak_ritschels_lamp_neutral(figs: tuple[Path, dict]):
    """At 10^4.5 our lamp's afterimage starts with green (Fig. 5: "the first hint of green
    around 10^4.5"), at 10^3.5 the courtyard's is red; Ritschel's afterimage of the white lamp
    is grey. Guards: both photographs shown at one peak (PHOTOS' peak_log swapped or equal),
    and the rows run with one model for both (PHOTO_MODELS = ("jacobs", "jacobs"))."""
    shown = figs[1]["6-7"]["photos"]

    def green_share(photo: str) -> float:
        rgb = np.array(shown[photo]["peak_rgb_linear"]["jacobs"][0])  # 0.5 s after closing
        return float(rgb[1] / rgb.sum())

    assert green_share("studio") > green_share("courtyard") + 0.15
    assert green_share("courtyard") < 0.25
    lamp = shown["studio"]["bright_saturation"]
    assert max(lamp["ritschel"]) < 0.1 and min(lamp["jacobs"]) > 0.3
    assert set(figs[1]["6-7"]["images"]) >= {
        "fig07_photo_afterimages.png",
        "fig07_photo_afterimages_x4.png",
    }


def test_fig7_without_its_photographs_is_not_made(tmp_path: Path, monkeypatch, capsys) -> None:
    """No photograph (an installation without the package data): Fig. 6-7 is "Not made", the
    page and stderr name the missing file and how to get it, the command exits 1, no PNG.
    Guards: `photos.load` quietly leaving the rows out or drawing a black photograph."""
    monkeypatch.setattr(photos, "data_dir", lambda: tmp_path / "no-data")
    out = tmp_path / "out"
    assert main(["figures", "--out", str(out), "--only", "7", *SMALL]) == 1
    err = capsys.readouterr().err
    assert "Fig. 6-7 not made" in err and "courtyard.exr" in err and "reinstall gazehdr" in err
    assert "apt-get install blender-data" in err
    page = _section(out, "6-7")
    assert "Not made" in page and "courtyard.exr" in page and "reinstall gazehdr" in page
    assert not list(out.glob("*.png"))


def test_the_shipped_photographs_are_small_licensed_and_packaged() -> None:
    """Each photograph is a 256×144 EXR under 1 MB, named in data/README.md with its source
    and CC0 licence, shipped by package-data and not ignored by git. Guards: a file left out
    of the wheel (package-data) or of the repository (.gitignore's `*.exr`), or undocumented."""
    from gazehdr.scenes.exr import read_exr
    from tests.test_packaging import SETUPTOOLS

    root = Path(__file__).resolve().parent.parent
    readme = (photos.data_dir() / "README.md").read_text()
    assert "CC0" in readme and str(photos.BLENDER_WORLDS) in readme and "blender-data" in readme
    assert "*.exr" in SETUPTOOLS["package-data"]["gazehdr.figures.data"]
    assert "gazehdr.figures.data" in SETUPTOOLS["packages"]
    for photo in photos.PHOTOS:
        path = photos.path(photo)
        assert path.stat().st_size < 1 << 20
        assert read_exr(path).rgb.shape == (144, 256, 3)
        assert f"`{path.name}`" in readme and f"`{photo.source}`" in readme
        if (root / ".git").exists():
            rel = path.relative_to(root)
            ignored = subprocess.run(["git", "check-ignore", "-q", str(rel)], cwd=root)
            assert ignored.returncode == 1, f"git ignores {rel}"


@pytest.mark.skipif(
    not photos.BLENDER_WORLDS.is_dir(), reason="Debian's blender-data is not installed"
)
def test_the_shipped_photographs_are_made_again_from_blender_data(tmp_path: Path) -> None:
    """`python -m gazehdr.figures.photos` makes the shipped files again, pixel for pixel, from
    the installed blender-data (as data/README.md says). Guards: a view's parameters in PHOTOS
    (yaw, pitch, field of view) or `make_views` changed without the files made again."""
    from gazehdr.scenes.exr import read_exr

    assert photos.main([str(photos.BLENDER_WORLDS), str(tmp_path)]) == 0
    for photo in photos.PHOTOS:
        made, shipped = (
            read_exr(d / f"{photo.key}.exr").rgb for d in (tmp_path, photos.data_dir())
        )
        np.testing.assert_array_equal(made, shipped, err_msg=photo.key)


def test_fig8_calcium_weakens_the_bleaching_afterimage(figs: tuple[Path, dict]) -> None:
    fig = figs[1]["8"]
    luma = np.array(Params().w_P)
    eq7, eq12 = (np.array(fig["spot_rgb_added"][k]) @ luma for k in ("eq7", "eq12"))
    assert eq7 > 0 and eq12 < eq7
    assert fig["reference_vs_simulator_max_abs"] < 2e-3


def test_fig9_ours_is_a_dark_spot_ritschels_a_bright_one(figs: tuple[Path, dict]) -> None:
    ratio = figs[1]["9"]["spot_luminance_ratio"]
    assert ratio["jacobs"] < 0.95 and ratio["ritschel"] > 1.5


def _section(out: Path, key: str) -> str:
    """The part of index.html that shows figure `key`, as text (entities decoded)."""
    index = (out / "index.html").read_text()
    start = index.index(f"<section id='fig{key}'>")
    return html.unescape(index[start : index.index("</section>", start)])


def test_fig9_ours_is_the_complement_of_the_blue_and_of_every_hue(figs: tuple[Path, dict]):
    """Fig. 9's bottom row and the hue circle: where squares of a saturated colour were, our
    afterimage's hue is within 30 degrees of the complement of the squares' hue (for the blue,
    yellow), and the page says so. The blue squares show strongly coloured."""
    out, data = figs
    fig = data["9"]
    ours = {k: np.array(v) for k, v in fig["squares"]["jacobs"].items()}
    shown = ours["fixating_rgb"]
    assert (shown.max() - shown.min()) / shown.max() > 0.8, f"pale squares: {shown}"
    measured = hue(ours["afterimage_rgb"] / ours["surround_rgb"])
    assert hue_error(measured, 60) <= 30, f"the blue's afterimage has hue {measured:.0f}"
    assert f"hue of the change {measured:.0f}°" in _section(out, "9")
    circle = fig["hue_circle"]
    assert len(circle["inducer_hue_deg"]) == 12
    for inducer, after in zip(circle["inducer_hue_deg"], circle["afterimage_hue_deg"], strict=True):
        assert hue_error(after, inducer + 180) <= 30, (inducer, after)
    assert "fig09_hue_circle.png" in fig["images"]
    assert f"{circle['inducer_hue_deg'][8]:.0f}° → {circle['afterimage_hue_deg'][8]:.0f}°" in (
        _section(out, "9")
    )


def test_fig9_blue_squares_leave_opponent_afterimages(figs: tuple[Path, dict]) -> None:
    """Bottom row: both afterimages of the blue squares lean to yellow on the yellow-blue axis
    (R + G > 2B in linear light, against a neutral grey); Ritschel's adds to the grey in every
    channel, ours modulates it (darker in blue)."""
    squares = figs[1]["9"]["squares"]
    for model in ("jacobs", "ritschel"):
        m = {k: np.array(v) for k, v in squares[model].items()}
        blue = m["fixating_rgb"]
        assert blue[2] > 1.5 * blue[:2].max(), f"{model}: the stimulus shown is not blue"
        for grey in (m["surround_rgb"], m["without_afterimage_rgb"]):
            assert np.ptp(grey) < 1e-3 * grey.mean(), f"{model}: the field is not neutral"
        r, g, b = m["afterimage_rgb"]
        assert r + g > 1.03 * 2 * b, f"{model}: afterimage not yellowish: {m['afterimage_rgb']}"
    ours, theirs = ({k: np.array(v) for k, v in squares[m].items()} for m in ("jacobs", "ritschel"))
    # Ritschel: strictly added on top (1e-6: figures.json rounds to 6 decimals) and visible.
    assert (theirs["afterimage_rgb"] >= theirs["surround_rgb"] - 1e-6).all()
    assert theirs["afterimage_rgb"].sum() > 1.05 * theirs["surround_rgb"].sum()
    # Ours: the grey is modulated, the blue channel darker than around it.
    assert ours["afterimage_rgb"][2] < 0.97 * ours["surround_rgb"][2]


def test_fig10_purkinje_brightens_blue_against_red_as_light_falls(figs: tuple[Path, dict]):
    ratio = figs[1]["10"]["blue_over_red_luminance"]
    assert np.ptp(ratio["photopic"]) < 0.02 * ratio["photopic"][0]
    assert (np.diff(ratio["purkinje"]) >= -1e-3).all()
    assert ratio["purkinje"][-1] > 2 * ratio["photopic"][-1]


def test_fig11_colour_fades_to_purple_and_acuity_falls(figs: tuple[Path, dict]) -> None:
    fig = figs[1]["11"]
    sat = fig["mean_saturation_chromatic_patches"]
    assert (np.diff(sat) <= 1e-3).all() and sat[-1] < 0.5 * sat[0]
    r, g, b = fig["neutral_patch_rgb_relative"][-1]
    assert b > g and r > g  # neutral greys turn purple
    assert fig["inset_sharpness_relative"][-1] < 0.7


def test_fig12_only_the_stochastic_model_varies_in_patches(figs: tuple[Path, dict]) -> None:
    fig = figs[1]["12"]
    change, kept = fig["frame_to_frame_change"], fig["contrast_kept"]
    assert change["stochastic"] > 5 * change["gaussian"]
    # Thompson's temporal noise changes the frames; the Gaussian blur hardly does.
    assert change["thompson"] > 3 * change["gaussian"]
    # The bilateral filter keeps the bars' edges: far more contrast than the Gaussian blur.
    for period in ("2", "3", "4"):
        assert min(kept["bilateral"][period]) > max(kept["gaussian"][period]) + 0.3, period
    # Ours keeps a different amount of fine detail in each frame; a Gaussian blur the same.
    varies = {m: max(np.ptp(c) for c in kept[m].values()) for m in ("stochastic", "gaussian")}
    assert varies["gaussian"] < 0.005 and varies["stochastic"] > 0.02
    assert min(kept["none"]["3"]) > max(kept["gaussian"]["3"]) + 0.3


def test_only_selects_and_bad_options_exit_2(tmp_path: Path, capsys) -> None:
    out = tmp_path / "only"
    assert main(["figures", "--out", str(out), "--only", "4", *SMALL]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "fig04_bleaching.png",
        "figures.json",
        "index.html",
    ]
    assert re.search(r"wrote 3 files to .* in [\d.]+ s", capsys.readouterr().out)
    for bad in (["--only", "3"], ["--only", "x"], ["--size", "8x8"], ["--seed", "-1"]):
        assert main(["figures", "--out", str(tmp_path / "bad"), *bad]) == 2
        assert "error" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["figures", "--out", str(tmp_path / "file"), "--only", "4"]) == 2


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """`gazehdr ARGS` in a child process: the real entry point with real stdout and stderr."""
    entry = "import sys; from gazehdr.cli import main; sys.exit(main())"
    return subprocess.run(
        [sys.executable, "-c", entry, *args],
        capture_output=True, text=True, timeout=300, cwd=Path(__file__).resolve().parent.parent,
    )  # fmt: skip


def test_progress_bar_on_stderr_unless_quiet(tmp_path: Path) -> None:
    small = ["--only", "4", "--size", "128x72"]
    loud = _cli("figures", "--out", str(tmp_path / "loud"), *small)
    quiet = _cli("figures", "--out", str(tmp_path / "quiet"), *small, "--quiet")
    for run in (loud, quiet):
        assert run.returncode == 0, run.stderr
        assert re.search(r"wrote 3 files to .* in [\d.]+ s", run.stdout), run.stdout
        assert "%|" not in run.stdout  # the bar never mixes into the summary
    assert re.search(r"Fig\. 4: 100%\|.*\| 1/1 ", loud.stderr), loud.stderr
    assert "Fig. 4" not in quiet.stderr and "%|" not in quiet.stderr, quiet.stderr


def test_missing_matplotlib_names_the_extra(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if not installed
    assert main(["figures", "--out", str(tmp_path), "--only", "4"]) == 2
    assert "pip install 'gazehdr[figures]'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_a_model_that_does_not_import_fails_loudly(tmp_path: Path, monkeypatch, capsys) -> None:
    from gazehdr.sim import models

    missing = "gazehdr.sim.baselines.not_there:Stage"
    monkeypatch.setitem(
        models.AFTERIMAGE_MODELS, "ritschel", dict.fromkeys(("opencl", "reference"), missing)
    )
    assert main(["figures", "--out", str(tmp_path), "--only", "9", *SMALL]) == 1
    assert "Fig. 9 not made" in capsys.readouterr().err
    assert "Not made" in (tmp_path / "index.html").read_text()
    assert not list(tmp_path.glob("*.png"))  # no figure drawn with another model
