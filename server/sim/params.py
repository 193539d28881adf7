"""Every number the model uses, in one typed place.

The defaults are the paper's Appendix A (Jacobs et al. 2015), under the paper's symbol names.
Values the paper does not give are marked *ours* in their comment, with the reason. The kernels
read theirs from `params_t`, which kernel_params.py generates from these fields.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from gazehdr.drivers.errors import InputError

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


#: The most pixels per degree a viewing geometry may give (a 4K phone at 30 cm gives ~250; tests
#: give a 64 px frame the paper's 64 px per degree by a screen of 1920 px seen from 30 m).
MAX_PPD = 4096.0
#: The kernels' room for acuity band thresholds (kernel_params: the parameter block).
MAX_BANDS = 8
#: The largest gamma and n: the kernels' polynomials for x^gamma and I^n are fitted up to there
#: (kernel_params.power_poly).
POWER_MAX = 4.0


@dataclass(frozen=True)
class Geometry:
    """Viewing geometry: pixel sizes in the paper refer to this screen (about 64 px per degree)."""

    screen_diagonal_m: float = 0.6
    screen_width_px: int = 1920
    screen_height_px: int = 1080
    viewing_distance_m: float = 1.0

    def __post_init__(self) -> None:
        for name in ("screen_width_px", "screen_height_px"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not 16 <= value <= 16384:
                raise InputError(
                    f"geometry {name} must be an integer in [16, 16384], got {value!r}"
                )
        for name, high in (("screen_diagonal_m", 20.0), ("viewing_distance_m", 100.0)):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0 < value <= high):
                raise InputError(f"geometry {name} must be in (0, {high:g}] m, got {value!r}")
        ppd = self.pixels_per_degree()
        if not 1.0 <= ppd <= MAX_PPD:
            raise InputError(
                f"geometry gives {ppd:.3g} px per degree, outside [1, {MAX_PPD:g}]: sizes in "
                "degrees become blurs and grids in pixels, so this bounds their work"
            )

    def pixels_per_degree(self, width_px: int | None = None) -> float:
        """Pixels per degree for a frame of `width_px` showing the whole screen."""
        pitch = self.screen_diagonal_m / math.hypot(self.screen_width_px, self.screen_height_px)
        ppd = 2.0 * self.viewing_distance_m * math.tan(math.radians(0.5)) / pitch
        return ppd * (width_px or self.screen_width_px) / self.screen_width_px


@dataclass(frozen=True)
class Params:
    """Model parameters. Paper symbols first (Appendix A), then ours."""

    # --- Appendix A -------------------------------------------------------------------------
    gamma: float = 0.455  # display gamma compensation, v = J^gamma
    n: float = 0.7  # Naka-Rushton exponent (Eq. 1)
    a1: float = 0.75  # adaptation rate to brighter stimuli, log10 units / s (Eq. 3)
    a2: float = 0.2  # adaptation rate to darker stimuli, log10 units / s (Eq. 3)
    b1: Vec3 = (1.2e-3, 1.4e-4, 5.5e-7)  # L, M, S photopigment bleaching rate (Eq. 4-6)
    b2: Vec3 = (6.9e-1, 1.4e0, 5.5e0)  # L, M, S photopigment regeneration rate, 1/s
    c1: float = 1.0  # calcium influx rate (Eq. 8-10); cancels in C / C_max, kept by name
    c2: float = 1.0  # calcium efflux rate, 1/s
    j1: float = 0.03  # bleaching afterimage strength (Eq. 7, 12)
    j2: float = 0.15  # adaptation afterimage strength (Eq. 12)
    m1: float = 0.0  # maximum mesopic log10 luminance (Eq. 13)
    m2: float = -2.0  # minimum mesopic log10 luminance
    w_P: Vec3 = (0.2126, 0.7152, 0.0722)  # RGB photopic luminance weights
    w_S: Vec3 = (0.0, 0.8451, 0.1459)  # RGB scotopic luminance weights
    sigma_0: float = 0.75  # sigma_i = sigma_0 * 2^(i/4) px at the reference geometry, i = 0..7
    rho_step: float = 0.286  # acuity thresholds rho_i = rho_step * i in log10 luminance
    g: float = 0.25  # stochastic acuity variance (Eq. 15)
    H: Mat3 = (  # LMS bleaching levels -> RGB afterimage colour matrix
        (1.14, -1.18, 0.36),
        (0.08, 1.02, 0.18),
        (0.30, -0.11, 1.25),
    )
    A_min: float = 2.0  # adaptation floor, log10(100 cd/m^2) (Sec. 2.4)

    # --- ours ---------------------------------------------------------------------------------
    # Plateau M(I) = I^m / (I^m + K^m) of Eq. 2, not given in the paper. m = n/2 gives
    # sigma = sqrt(I*K): partial adaptation, so bright scenes still look brighter than dim ones.
    plateau_m_over_n: float = 0.5
    plateau_K: float = 300.0  # cd/m^2; a comfortable office white
    bands: int = 8  # i = 0..7 in Appendix A
    adaptation_sigma_deg: float = 1.0  # the "small patch" of Sec. 2.1: about the fovea
    rho_sigma_deg: float = 0.5  # local average for L in Eq. 13: smooth over a few acuity cells
    # Scotopic colour of a neutral grey (Sec. 2.3.2), a dull purple after Shin et al. 2004,
    # normalised so that w_P . k_s = 1 (it keeps the luminance the tone curve gives).
    k_s: Vec3 = (1.10, 0.94, 1.30)
    noise_cell_deg: float = 0.5  # spacing of the coarse acuity noise grid (Sec. 2.3.3)
    noise_rate_hz: float = 4.0  # key frames of the acuity noise per second: "a few Hz"
    map_blur_deg: float = 0.1  # sigma of the B, C map blur after 1 s; scales with sqrt(dt)
    fovea_sigma_deg: float = 10.0  # afterimage visibility fall-off (Sec. 2.4): fades by 20 deg
    retina_cell_deg: float = 0.1  # retinal state cell: afterimages are blurry, 6 arcmin is ample
    # Eq. 12 on the display. The paper's defaults (the `paper` preset) add the bleaching term
    # as printed: display gain 1, no masking; they give Sec. 4.1's measured afterimages
    # (2.2e-2 and 6.5e-2 cd/m^2 at j1 = 0.0003, 0.001 on a 100 cd/m^2 white). Ours, for a plain
    # monitor (the `visible` preset): a gain of 32 puts the afterimage of Fig. 4's flash
    # (1e7 cd/m^2, 1/8 s) in the dark at display white in its brightest channel, G, when the
    # flash ends: 1 / (j1 e^(-c2/8) (H (1, 1, 0.37))_G) = 32.4; shown as the cone's response to
    # its equivalent light (reference.bleach_response), a background as bright as that light
    # masks it, as Sec. 2.2.2 says, and the lamp of Fig. 9 keeps its dark spot.
    bleach_display_gain: float = 1.0
    bleach_equivalent_light: bool = False
    # Eq. 11's gains per cone, as one vector pointed along the cone contrast of the light the eye
    # adapted to (reference.opponent_gain): ours, on in the `paper` preset because it gives what
    # the paper reports (Fig. 9: blue squares leave yellow; per cone, Eq. 11 gives orange, 17
    # deg) and equals Eq. 11 exactly for every neutral light (docs/model.md, "Adaptation
    # colour"). False: Eq. 11 per cone, as printed.
    gain_along_adapting_light: bool = True
    # Eq. 13's Purkinje shift of the luminance fed to Eq. 1 (Sec. 2.3.1). False: the photopic
    # luminance, while the hue shift, the acuity loss and the adaptation target stay mesopic
    # (Sec. 4.2 leaves the Purkinje shift out of its stimuli).
    purkinje: bool = True
    alpha_eps: float = 1e-3  # Eq. 11 guard: alpha = (1 - c_inf + eps) / (1 - c + eps)
    Y_min: float = 1e-6  # cd/m^2 floor inside log10; far below the scotopic range
    radiance_max: float = 1e10  # cd/m^2 cap on input; the sun's disc is about 1.6e9
    geometry: Geometry = field(default_factory=Geometry)
    # What the retina sees off the screen (Sec. 2.2 locks the retina to the gaze, so part of it
    # always lies beyond the frame): at the nearest screen point, `surround` times the average
    # of the frame's edge along it (a Gaussian of surround_sigma_deg; layout.surround_map). The
    # eye is adapted to the scene (Sec. 2.1) and the frame is a window on it: the least we can
    # assume of the scene past its edge is that it goes on as it is there (1), without detail
    # finer than a few degrees, which would be invented, and without light from inside the
    # frame. A dark room (0) leaves that retina dark-adapted, and every gaze shift then brings
    # bright bands onto the frame's edges (up to 13 % in v).
    surround: float = 1.0
    surround_sigma_deg: float = 2.0
    # The paper's tracker (Sec. 3: a Tobii REX, about 1 deg, 30 Hz). A caller sets its own: the
    # foveal blind spot below needs a good one.
    tracker_accuracy_deg: float = 1.0
    tracker_rate_hz: float = 30.0

    # --- Sec. 5 observations, ours, off by default ------------------------------------------------
    # After a blink or a saccade the afterimage looks stronger for a moment: its visibility is
    # multiplied by 1 + afterimage_boost exp(-t / afterimage_boost_s) (t since the eyes opened,
    # or since a step whose gaze moved faster than saccade_deg_s: Tobii's I-VT threshold, as
    # drivers/fixations). 0 = off; the paper gives no size or time course.
    afterimage_boost: float = 0.0
    afterimage_boost_s: float = 0.5
    saccade_deg_s: float = 30.0
    # Scotopic foveal blind spot: the fovea has no rods (a rod-free zone 1.25 deg across,
    # Curcio et al. 1990), so in scotopic light a fixated object vanishes into its surround.
    # Where rho < 1 the scene is filled in with its local mean (sigma: the zone's diameter) by
    # foveal_blind_spot (1 - rho_c) exp(-r^2 / 2 s^2), s such that it halves at the zone's edge,
    # times what the tracker lets us show (layout.blind_spot_strength): the zone must land on
    # the fovea (accuracy against rod_free_radius_deg) and follow it after each saccade
    # (one sample late within a fixation of fixation_s, Rayner 1998). 0 = off.
    foveal_blind_spot: float = 0.0
    rod_free_radius_deg: float = 0.625
    fixation_s: float = 0.25

    # --- baseline afterimage models (docs/baselines/) -------------------------------------------
    # Ritschel & Eisemann 2012: Eq. 3 and Listing 1.
    c_a: float = 0.3  # opsin activation constant (Sec. 3.1), per second per unit of L
    c_d: float = 0.3  # deactivation constant, c_d = 1.0 c_a (Sec. 3.1)
    ritschel_steps: int = 1  # explicit steps per frame, clamped to [0, 1] (Listing 1: n = 1)
    # Ours: the paper's L is in trolands with an unstated scale. L = I / ritschel_L_ref with
    # c_a = c_d half-bleaches at I = L_ref: the measured half-bleach of cone pigment, 10^4.3 td
    # (Rushton & Henry 1968), through a ~2.1 mm pupil (Moon & Spencer at that luminance) is
    # ~6000 cd/m^2. (100 cd/m^2 would saturate all three cones for any light above a few 1000
    # cd/m^2: every bright afterimage alike, whatever the light's colour.)
    ritschel_L_ref: float = 6000.0
    # Micro-saccade blur of the input: "about 10 px at 1280x1024, 1 m"; read as a 10 px
    # kernel width on a 19" screen, sigma = 5 px = 0.08 deg (ours).
    ritschel_saccade_sigma_deg: float = 0.08
    # Diffusion N_sigma: blur after one second, sigma = N_sigma / sqrt(f) per frame. The paper
    # fits Brindley's curve, which the text does not give; ours, as map_blur_deg.
    ritschel_N_sigma_deg: float = 0.1
    ritschel_strength: float = 1.0  # ours: scale of the composited afterimage (display units)
    ritschel_flight_rate: float = 0.0  # flight of colours: oRGB hue rotation, rad/s (0 = off)
    # Mikamo et al. 2012.
    mikamo_top_fraction: float = 0.05  # mask: the top 5 % of luminance of I_on (Sec. 4)
    mikamo_gamma: float = 0.7  # Z = (L_on / L_on_max)^gamma (Sec. 4)
    mikamo_reference_xy: tuple[float, float] = (0.43, 0.40)  # Padgham's light, Yxy chromaticity
    mikamo_drop_log10: float = 1.0  # ours: "drops sharply" = falls a log unit within one step
    mikamo_lowpass_deg: float = 0.25  # ours: the fixed Gaussian low-pass of the afterimage
    # Ours: Eq. 1 divides by delta E, which amplifies rounding noise near the reference colour
    # and jumps there; below this many Delta E units (1: about a just-noticeable difference) it
    # divides by this instead, so (Delta a, Delta b) shrinks continuously to 0 there.
    mikamo_delta_e_floor: float = 1.0
    mikamo_strength: float = 1.0  # ours: scale of the added afterimage (display units)
    mikamo_sequence: str = ""  # a CSV of Padgham's sequence; "" = the shipped data file

    # --- acuity baselines (docs/baselines/acuity.md) --------------------------------------------
    # Ours: a Gaussian passes half its contrast at the acuity limit R(L) of Ferwerda et al.
    acuity_cutoff_response: float = 0.5
    # Ours: cap on the baselines' blur sigma. Ferwerda's fit R(L) falls to 0 near 1e-9.25
    # cd/m^2; 0.25 deg is its sigma at about Y_min (1e-6), so the cap only guards the limit
    # and bounds the kernels' radius (3 sigma).
    acuity_sigma_max_deg: float = 0.25
    bilateral_sigma_r: float = 0.4  # ours: range sigma of Jensen et al.'s filter, log10 units
    # Ours: Thompson et al.'s edge band is the difference of the log luminance blurred at sigma
    # and at thompson_dog_ratio * sigma (Marr & Hildreth's 1.6), added back with this gain.
    thompson_dog_ratio: float = 1.6
    thompson_dog_gain: float = 1.0
    thompson_noise: float = 0.05  # ours: temporal noise sigma at full scotopic vision
    thompson_noise_hz: float = 30.0  # ours: new noise this often (a display frame rate)

    def __post_init__(self) -> None:
        positive = ("n", "a1", "a2", "c1", "c2", "gamma", "plateau_K", "Y_min", "alpha_eps",
                    "fovea_sigma_deg")  # fmt: skip
        sec5 = ("tracker_rate_hz", "afterimage_boost_s", "saccade_deg_s", "rod_free_radius_deg",
                "fixation_s")  # fmt: skip
        acuity = ("acuity_sigma_max_deg", "bilateral_sigma_r", "thompson_noise_hz")
        baselines = ("ritschel_L_ref", "mikamo_gamma", "mikamo_drop_log10", "mikamo_delta_e_floor")
        for name in positive + acuity + baselines + sec5:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"parameter {name} must be a finite positive number, got {value}")
        for name in ("gamma", "n"):
            if getattr(self, name) > POWER_MAX:
                raise InputError(
                    f"parameter {name} = {getattr(self, name):g} is above {POWER_MAX:g} (the "
                    "kernels' powers are fitted up to there)"
                )
        for name in ("b1", "b2"):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(v) and v > 0 for v in value):
                raise InputError(f"parameter {name} must be three finite positive numbers")
        if not self.m1 > self.m2:
            raise InputError(f"m1 ({self.m1}) must be greater than m2 ({self.m2})")
        if not self.alpha_eps < 1:  # Eq. 11's guard; contrast_floor takes log(1 - alpha_eps)
            raise InputError(f"alpha_eps must be below 1, got {self.alpha_eps}")
        if not 0 < self.plateau_m_over_n < 1:
            raise InputError("plateau_m_over_n must lie in (0, 1); 1 would cancel adaptation")
        if not 0 < self.acuity_cutoff_response < 1:
            raise InputError("acuity_cutoff_response must lie in (0, 1)")
        if not (isinstance(self.ritschel_steps, int) and 1 <= self.ritschel_steps <= 64):
            raise InputError("ritschel_steps must be an integer in [1, 64]")
        if not isinstance(self.bands, int) or isinstance(self.bands, bool):
            raise InputError(f"bands must be an integer, got {self.bands!r}")
        for name, (low, high, what) in WORK_BOUNDS.items():
            value = getattr(self, name)
            if not low <= value <= high:
                raise InputError(
                    f"parameter {name} = {value:g} is outside [{low:g}, {high:g}] ({what}; the "
                    "bounds keep the work of a step bounded)"
                )
        if not 0 < self.mikamo_top_fraction <= 1:
            raise InputError("mikamo_top_fraction must lie in (0, 1]")
        non_negative = (
            "bleach_display_gain", "c_a", "c_d", "ritschel_saccade_sigma_deg",
            "ritschel_N_sigma_deg", "ritschel_strength", "mikamo_lowpass_deg", "mikamo_strength",
        )  # fmt: skip
        ours = ("surround", "surround_sigma_deg", "tracker_accuracy_deg", "afterimage_boost")
        for name in ("thompson_dog_gain", "thompson_noise", *non_negative, *ours):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"parameter {name} must be a finite number >= 0, got {value}")
        if not (math.isfinite(self.thompson_dog_ratio) and self.thompson_dog_ratio >= 1):
            raise InputError("thompson_dog_ratio must be a finite number >= 1")
        if not 0 <= self.foveal_blind_spot <= 1:
            raise InputError("foveal_blind_spot must lie in [0, 1]")
        for name in SWITCHES:
            if not isinstance(getattr(self, name), bool):
                raise InputError(
                    f"parameter {name} must be true or false, got {getattr(self, name)!r}"
                )
        if not math.isfinite(self.ritschel_flight_rate):
            raise InputError("ritschel_flight_rate must be a finite number (rad/s)")

    def tone_scotopic_weights(self) -> Vec3:
        """The scotopic weights of the luminance fed to Eq. 1: w_S with the Purkinje shift
        (Eq. 13), w_P without it (the blend is then the photopic luminance)."""
        return self.w_S if self.purkinje else self.w_P

    def sigma_i(self, ppd: float) -> list[float]:
        """Acuity Gaussian bank in pixels of a frame with `ppd` pixels per degree."""
        scale = ppd / self.geometry.pixels_per_degree()
        return [self.sigma_0 * 2 ** (i / 4) * scale for i in range(self.bands)]

    def rho_i(self) -> list[float]:
        """Band thresholds in normalised units, finest band first (highest threshold)."""
        per = self.rho_step / (self.m1 - self.m2)
        return [per * (self.bands - 1 - i) for i in range(self.bands)]

    def replace(self, **changes: Any) -> Params:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Params:
        """Build from a (partial) dict, e.g. a JSON preset; unknown names are an error."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise InputError(f"unknown parameter(s): {', '.join(unknown)}")
        values = dict(data)
        if "geometry" in values and isinstance(values["geometry"], dict):
            values["geometry"] = Geometry(**values["geometry"])
        for name in ("b1", "b2", "w_P", "w_S", "k_s", "mikamo_reference_xy"):
            if name in values:
                values[name] = tuple(float(v) for v in values[name])
        if "H" in values:
            values["H"] = tuple(tuple(float(v) for v in row) for row in values["H"])
        return cls(**values)

    @classmethod
    def load(cls, path: str | Path) -> Params:
        return cls.from_dict(json.loads(Path(path).read_text()))


