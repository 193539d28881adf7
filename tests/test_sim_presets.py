"""The paper's numbers by default: the `paper` preset, our `visible` one, the switches of the
model that are ours, and the display model the cd/m² figures assume.

Each test names the mutation it guards; each was seen to fail on it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gazehdr.experiment.design import load_design
from gazehdr.experiment.stimulus import render_clip
from gazehdr.sim import Params, Simulator
from gazehdr.sim.display import PAPER_DISPLAY, DisplayModel
from gazehdr.sim.layout import RGB_TO_LMS
from gazehdr.sim.presets import PRESETS, describe, nearest_preset, preset

W, H = 128, 72
CENTRE = (64.0, 36.0)
BACKENDS = ["reference", "opencl"]
LUMA = np.array(Params().w_P)


def uniform(value) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, np.float32), (H, W, 3)).copy()


def test_the_defaults_are_the_paper_preset_with_eq12_as_printed() -> None:
    """`Params()` is the `paper` preset: Eq. 12's bleaching term unscaled and unmasked, the
    Purkinje shift on. Guards a default of ours creeping back (bleach_display_gain = 32 made
    Sec. 4.1's afterimages 33x too bright)."""
    p = Params()
    assert p == preset("paper") and PRESETS["paper"] == {}
    assert p.bleach_display_gain == 1.0 and p.bleach_equivalent_light is False
    assert p.purkinje is True and p.gain_along_adapting_light is True
    assert preset("visible").bleach_display_gain == 32.0


def test_a_preset_is_named_with_the_parameters_changed_over_it() -> None:
    """What the HUD and the panel say of the live parameters. Guards a description that ignores
    edits (a session with j1 changed is not "paper") or counts the tracker's figures, which the
    gaze source sets (a session following a tracker still runs the paper's model)."""
    assert nearest_preset(Params()) == ("paper", [])
    assert describe(preset("visible")) == "visible"
    assert describe(preset("visible").replace(j1=0.01)) == "visible + j1"
    assert describe(Params(tracker_accuracy_deg=0.5, tracker_rate_hz=250.0)) == "paper"
    many = Params(j1=0.01, j2=0.2, a1=1.0, a2=0.1)
    assert describe(many) == "paper + a1, a2, j1 and 1 more"
    with pytest.raises(ValueError, match="no preset 'vivid'; the presets are paper, visible"):
        preset("vivid")


def flash_on_grey(backend: str, params: Params) -> Simulator:
    """A 1e7 cd/m^2 flash for 1/8 s over the whole 100 cd/m^2 field, then the grey again."""
    sim = Simulator(W, H, params=params, backend=backend, seed=0)
    sim.start(uniform(100.0), CENTRE)
    sim.load_scene(uniform(1e7), reset=False)
    for _ in range(8):
        sim.step(1 / 64, gaze=CENTRE)
    sim.load_scene(uniform(100.0), reset=False)
    sim.step(0.05, gaze=CENTRE)
    return sim


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_bleaching_map_is_eq12s_term_through_h(backend: str) -> None:
    """Eq. 12's additive term, from the state at the gaze: H j1 (C / C_max) max(B - B_inf, 0),
    B_inf of the grey seen now (Eq. 6), typed from the paper here, not read from the model.
    Guards the display gain (32: 32x) and the equivalent-light masking (on the grey: 0.8x) in
    the paper preset, and the term's factors (C / C_max dropped: 1.3x)."""
    p = Params()
    sim = flash_on_grey(backend, p)
    lay = sim.layout
    i, j = lay.grid_h // 2, lay.grid_w // 2
    state = sim._backend.get("state")[:, i, j].astype(np.float64)
    B, c = state[:3], state[3:6]
    lms = RGB_TO_LMS @ np.full(3, 100.0)
    b1, b2 = np.array(p.b1), np.array(p.b2)
    B_inf = b1 * lms / (b1 * lms + b2)
    expected = np.array(p.H) @ (p.j1 * c * np.maximum(B - B_inf, 0.0))
    maps = sim._backend.get("maps")[3:, i, j].astype(np.float64)
    assert expected.max() > 1e-3  # a bleaching afterimage to compare
    np.testing.assert_allclose(maps, expected, rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_eq11_per_cone_when_asked(backend: str) -> None:
    """With gain_along_adapting_light off, the gain map is Eq. 11 per cone as printed,
    ((C_max - C_inf) / (C_max - C))^j2 (guarded by alpha_eps), C_inf from the light seen now
    (Eq. 10: 1 - R). Guards the switch (ignored: the gain points along the adapting light,
    which for this blue-tinted adaptation differs from the per-cone gain by up to 9 %)."""
    p = Params(gain_along_adapting_light=False)
    sim = Simulator(W, H, params=p, backend=backend, seed=0)
    sim.start(uniform((40.0, 60.0, 900.0)), CENTRE)
    sim.step(3.0, gaze=CENTRE)
    sim.load_scene(uniform(100.0), reset=False)
    sim.step(0.1, gaze=CENTRE)
    lay = sim.layout
    i, j = lay.grid_h // 2, lay.grid_w // 2
    c = sim._backend.get("state")[3:6, i, j].astype(np.float64)
    lms = RGB_TO_LMS @ np.full(3, 100.0)
    m = p.n * p.plateau_m_over_n  # Eq. 2 with our plateau: sigma^n = I_bar^(n-m) K^m
    sigma_n = 10 ** ((p.n - m) * sim.adaptation) * p.plateau_K**m
    c_inf = 1 - lms**p.n / (lms**p.n + sigma_n)
    alpha = (1 - c_inf + p.alpha_eps) / (1 - c + p.alpha_eps)
    gain = sim._backend.get("maps")[:3, i, j].astype(np.float64)
    np.testing.assert_allclose(gain, alpha**p.j2, rtol=5e-4)
    assert np.ptp(np.log(gain)) > 0.02  # the cones' gains differ: a coloured adaptation


def purkinje_run(backend: str, params: Params) -> tuple[float, float, float]:
    """A red and a blue half of equal photopic luminance at 0.01 cd/m^2 (scotopic: rho = 0),
    the adaptation floor lowered so that the scene sets the adaptation, the gaze on the blue:
    the display luminance of the blue half and of the red, and the adaptation A."""
    scene = uniform(0.0)
    scene[:, : W // 2] = np.array([1.0, 0.0, 0.0]) * 0.01 / LUMA[0]
    scene[:, W // 2 :] = np.array([0.0, 0.0, 1.0]) * 0.01 / LUMA[2]
    p = params.replace(A_min=-4.0)
    sim = Simulator(W, H, params=p, backend=backend, seed=0, acuity="none")
    gaze = (100.0, 36.0)
    sim.start(scene, gaze)
    v = sim.step(0.0, gaze=gaze)
    J = np.power(v.astype(np.float64), 1 / p.gamma) @ LUMA
    return float(J[36, 100]), float(J[36, 28]), sim.adaptation


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_purkinje_shift_switches_alone(backend: str) -> None:
    """Sec. 2.3.1: in scotopic light the blue looks brighter than a red of equal photopic
    luminance; with `purkinje` off, both show alike (as photopic luminances), while the
    adaptation target stays the mesopic one (w_S = w_P, the way the 4.2 preset used to switch
    it off, moves that too). Guards the switch ignored (the ratio stays far above 1) and a
    switch that also moves the adaptation (A changes)."""
    blue, red, A_on = purkinje_run(backend, Params())
    assert blue > 3.0 * red
    blue, red, A_off = purkinje_run(backend, Params(purkinje=False))
    assert blue == pytest.approx(red, rel=0.02)
    assert A_off == pytest.approx(A_on, abs=1e-6)
    *_, A_photopic = purkinje_run(backend, Params(w_S=Params().w_P))
    assert abs(A_photopic - A_on) > 0.1


SEC41_MEASURED = {"control": 2.2e-2, "manipulated": 6.5e-2}  # cd/m^2, Sec. 4.1.1


def afterimage_peaks(display: DisplayModel) -> dict[str, float]:
    """Sec. 4.1's stimuli as the experiment renders and shows them on `display` (the standard's
    27 cd/m^2 flash for 50 ms, then 2.5 s of black): the brightest luminance of the black phase
    in cd/m^2, for the control (j1 = 0.0003) and the manipulated test (j1 = 0.001)."""
    d = dataclasses.replace(load_design("4.1"), display=display)
    peaks = {}
    for name in SEC41_MEASURED:
        c = render_clip(d, d.conditions[name].test, (240, 135), "opencl")
        shown = c.shown(d.standard, d).astype(np.float64)
        flash = display.cd_m2(shown[0]) @ LUMA
        assert flash.max() == pytest.approx(d.standard, rel=0.01)
        after = [display.cd_m2(shown[i]) @ LUMA for i, p in enumerate(c.phases) if p == "off"]
        peaks[name] = float(np.max(after))
    return peaks


@pytest.mark.slow
def test_sec41_afterimages_have_the_luminance_the_paper_measured() -> None:
    """With the defaults, on the display model the docs state (PAPER_DISPLAY: 100 cd/m^2
    white), 4.1's control and manipulated afterimages peak within 1.5x of what the authors
    measured, 2.2e-2 and 6.5e-2 cd/m^2 (0.024 and 0.079 here). Guards the display gain of ours
    (32: 0.74 and 2.46 cd/m^2)."""
    peaks = afterimage_peaks(PAPER_DISPLAY)
    for name, measured in SEC41_MEASURED.items():
        assert measured / 1.5 <= peaks[name] <= measured * 1.5, (name, peaks[name])


@pytest.mark.slow
def test_a_lab_monitor_shows_the_papers_luminances() -> None:
    """A lab enters its monitor's measured white and gamma: the stimuli are made for it, so its
    flash peaks at the standard's 27 cd/m^2 and its afterimages have the luminances they have on
    the paper's display. Guards the gamma ignored (a 2.4 monitor shows 0.72x) and the white
    ignored in the black phase (250 cd/m^2: 2.5x)."""
    paper = afterimage_peaks(PAPER_DISPLAY)
    lab = afterimage_peaks(DisplayModel(white_cd_m2=250.0, gamma=2.4))
    for name in SEC41_MEASURED:
        assert lab[name] == pytest.approx(paper[name], rel=0.01)


def test_display_model_values_and_luminances_are_inverse() -> None:
    """cd/m² of values and values of cd/m² undo each other below the white; above it, white.
    Guards a gamma applied the wrong way round (1/gamma in cd_m2)."""
    d = DisplayModel(white_cd_m2=160.0, gamma=2.4)
    v = np.linspace(0.0, 1.0, 11)
    np.testing.assert_allclose(d.values(d.cd_m2(v)), v, atol=1e-12)
    assert d.cd_m2(0.5) == pytest.approx(160.0 * 0.5**2.4)
    assert d.values(1e6) == 1.0
    with pytest.raises(ValueError, match="display gamma must be a finite positive number"):
        DisplayModel(gamma=0.0)
