"""`gazehdr figures`: the paper's Figures 4-12 made again with the real simulator.

Each figure is one small function (in `afterimage`, `look_away` and `mesopic`) that runs
`Simulator`s and writes PNGs; `FIGURES` lists them with the paper's caption, what to look for,
and what we know matches or differs. `make_figures` runs a selection and writes `index.html`
(each figure beside its caption) and `figures.json` (the numbers each figure measured, which
the tests check).
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from gazehdr.drivers.errors import InputError
from gazehdr.figures import afterimage, colour, look_away, mesopic
from gazehdr.figures.common import Context, ModelUnavailableError, Result

__all__ = ["FIGURES", "Context", "Figure", "Summary", "make_figures", "select"]


@dataclass(frozen=True)
class Figure:
    key: str  # "4", "6-7"
    numbers: tuple[int, ...]  # the paper's figure numbers it answers to (for --only)
    title: str
    caption: str  # the paper's caption, quoted
    explanation: str  # how we made it and what to look for
    differences: str  # what matches the paper and what does not, as far as we know
    make: Callable[[Context], Result]


FIGURES: tuple[Figure, ...] = (
    Figure(
        "4",
        (4,),
        "Photoreceptor bleaching time course",
        "Photoreceptor bleaching time course. A bright stimulus “bleaches” a portion of a "
        "photoreceptor’s photopigments; these molecules remain bleached even after the stimulus "
        "is removed, see Section 2.2.1. The differential change in bleaching level induced by a "
        "stimulus is predicted by Equation 4 [Baylor et al. 1974]. Above we show the predicted "
        "bleaching levels over time of an L-, M-, and S-cone (shown in red, green, and blue, "
        "respectively) exposed to a 1/8 second (s), 10⁷ candela/meter² (cd/m²), white "
        "(stimulating all cone types equally) flash, ending at time t = 0s. We selected the "
        "parameters governing the three cone types’ bleaching behaviors to produce "
        "phenomenologically plausible afterimages. The corresponding afterimage color "
        "appearance for these bleaching levels is shown below in the 10⁷ cd/m² line of Figure 5.",
        "The bleaching level B of the retina cell at the gaze, read from the simulator's state "
        "after every step: a uniform white disc of 10⁷ cd/m² (radius 3°, on black) is fixated "
        "for 1/8 s in 8 steps, then the eyes close and the state is read every 0.05 s. Look "
        "for: L and M saturate during the flash, S reaches about a third; afterwards each "
        "decays as exp(−b2 t), S fastest, L slowest.",
        "Matches the caption's description (three exponentials, S fastest). The paper's plot "
        "is not given numerically, so only its shape can be compared.",
        afterimage.fig4,
    ),
    Figure(
        "5",
        (5,),
        "Bleaching afterimages and stimulus intensity",
        "Bleaching afterimages and stimulus intensity. The bleaching levels of the three cone "
        "types determines the appearance of a bleaching afterimage. Here we show our predicted "
        "bleaching afterimage appearance over time in response to brief flashes ending at time "
        "t = 0s. The corresponding flash intensities are shown on the left side of each bar. As "
        "the intensity of the flash grows, the afterimages increasingly start from cyan, always "
        "fading to magenta. The sudden transition between 10⁴ and 10⁵ cd/m² is a result of the "
        "relatively strong impact M-cones have on the final RGB afterimage appearance. The first "
        "hint of green begins appearing around 10^4.5 cd/m², but is not shown here. The "
        "corresponding cone bleaching levels for the 10⁷ cd/m² flash are shown above in "
        "Figure 4.",
        "The displayed value at the centre of the flash disc (the same runs as Fig. 4, one per "
        "intensity), eyes closed after the flash, every 0.05 s. Top: as the display shows it "
        "(Eq. 12's bleaching term as printed, j1 = 0.03 of display white at most; our "
        "`visible` preset brings the 10⁷ row's start to display white); bottom: each swatch "
        "scaled to full brightness, so only its hue remains. The hues listed below are HSV "
        "hues (0° red, 60° yellow, 120° green, 180° cyan, 300° magenta) at 0.05, 1, 2, 4 and "
        "8 s, of the display values (as a figure is seen) and of the light (linear RGB), "
        "named after the nearest of the RGB colour wheel's twelve hues.",
        "Matches: weak flashes (10³, 10⁴) start and stay red to rose; from 10⁵ the afterimage "
        "starts green and the change between 10⁴ and 10⁵ is abrupt; the stronger the flash, "
        "the nearer cyan it starts (the hues measured are below). Where the caption and the "
        "equations disagree, this follows the equations (Eq. 7 with Appendix A's H and b2): "
        "the 10⁷ flash starts spring green, short of cyan (H·ΔB of a white 10⁷ flash as it "
        "ends has hue 151°, cyan is 180°; the display's gamma moves it a little toward cyan); "
        "every row ends rose-pink, the hue of H's first column (1.14, 0.08, 0.30), 348° in "
        "light, where the caption says magenta (300°), because the L cones' bleaching "
        "outlasts the others' (b2 smallest); Fig. 3's “pink or deep purple” fits it better. "
        "On the way, strong flashes pass through yellow and red as the M cones' bleaching "
        "fades before the L cones', a phase the caption does not name.",
        afterimage.fig5,
    ),
    Figure(
        "6-7",
        (6, 7),
        "Bleaching afterimages after a flash, eyes closed: three models",
        "Fig. 6: Animated bleaching afterimages. […] a comparison of the time dynamics of the "
        "afterimages generated by a flash, as predicted by our model (left), Ritschel and "
        "Eisemann’s model [2012] (middle), and Mikamo et al.’s [2013] model (right). Mikamo et "
        "al.’s model predicts a longer-lasting afterimage, so we show it at 2× playback speed. "
        "[…] Notice that the model by Ritschel and Eisemann fails to reproduce the color casts "
        "that are commonly observed when exposed to a very bright stimulus.\n"
        "Fig. 7: Bleaching afterimages. To illustrate the appearance of bleaching afterimages as "
        "predicted by our model, we simulate a viewer shutting his or her eyes after a brief "
        "exposure to a scene (i.e., we suddenly drop the scene radiance to zero). The appearance "
        "of the afterimage t seconds after the “blink” is shown in each column as marked. The "
        "gaze position is also held constant in this figure […]. In particular, note the "
        "presence of cyan, green, and pink elements in each afterimage. We also provide Ritschel "
        "and Eisemann’s result for comparison; note that their model cannot capture the colorful "
        "nature of afterimages produced by a color-neutral stimulus.",
        "The built-in `flash` scene (10⁷ cd/m² head, 1/8 s), gaze on the flash head, 2 frames "
        "of the room, the flash at 30 frames/s, then the eyes close (`eyes_open=False`) and "
        "the frames at t = 0.5 … 8 s are shown (steps of 0.1 s for the first second, then "
        "0.25 s). Panels are the part of the frame around the flash, enlarged. As in Fig. 6, "
        "Mikamo's column t shows its simulated time 2t. The second image is the same with "
        "every panel 4× brighter in linear light, to show the colours of the dim ones. "
        "The third and fourth images are Fig. 7's top rows: two HDR photographs in place of "
        "the paper's Fairchild photographs (which we cannot ship), views cut from the CC0 world "
        "HDRIs by Greg Zaal (HDRI Haven) that Debian's blender-data ships "
        "(server/figures/data/README.md): a sunlit courtyard scaled so that its brightest "
        "pixel is 10^3.5 cd/m² and a studio lamp scaled to 10^4.5 cd/m², the paper's "
        "maximum radiances (each the file's values times 10^peak / its brightest pixel's "
        "luminance in the frame, about 300×; the factor is listed below). The eye settles on "
        "the photograph, its gaze held (the courtyard's centre, the lamp), sees it 2 frames "
        "more (the first panel), then the eyes close; ours and Ritschel's, whole frames, "
        "again also 4× brighter. Should the photographs be missing from an installation, "
        "the figure is not made and says which file is missing.",
        "Matches: Ritschel's afterimage of the neutral flash is neutral grey; Mikamo's runs "
        "through a sequence of hues and lasts longest; ours has a green centre with a red rim "
        "and fades to red-rose, far dimmer than the other two (Eq. 12's bleaching term as "
        "printed, j1 = 0.03 of display white: the second image shows every panel 4× "
        "brighter). The photographs' rows match Fig. 5 at their peaks: at 10^3.5 ours is red "
        "to rose throughout, at 10^4.5 the lamp's centre starts with a hint of green inside a "
        "red rim; Ritschel's is a negative of the courtyard's colours and a neutral grey for "
        "the white lamp. Differs: our photographs are not the paper's (two Fairchild "
        "photographs, which we cannot ship), and the paper does not say how long its scenes "
        "were seen or where the gaze was held.",
        afterimage.fig6_7,
    ),
    Figure(
        "8",
        (8,),
        "Combining afterimage types: the calcium term",
        "Combining afterimage types. The gain induced by calcium affects the entire "
        "transduction process, including cascades initiated by bleached photopigments. We can "
        "combine adaptation afterimages with bleaching afterimages to reflect this. From left to "
        "right: the original scene, bleaching afterimages without local adaptation applied, and "
        "bleaching afterimages with local adaptation applied (the C/C_max term in Equation 12).",
        "The built-in `lamp` scene: the bulb (10⁶ cd/m²) is fixated for 3 s, then the gaze "
        "moves to the left page of the book; the panels show the book 0.3 s later, when the "
        "bulb's afterimage lies at the gaze. Left: no afterimage; middle: Eq. 7 (bleaching "
        "term without C/C_max and without the adaptation gain α^j2); right: Eq. 12, the "
        "simulator's own frame. The Params cannot switch the calcium factor off, so the left "
        "and middle panels are recomposed with the NumPy reference (`afterimage_maps`, "
        "`compose`) from the simulator's state at that moment; the same recomposition with "
        "C/C_max reproduces the simulator's frame (number below).",
        "Matches: with the calcium term the bleaching afterimage of a bright source seen in a "
        "bright situation is weak (c = C/C_max is low where the bulb was), and the local "
        "adaptation gain turns the spot darker than the page. The paper's scene is a Fairchild "
        "photograph; ours is the procedural lamp.",
        look_away.fig8,
    ),
    Figure(
        "9",
        (9,),
        "Local adaptation afterimages: ours vs Ritschel & Eisemann",
        "Local adaptation afterimages. Long fixations give individual photoreceptors time to "
        "adapt. When the gaze moves to a new position, the spatially-varying photoreceptor "
        "sensitivities manifest themselves as an afterimage of the first fixation. The top row "
        "shows the adaptation afterimage of a bright white lamp, which appears as a dark spot on "
        "the book. The model by Ritschel and Eisemann predicts a less plausible, bright white "
        "spot. The bottom row shows the adaptation afterimage of a strongly colored stimulus. "
        "Both models produce color-opponent afterimages (e.g., the blue squares become yellow), "
        "but our model does so by modulating the background appearance, while Ritschel and "
        "Eisemann overlay an afterimage which is strictly brighter than the background. In other "
        "words, their model only predicts positive afterimages.",
        "Top row (first image): the same lamp run as Fig. 8 for both models: 3 s on the bulb "
        "(frames of 0.25 s), then 0.3 s on the book (frames of 0.1 s). Columns: the frame "
        "while fixating; the book without any afterimage (the reference compose with neutral "
        "maps, same adaptation); the book with the model's afterimage. The number below "
        "compares the luminance inside the bulb's afterimage with and without it. Bottom row "
        "(second image): a procedural stimulus, four squares of saturated blue (the sRGB blue "
        "primary, 433 cd/m²) on a 100 cd/m² grey, fixated for 3 s, then 0.3 s on the plain "
        "grey field to their right, so that their afterimage lands on grey; same columns. "
        "The display's blue primary alone cannot reach the squares' luminance; the gamut "
        "mapping (ours) keeps their hue and saturation and gives up luminance, so they show "
        "saturated blue. The numbers below give the grey field where the squares' afterimage "
        "lies, per channel relative to the grey around it, and the hue of that change against "
        "the blue's complement (60°, yellow). Third image: the same for squares of twelve "
        "saturated hues at the grey's luminance (ours only); its last row shows each "
        "afterimage's change from the grey 5× larger.",
        "Matches the top row: ours is a dark spot on the book, Ritschel's a bright one. Bottom "
        "row: both afterimages are opponent to blue, yellow (R + G > 2B in linear light; the "
        "hues measured are below); ours modulates the grey while Ritschel's is added on top "
        "(no channel darker, all brighter or equal). Our calcium gain keeps each cone's "
        "strength (Eq. 11) but points along the adapting light's cone contrast (ours, on in "
        "the paper preset, docs/model.md): per cone, as Eq. 11 is printed, it compresses the "
        "blue's large S contrast far more than its small L − M contrast and leaves orange "
        "(`gain_along_adapting_light = false`), where the caption and Sec. 2.2.3 say yellow. "
        "The stimulus and its luminances are ours (the paper's picture is not given); a blue "
        "no brighter than the grey leaves Ritschel's model almost nothing.",
        colour.fig9,
    ),
    Figure(
        "10",
        (10,),
        "Purkinje effect",
        "Purkinje effect. As the illumination decreases, the perception of the relative "
        "intensities of different colors is altered. The leftmost column shows the original "
        "scene without any mesopic cues. The two other columns show the luminance channel of "
        "the scene (middle column) and the luminance channel of the scene after applying the "
        "Purkinje effect (rightmost column). Notice that the blue square becomes slightly "
        "brighter and the red square becomes darker when the Purkinje shift cue is active.",
        "The built-in ColorChecker (`checker-night`) with its white patch at four luminances, "
        "fixated at its centre, at equilibrium. Left: rendered without mesopic cues (m1, m2 "
        "moved to −10, −12 so ρ ≥ 1 everywhere); middle: its luminance; right: the luminance "
        "of the default rendering, which is R(mesopic luminance), the Purkinje-shifted one "
        "(the hue shift keeps luminance, w_P·k_s = 1). Panels are scaled to one mean "
        "luminance (see Fig. 11).",
        "Matches: as the level falls the blue patch (third row, first) brightens and the red "
        "(third row, third) darkens relative to the photopic luminance; the shift saturates "
        "once ρ reaches 0 (below about 10⁻² cd/m² of local mean).",
        mesopic.fig10,
    ),
    Figure(
        "11",
        (11,),
        "Mesopic effects: desaturation, purple shift, acuity",
        "Mesopic effects. Above we show a scene rendered with varying levels of mesopic cues "
        "injected, while keeping the mean pixel brightnesses constant. The simulated luminance "
        "of the white square at the bottom left corner of the color checker is shown above each "
        "column. As the luminance of a scene decreases, the scene loses color saturation and "
        "tends towards a dull purple color. […] The bottom row of inset images shows the gradual "
        "reduction in visual acuity trending with luminance as well.",
        "Top: the ColorChecker at five white-patch luminances, each panel scaled in linear "
        "light to the same mean luminance, as in the paper. Bottom: the corner of four patches "
        "at the paper's pixel density (a crop of a 1920×1080 rendering simulated at 64 px/°), "
        "where the acuity bank acts at its real size.",
        "Matches: saturation falls and every patch drifts to the dull purple k_s; the inset "
        "edges blur as the luminance falls. Differs: the paper does not say which luminances "
        "its columns show; ours are chosen to span the model's mesopic range (m2 = −2 to m1 = "
        "0 log cd/m² of local mean), below which nothing changes any more.",
        mesopic.fig11,
    ),
    Figure(
        "12",
        (12,),
        "Stochastic loss of acuity vs other acuity models",
        "Animated stochastic loss of acuity. Our model produces a spatially- and "
        "temporally-varying loss of visual acuity. We compare our model with Thompson et al.’s "
        "[2002] and bilateral filtering [Jensen et al. 2000]. […] Note that the variance of the "
        "acuity loss is exaggerated here for illustrative purposes.",
        "A bar chart (periods 2-12 px) with its peak at 0.3 cd/m² (ρ ≈ 0.5 locally), at the "
        "paper's pixel density (64 px/°), fixated at its centre; four frames 0.25 s apart (the "
        "stochastic noise has a key frame every 0.25 s) for each acuity model. Panels are "
        "scaled to one mean luminance.",
        "Matches: ours loses detail unevenly, with patches of full resolution that come and go "
        "between frames; the Gaussian blur is uniform and static; Thompson adds temporal noise "
        "to a blur. Differs: we use the default variance g = 0.25, not an exaggerated one.",
        mesopic.fig12,
    ),
)


def select(only: Iterable[int] | None) -> list[Figure]:
    """The figures answering to the given paper figure numbers (all when None)."""
    if only is None:
        return list(FIGURES)
    wanted = set(only)
    known = {n for f in FIGURES for n in f.numbers}
    unknown = sorted(wanted - known)
    if unknown:
        raise InputError(
            f"no figure {', '.join(map(str, unknown))}; choose from "
            f"{', '.join(map(str, sorted(known)))}"
        )
    return [f for f in FIGURES if wanted & set(f.numbers)]


@dataclass(frozen=True)
class Summary:
    files: list[Path]
    failed: dict[str, str]  # figure key -> why
    seconds: float


def make_figures(ctx: Context, figures: list[Figure], progress: bool = True) -> Summary:
    """Make the figures into `ctx.out_dir`, then index.html and figures.json.

    A figure whose model does not import is reported as failed (on the page and in the
    summary), never drawn with another model; the other figures are still made.
    """
    from tqdm import tqdm

    started = time.perf_counter()
    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, Result | str] = {}
    bar = tqdm(figures, unit="fig", disable=not progress)
    for fig in bar:
        bar.set_description(f"Fig. {fig.key}")
        try:
            results[fig.key] = fig.make(ctx)
        except ModelUnavailableError as e:
            results[fig.key] = str(e)
    done = {k: r for k, r in results.items() if isinstance(r, Result)}
    (ctx.out_dir / "figures.json").write_text(
        json.dumps({k: {"images": [n for n, _ in r.images], **r.measures} for k, r in done.items()})
    )
    (ctx.out_dir / "index.html").write_text(page(ctx, figures, results))
    files = [ctx.out_dir / n for r in done.values() for n, _ in r.images]
    files += [ctx.out_dir / "figures.json", ctx.out_dir / "index.html"]
    failed = {k: r for k, r in results.items() if isinstance(r, str)}
    return Summary(files, failed, time.perf_counter() - started)


_STYLE = """
body { font: 15px/1.45 system-ui, sans-serif; max-width: 1400px; margin: 2em auto; padding: 0 1em;
       color: #222; }
section { border-top: 1px solid #ccc; padding-top: 1em; margin-top: 2em; }
img { max-width: 100%; image-rendering: pixelated; display: block; margin: .5em 0; }
blockquote { margin: .5em 0; padding: .5em 1em; background: #f4f4f4; border-left: 4px solid #999;
             white-space: pre-line; }
.failed { color: #a00; font-weight: bold; }
h3 { font-size: 1em; margin: 1em 0 .2em; }
"""


def page(ctx: Context, figures: list[Figure], results: dict[str, Result | str]) -> str:
    """index.html: one section per figure, its PNGs beside the paper's caption."""
    e = html.escape
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>",
        "<title>gazehdr: the figures of Jacobs et al. 2015</title>",
        f"<style>{_STYLE}</style></head><body>",
        "<h1>Figures 4–12 of Jacobs et al. 2015, made with gazehdr</h1>",
        f"<p>Frame size {ctx.width}×{ctx.height}, backend {e(ctx.backend)}, seed {ctx.seed}. "
        "Every image comes from <code>gazehdr.sim.Simulator</code> with the default "
        "parameters unless a figure says otherwise. PNGs are the display values rounded to "
        "8 bits (no dither: these are stills). The numbers under each figure are in "
        "<code>figures.json</code>.</p>",
    ]
    for fig in figures:
        result = results[fig.key]
        parts.append(f"<section id='fig{e(fig.key)}'><h2>Fig. {e(fig.key)}: {e(fig.title)}</h2>")
        if isinstance(result, str):
            parts.append(f"<p class='failed'>Not made: {e(result)}</p>")
        else:
            parts += [f"<img src='{e(name)}' alt='{e(alt)}'>" for name, alt in result.images]
        parts += [
            f"<h3>The paper's caption</h3><blockquote>{e(fig.caption)}</blockquote>",
            f"<h3>How we made it, what to look for</h3><p>{e(fig.explanation)}</p>",
        ]
        if isinstance(result, Result) and result.findings:
            items = "".join(f"<li>{e(x)}</li>" for x in result.findings)
            parts.append(f"<h3>Measured</h3><ul>{items}</ul>")
        parts.append(f"<h3>Matches and differs</h3><p>{e(fig.differences)}</p></section>")
    parts.append("</body></html>\n")
    return "\n".join(parts)