#: Parameters grouped by the paper's sections, for the viewer's panel and the docs.
SECTIONS: dict[str, list[str]] = {
    "2.1 Global adaptation": [
        "n", "a1", "a2", "A_min", "gamma", "plateau_m_over_n", "plateau_K",
        "adaptation_sigma_deg",
    ],
    "2.2 Afterimages": [
        "b1", "b2", "c1", "c2", "j1", "j2", "H", "bleach_display_gain", "bleach_equivalent_light",
        "gain_along_adapting_light", "alpha_eps", "map_blur_deg", "fovea_sigma_deg",
        "retina_cell_deg", "surround", "surround_sigma_deg",
    ],
    "2.3 Mesopic vision": [
        "m1", "m2", "w_P", "w_S", "purkinje", "k_s", "rho_sigma_deg", "sigma_0", "rho_step",
        "g", "bands", "noise_cell_deg", "noise_rate_hz",
    ],
    "5 Discussion (off by default)": [
        "afterimage_boost", "afterimage_boost_s", "saccade_deg_s", "foveal_blind_spot",
        "rod_free_radius_deg", "fixation_s",
    ],
    "Ritschel & Eisemann 2012": [
        "c_a", "c_d", "ritschel_steps", "ritschel_L_ref", "ritschel_saccade_sigma_deg",
        "ritschel_N_sigma_deg", "ritschel_strength", "ritschel_flight_rate",
    ],
    "Mikamo et al. 2012": [
        "mikamo_top_fraction", "mikamo_gamma", "mikamo_reference_xy", "mikamo_drop_log10",
        "mikamo_lowpass_deg", "mikamo_delta_e_floor", "mikamo_strength", "mikamo_sequence",
    ],
    "Acuity baselines": [
        "acuity_cutoff_response", "acuity_sigma_max_deg", "bilateral_sigma_r",
        "thompson_dog_ratio", "thompson_dog_gain", "thompson_noise", "thompson_noise_hz",
    ],
    "Input and viewing": [
        "Y_min", "radiance_max", "geometry", "tracker_accuracy_deg", "tracker_rate_hz",
    ],
}  # fmt: skip
#: The values the paper does not give (see their comments in `Params`).
OURS = frozenset(
    {
        "plateau_m_over_n", "plateau_K", "adaptation_sigma_deg", "rho_sigma_deg",
        "k_s", "noise_cell_deg", "noise_rate_hz", "map_blur_deg", "fovea_sigma_deg",
        "retina_cell_deg", "bleach_display_gain", "bleach_equivalent_light",
        "gain_along_adapting_light", "alpha_eps", "Y_min", "radiance_max",
        "geometry", "surround", "surround_sigma_deg", "tracker_accuracy_deg", "tracker_rate_hz",
        "afterimage_boost", "afterimage_boost_s", "saccade_deg_s", "foveal_blind_spot",
        "rod_free_radius_deg", "fixation_s",
        "ritschel_L_ref", "ritschel_saccade_sigma_deg", "ritschel_N_sigma_deg",
        "ritschel_strength", "mikamo_drop_log10", "mikamo_lowpass_deg", "mikamo_strength",
        "mikamo_delta_e_floor",
        "acuity_cutoff_response", "acuity_sigma_max_deg", "bilateral_sigma_r",
        "thompson_dog_ratio", "thompson_dog_gain", "thompson_noise", "thompson_noise_hz",
    }
)  # fmt: skip
#: Bounds of the values that size the work of a step (a blur's radius, a grid's cells, a band
#: count, key frames a second), each far outside what the paper and we use. `Params` refuses a
#: value past one with the bound named, before anything is built; with the geometry's
#: `MAX_PPD` and the largest frame they bound every blur (`layout.check_work`).
WORK_BOUNDS: dict[str, tuple[float, float, str]] = {
    "sigma_0": (0.0, 8.0, "px, the finest acuity blur; the widest is 3.4 times it"),
    "bands": (1, MAX_BANDS, "acuity bands, the kernels' room"),
    "adaptation_sigma_deg": (0.0, 10.0, "deg, the patch the eye adapts to"),
    "rho_sigma_deg": (0.0, 5.0, "deg, the local average of Eq. 13"),
    "map_blur_deg": (0.0, 2.0, "deg, the afterimage maps' blur after 1 s"),
    "surround_sigma_deg": (0.0, 10.0, "deg, the blur of the frame's edge"),
    "rod_free_radius_deg": (0.0, 5.0, "deg, the blind spot's fill blur"),
    "retina_cell_deg": (0.02, 2.0, "deg, a retina cell: smaller cells, a larger grid"),
    "noise_cell_deg": (0.05, 20.0, "deg, the acuity noise grid: smaller cells, a larger grid"),
    "noise_rate_hz": (0.0, 240.0, "acuity noise key frames a second"),
    "acuity_sigma_max_deg": (0.0, 2.0, "deg, the acuity baselines' largest blur"),
    "ritschel_saccade_sigma_deg": (0.0, 5.0, "deg, Ritschel's micro-saccade blur"),
    "ritschel_N_sigma_deg": (0.0, 5.0, "deg, Ritschel's diffusion blur after 1 s"),
    "mikamo_lowpass_deg": (0.0, 5.0, "deg, Mikamo's low-pass"),
    "thompson_noise_hz": (0.0, 1000.0, "Thompson's noise frames a second"),
}  # fmt: skip
#: The parameters that switch a part of the model on or off.
SWITCHES = frozenset({"bleach_equivalent_light", "gain_along_adapting_light", "purkinje"})
#: Parameters that name a file on the server. A change that comes over the network may keep
#: their value or set the default (""), never a path: a viewer must not make the server read
#: its files. Set them with `gazehdr serve --params PRESET.json`.
SERVER_FILES = frozenset({"mikamo_sequence"})


