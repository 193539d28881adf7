"""Sec. 4.3's palette (Fig. 15): the colour transforms of its columns, their refusals in the
design file, the preset's columns A-H by rows 1-4, the images the server makes of them, and the
page laying them out as the paper's grid (real headless Chromium, tests/browser.py)."""

from __future__ import annotations

import colorsys
import contextlib
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from gazehdr.experiment import transforms
from gazehdr.experiment.design import DesignError, load_design, parse_design, preset_path
from gazehdr.experiment.service import ExperimentConfig
from gazehdr.experiment.stimulus import palette_images, render_clip
from tests.browser import WAIT_MS, browser  # noqa: F401 -- the browser fixture
from tests.test_experiment_design import PALETTE

GAMMA = 0.455  # the paper's display: v = J^gamma
SIZE = (96, 54)
BACKEND = "reference"
COLUMNS, ROWS, FLASHES = "ABCDEFGH", (1, 2, 3, 4), (1e7, 1e5, 1e4, 1e3)


def hues(v: np.ndarray) -> np.ndarray:
    """HSV hue in degrees of each pixel's linear light (colorsys: not the code under test)."""
    J = np.power(v.astype(np.float64), 1 / GAMMA).reshape(-1, 3)
    return np.array([colorsys.rgb_to_hsv(*p)[0] * 360 for p in J])


def hsv(v: np.ndarray) -> np.ndarray:
    J = np.power(v.astype(np.float64), 1 / GAMMA).reshape(-1, 3)
    return np.array([colorsys.rgb_to_hsv(*p) for p in J])