def check_remote_change(current: Params, values: dict[str, Any]) -> None:
    """Refuse a change from a client that would point a file parameter somewhere new."""
    for name in sorted(SERVER_FILES & set(values)):
        if values[name] not in ("", getattr(current, name)):
            raise InputError(
                f"{name} names a file on the server and cannot be set remotely; "
                "start the server with --params PRESET.json instead"
            )


class ParamInfo(NamedTuple):
    """What the viewer's panel and the docs say of a parameter."""

    symbol: str  # the paper's (or the baseline paper's) symbol; ours where it has none
    unit: str  # "—" for a plain number
    meaning: str  # one line


_DEG, _HZ, _LOG = "deg", "Hz", "log10 units"
#: Every parameter's symbol, unit and meaning (tests/test_sim_interfaces.py checks the set).
PARAM_INFO: dict[str, ParamInfo] = {
    "gamma": ParamInfo("γ", "—", "display gamma compensation, v = J^γ"),
    "n": ParamInfo("n", "—", "Naka-Rushton exponent of the photoreceptor response (Eq. 1)"),
    "a1": ParamInfo("a₁", "log10 units/s", "adaptation speed towards brighter light (Eq. 3)"),
    "a2": ParamInfo("a₂", "log10 units/s", "adaptation speed towards darker light (Eq. 3)"),
    "b1": ParamInfo("b₁", "1/(cd/m²·s)", "L, M, S photopigment bleaching rates (Eq. 4-6)"),
    "b2": ParamInfo("b₂", "1/s", "L, M, S photopigment regeneration rates (Eq. 4-6)"),
    "c1": ParamInfo("c₁", "1/s", "calcium influx rate (Eq. 8-10); cancels in C/C_max"),
    "c2": ParamInfo("c₂", "1/s", "calcium efflux rate (Eq. 8-10)"),
    "j1": ParamInfo("j₁", "—", "strength of the bleaching afterimage (Eq. 7, 12)"),
    "j2": ParamInfo("j₂", "—", "strength of the local-adaptation afterimage (Eq. 12)"),
    "m1": ParamInfo("m₁", _LOG, "log luminance above which vision is photopic (Eq. 13)"),
    "m2": ParamInfo("m₂", _LOG, "log luminance below which vision is scotopic (Eq. 13)"),
    "w_P": ParamInfo("w_P", "—", "RGB weights of photopic luminance"),
    "w_S": ParamInfo("w_S", "—", "RGB weights of scotopic luminance"),
    "sigma_0": ParamInfo("σ₀", "px", "finest acuity blur; σ_i = σ₀·2^(i/4) at 64 px/deg"),
    "rho_step": ParamInfo("ρ step", "—", "ρ threshold between acuity bands, ρ_i = step·i"),
    "g": ParamInfo("g", "—", "variance of the stochastic acuity noise (Eq. 15)"),
    "H": ParamInfo("H", "—", "LMS bleaching levels → RGB afterimage colour"),
    "A_min": ParamInfo("A_min", "log10 cd/m²", "adaptation floor: 2 = 100 cd/m² (Sec. 2.4)"),
    "plateau_m_over_n": ParamInfo("m/n", "—", "plateau exponent of Eq. 2 over n (partial)"),
    "plateau_K": ParamInfo("K", "cd/m²", "plateau half point of Eq. 2: an office white"),
    "bands": ParamInfo("bands", "—", "number of acuity bands (i = 0..7)"),
    "adaptation_sigma_deg": ParamInfo("σ_A", _DEG, "size of the patch the eye adapts to"),
    "rho_sigma_deg": ParamInfo("σ_ρ", _DEG, "local average for ρ's luminance L (Eq. 13)"),
    "k_s": ParamInfo("k_s", "—", "scotopic tint of a neutral grey (dull purple)"),
    "noise_cell_deg": ParamInfo("noise cell", _DEG, "grid spacing of the acuity noise"),
    "noise_rate_hz": ParamInfo("noise rate", _HZ, "new acuity noise this often"),
    "map_blur_deg": ParamInfo("σ_map", _DEG, "afterimage map blur after 1 s (∝ √dt)"),
    "fovea_sigma_deg": ParamInfo("σ_fovea", _DEG, "afterimage visibility fall-off from the gaze"),
    "retina_cell_deg": ParamInfo("cell", _DEG, "size of a retina cell of the afterimage state"),
    "bleach_display_gain": ParamInfo("gain_B", "—", "display gain of Eq. 12's bleaching term"),
    "bleach_equivalent_light": ParamInfo(
        "I_x", "on/off", "Eq. 12's bleaching shown as its equivalent light (masked)"
    ),
    "gain_along_adapting_light": ParamInfo(
        "α along u", "on/off", "Eq. 11's gains along the adapting light (off: per cone)"
    ),
    "purkinje": ParamInfo("Purkinje", "on/off", "Purkinje shift of the luminance into Eq. 1"),
    "alpha_eps": ParamInfo("ε_α", "—", "guard of Eq. 11's α against 0/0"),
    "Y_min": ParamInfo("Y_min", "cd/m²", "luminance floor inside logarithms"),
    "radiance_max": ParamInfo("Y_max", "cd/m²", "cap on input radiance (the sun: 1.6e9)"),
    "geometry": ParamInfo("geometry", "m, px", "screen size, resolution and viewing distance"),
    "surround": ParamInfo("surround", "—", "light off the screen, times the frame's edge"),
    "surround_sigma_deg": ParamInfo("σ_surround", _DEG, "blur of the edge seen off the screen"),
    "tracker_accuracy_deg": ParamInfo("accuracy", _DEG, "the eye tracker's accuracy"),
    "tracker_rate_hz": ParamInfo("rate", _HZ, "the eye tracker's sample rate"),
    "afterimage_boost": ParamInfo("boost", "—", "afterimage boost after a blink or saccade"),
    "afterimage_boost_s": ParamInfo("τ_boost", "s", "time constant of that boost"),
    "saccade_deg_s": ParamInfo("v_saccade", "deg/s", "gaze speed that counts as a saccade"),
    "foveal_blind_spot": ParamInfo("blind spot", "—", "scotopic foveal fill-in (0 = off)"),
    "rod_free_radius_deg": ParamInfo("r_rod-free", _DEG, "radius of the rod-free fovea"),
    "fixation_s": ParamInfo("T_fix", "s", "typical fixation, for the blind spot's lag"),
    "c_a": ParamInfo("c_a", "1/s", "Ritschel: opsin activation constant (Sec. 3.1)"),
    "c_d": ParamInfo("c_d", "1/s", "Ritschel: opsin deactivation constant (Sec. 3.1)"),
    "ritschel_steps": ParamInfo("n", "—", "Ritschel: explicit steps per frame (Listing 1)"),
    "ritschel_L_ref": ParamInfo("L_ref", "cd/m²", "Ritschel: luminance that half-bleaches"),
    "ritschel_saccade_sigma_deg": ParamInfo("σ_s", _DEG, "Ritschel: micro-saccade blur"),
    "ritschel_N_sigma_deg": ParamInfo("N_σ", _DEG, "Ritschel: diffusion blur after 1 s"),
    "ritschel_strength": ParamInfo("strength", "—", "Ritschel: scale of the afterimage"),
    "ritschel_flight_rate": ParamInfo("flight", "rad/s", "Ritschel: flight of colours (0 = off)"),
    "mikamo_top_fraction": ParamInfo("top", "—", "Mikamo: brightest fraction that can trigger"),
    "mikamo_gamma": ParamInfo("γ", "—", "Mikamo: Z = (L_on/L_on,max)^γ (Sec. 4)"),
    "mikamo_reference_xy": ParamInfo("xy_ref", "—", "Mikamo: Padgham's light chromaticity"),
    "mikamo_drop_log10": ParamInfo("drop", _LOG, "Mikamo: fall in one step that triggers"),
    "mikamo_lowpass_deg": ParamInfo("σ_low", _DEG, "Mikamo: low-pass of the afterimage"),
    "mikamo_delta_e_floor": ParamInfo("ΔE_min", "ΔE", "Mikamo: floor of Eq. 1's divisor"),
    "mikamo_strength": ParamInfo("strength", "—", "Mikamo: scale of the afterimage"),
    "mikamo_sequence": ParamInfo("sequence", "file", "Mikamo: colour sequence CSV (server-side)"),
    "acuity_cutoff_response": ParamInfo("R_c", "—", "contrast passed at the acuity limit"),
    "acuity_sigma_max_deg": ParamInfo("σ_max", _DEG, "cap on the baselines' blur"),
    "bilateral_sigma_r": ParamInfo("σ_r", _LOG, "Jensen: range sigma of the bilateral filter"),
    "thompson_dog_ratio": ParamInfo("k_DoG", "—", "Thompson: ratio of the DoG's two sigmas"),
    "thompson_dog_gain": ParamInfo("g_DoG", "—", "Thompson: gain of the edge band"),
    "thompson_noise": ParamInfo("σ_noise", "—", "Thompson: noise at full scotopic vision"),
    "thompson_noise_hz": ParamInfo("f_noise", _HZ, "Thompson: new noise this often"),
}  # fmt: skip


def param_info() -> dict[str, dict[str, Any]]:
    """PARAM_INFO as JSON for the viewers, with `ours` (a value the paper does not give)."""
    return {name: {**i._asdict(), "ours": name in OURS} for name, i in PARAM_INFO.items()}