def turned(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Signed hue change from a to b, degrees in [-180, 180)."""
    return (b - a + 180) % 360 - 180


def colours(n: int = 400, seed: int = 1) -> np.ndarray:
    """Display values of saturated colours of every hue (saturation >= 0.3)."""
    rng = np.random.default_rng(seed)
    J = np.array(
        [colorsys.hsv_to_rgb(h, s, v) for h, s, v in rng.uniform([0, 0.3, 0.05], 1, (n, 3))]
    )
    return np.power(J, GAMMA).reshape(20, n // 20, 3).astype(np.float32)


@pytest.mark.parametrize("degrees", [120, -60, 180, 37.5])
def test_a_hue_rotation_moves_the_measured_hue_by_its_degrees(degrees: float) -> None:
    """hue+D (hue-D) turns every pixel's hue of linear light by D (-D) degrees, keeping its
    saturation and value; a grey stays grey. Guards: the sign of hue-D, and the rotation done
    on the display values instead of linear light (which misses by up to 32 degrees here)."""
    v = colours()
    name = f"hue{'+' if degrees > 0 else '-'}{abs(degrees):g}"
    out = transforms.parse(name).apply(v, GAMMA)
    assert str(transforms.parse(name)) == name
    np.testing.assert_allclose(turned(hues(v) + degrees, hues(out)), 0.0, atol=0.5)
    np.testing.assert_allclose(hsv(out)[:, 1:], hsv(v)[:, 1:], atol=2e-3)
    grey = np.full((2, 2, 3), 0.3, np.float32)
    np.testing.assert_allclose(transforms.parse(name).apply(grey, GAMMA), grey, atol=1e-6)


def test_a_tint_sets_the_hue_and_saturation_and_keeps_the_value() -> None:
    """tint=H/S gives every pixel, grey ones too, hue H and saturation S at its own value.
    Guards: the tint leaving greys grey (a rotation's behaviour) or changing the value."""
    v = np.concatenate([colours(), np.full((20, 20, 3), 0.4, np.float32)], axis=1)
    out = transforms.parse("tint=200/0.4").apply(v, GAMMA)
    np.testing.assert_allclose(hues(out), 200.0, atol=0.5)
    got, want = hsv(out), hsv(v)
    np.testing.assert_allclose(got[:, 1], 0.4, atol=2e-3)
    np.testing.assert_allclose(got[:, 2], want[:, 2], rtol=1e-3)
    np.testing.assert_array_equal(transforms.parse("none").apply(v, GAMMA), v)


@pytest.mark.parametrize(
    ("transform", "why"),
    [
        ('"hue+abc"', "not a colour transform"),
        ('"rotate120"', "not a colour transform"),
        ('"hue+360"', "more than 0, less than 360"),
        ('"hue-0"', "more than 0, less than 360"),
        ('"tint=200/1.5"', "saturation in [0, 1]"),
        ('"tint=400/0.5"', "hue is in [0, 360)"),
        ("120", "must be a string"),
    ],
)
def test_a_bad_transform_is_refused_naming_the_field(transform: str, why: str) -> None:
    """The loader refuses a transform it cannot apply, naming the choice's key, the value and
    what a transform may be. Guards: an unknown name accepted (and shown untransformed)."""
    text = PALETTE.replace(
        'model = "ritschel" }', f'model = "ritschel", transform = {transform} }}'
    )
    with pytest.raises(DesignError) as e:
        parse_design(text, "p.toml")
    said = str(e.value)
    bad = transform.strip('"') if transform.startswith('"') else int(transform)
    assert f"p.toml: palette.choices[2].transform = {bad!r}: " in said and why in said
    assert "hue+D or hue-D" in said and "tint=H/S" in said


def test_the_43_preset_palette_is_columns_a_to_h_by_rows_1_to_4() -> None:
    """Fig. 15: columns A-H, rows 1-4 after flashes of 1e7, 1e5, 1e4, 1e3 cd/m^2; H is ours and
    C Ritschel's, as rendered; every other column one transform of one model down its rows,
    and no two columns alike. Guards: a column or row dropped, a row at the wrong flash, a
    column mixing transforms, H or C transformed, a transformed column that repeats another."""
    d = load_design("4.3")
    by_label = {c.label: c for c in d.palette}
    assert sorted(by_label) == sorted(f"{c}{r}" for c in COLUMNS for r in ROWS)
    columns = {}
    for col in COLUMNS:
        cells = [by_label[f"{col}{r}"] for r in ROWS]
        assert [c.flash for c in cells] == list(FLASHES), col
        assert len({(c.look.model, c.transform) for c in cells}) == 1, col
        columns[col] = (cells[0].look.model, str(cells[0].transform))
    assert columns["H"] == ("jacobs+stochastic", "none")
    assert columns["C"] == ("ritschel+stochastic", "none")
    assert len(set(columns.values())) == 8
    for col, (model, transform) in columns.items():
        if col not in "CH":
            assert transform != "none", col
            if model.startswith("ritschel"):  # its afterimage is grey: only a tint colours it
                assert transform.startswith("tint="), col


@pytest.fixture(scope="module")
def row3() -> tuple[dict[str, np.ndarray], Any]:
    """Row 3 of the 4.3 preset's palette (the 1e4 cd/m^2 flash), rendered small."""
    d = load_design("4.3")
    d = replace(d, palette=tuple(c for c in d.palette if c.label.endswith("3")))
    images = palette_images(d, SIZE, BACKEND)
    return dict(zip((c.label for c in d.palette), images, strict=True)), d


def test_palette_images_apply_each_options_transform(row3) -> None:
    """Each option's image is its model's image so transformed: E3 (hue+120) is H3 turned by
    120 degrees (its hue as measured, +-1), D3 is Ritschel's grey C3 tinted light blue.
    Guards: `palette_images` ignoring the choice's transform."""
    images, d = row3
    by_label = {c.label: c for c in d.palette}
    for label, image in images.items():
        model = "H3" if by_label[label].look.model.startswith("jacobs") else "C3"
        want = by_label[label].transform.apply(images[model], GAMMA)
        np.testing.assert_array_equal(image, want, err_msg=label)
    J = {k: np.power(images[k].astype(np.float64), 1 / GAMMA) for k in ("H3", "E3")}
    Y = J["H3"] @ np.array([0.2126, 0.7152, 0.0722])
    bright = Y >= 0.5 * Y.max()  # the afterimage of the flash head
    ours, rotated = (colorsys.rgb_to_hsv(*J[k][bright].mean(axis=0))[0] * 360 for k in J)
    assert abs(turned(np.array(ours + 120), np.array(rotated))) < 3.0
    ritschel = hsv(images["C3"])
    assert ritschel[ritschel[:, 2] > 0.1 * ritschel[:, 2].max(), 1].max() < 0.02  # grey
    lit = hsv(images["D3"])[:, 2] > 0.01
    np.testing.assert_allclose(hues(images["D3"])[lit], 200.0, atol=1.0)


def test_a_palette_image_is_the_first_black_frame_of_the_full_clip(row3) -> None:
    """`palette_images` renders only up to the first frame of black (the one it shows): that
    frame is the full clip's. Guards: the shortened render changing what came before it (the
    flash's duration, `on`, or the seed)."""
    images, d = row3
    choice = next(c for c in d.palette if c.label == "H3")
    longer = replace(d, off=0.5)  # the preset's 2.5 s of black would take seconds to render
    full = render_clip(longer, d.flash_look(choice.look, choice.flash), SIZE, BACKEND)
    frame = full.frames[full.phases.index("off")].astype(np.float32)
    side = images["H3"].shape[0]
    Y = frame @ np.ones(3)
    found = [
        (y, x)
        for y in range(frame.shape[0] - side + 1)
        for x in range(frame.shape[1] - side + 1)
        if np.array_equal(frame[y : y + side, x : x + side], images["H3"])
    ]
    assert found and Y.max() > 0


@contextlib.contextmanager
def palette_page(chromium: Any, url: str, viewport: dict[str, int]) -> Iterator[Any]:
    """The page past consent and instructions, at `viewport`; no error on it."""
    page = chromium.new_page(viewport=viewport)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(f"{url}/experiment")
        page.wait_for_function("() => window.gazehdrExperiment.design", timeout=WAIT_MS)
        page.fill("#observer", "lay1")
        page.check("#agree")
        page.click("#begin")
        page.wait_for_function(
            "() => window.gazehdrExperiment.state === 'instructions'", timeout=WAIT_MS
        )
        page.keyboard.press("Space")
        yield page
    finally:
        page.close()
    assert not errors, errors


def _small_43() -> Any:
    """The 4.3 preset, its palette whole, with a short black, one block and a small frame."""
    text = preset_path("afterimage-palette").read_text()
    text = text.replace("off = 2.5", "off = 0.1").replace("size = [480, 270]", "size = [48, 27]")
    text = text.replace("fps = 60.0", "fps = 20.0")
    return parse_design(
        text[: text.index('[[blocks]]\nname = "nd4"')] + text[text.index("[palette]") :]
    )


@pytest.mark.parametrize(
    "viewport", [{"width": 1280, "height": 720}, {"width": 800, "height": 600}]
)
def test_the_page_lays_the_palette_out_as_fig_15(live_server, browser, tmp_path, viewport):  # noqa: F811
    """The 4.3 palette on the page: 8 columns A-H left to right by 4 rows 1-4 top to bottom,
    every option inside the window, the images square and all the same size. Guards: the
    page's old flow of 22 %-wide options (four a row: 8 rows that run off the window) and
    options placed in the design's order instead of by their label."""
    design = _small_43()
    config = ExperimentConfig(design, tmp_path / "results", (48, 27), BACKEND, 3)
    server = live_server(experiment=config)
    with palette_page(browser, server.url, viewport) as page:
        page.wait_for_function(
            "() => window.gazehdrExperiment.state === 'prompt' "
            "&& [...document.querySelectorAll('#palette img')].every((i) => i.complete "
            "&& i.naturalWidth > 0)",
            timeout=WAIT_MS,
        )
        boxes = page.evaluate(
            "() => [...document.querySelectorAll('#palette figure')].map((f) => {"
            " const r = f.getBoundingClientRect(), i = f.querySelector('img')"
            ".getBoundingClientRect();"
            " return [f.dataset.label, r.left, r.top, r.right, r.bottom, i.width, i.height]; })"
        )
    assert len(boxes) == 32
    xs = {c: {round(b[1]) for b in boxes if b[0][0] == c} for c in COLUMNS}
    ys = {r: {round(b[2]) for b in boxes if b[0][1:] == str(r)} for r in ROWS}
    assert all(len(x) == 1 for x in xs.values()) and all(len(y) == 1 for y in ys.values())
    lefts, tops = [xs[c].pop() for c in COLUMNS], [ys[r].pop() for r in ROWS]
    assert lefts == sorted(lefts) and len(set(lefts)) == 8
    assert tops == sorted(tops) and len(set(tops)) == 4
    for label, left, top, right, bottom, w, h in boxes:
        assert 0 <= left and right <= viewport["width"], label
        assert 0 <= top and bottom <= viewport["height"], label
        assert w == h == boxes[0][5] and w > 40, label
