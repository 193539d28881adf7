"""The experiment's pure core: the design loader's refusals, the presets' block structure, the
schedule's counterbalancing and seeding, and the training rule (gazehdr.experiment)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from gazehdr.experiment.design import DesignError, load_design, parse_design, preset_path
from gazehdr.experiment.schedule import Trial, excluded, schedule, training_score
from gazehdr.experiment.stimulus import trial_looks

#: The smallest valid design; each refusal below changes one line of it.
TINY = """\
name = "tiny"
[stimulus]
scene = "flash"
at = 1.0
on = 0.05
off = 0.1
standard = 27.0
tests = [14.0, 49.0]
[display]
fps = 20.0
size = [48, 27]
[conditions.training]
[conditions.control]
test = { params = { j1 = 0.001 } }
[[blocks]]
name = "training"
repeats = { training = 2 }
feedback = true
[[blocks]]
name = "main"
repeats = { control = 4 }
[exclusion]
block = "training"
"""


def test_the_tiny_design_loads() -> None:
    d = parse_design(TINY)
    assert d.name == "tiny" and d.tests == (14.0, 49.0) and d.fps == 20.0
    assert [b.trials for b in d.blocks] == [4, 8]
    assert d.conditions["control"].test.params == {"j1": 0.001}
    assert d.exclusion_block == "training" and d.min_correct == 0.7


@pytest.mark.parametrize(
    ("old", "new", "says"),
    [
        ('name = "tiny"', 'name = "tiny task"', "name = 'tiny task'"),
        ('scene = "flash"', 'scene = "moon"', "stimulus.scene = 'moon'"),
        ("on = 0.05", "on = -1", "stimulus.on = -1"),
        ("on = 0.05", 'on = "short"', "stimulus.on = 'short'"),
        ("tests = [14.0, 49.0]", "tests = []", "stimulus.tests = []"),
        ("tests = [14.0, 49.0]", "tests = [14.0, 490.0]", "over the monitor's white"),
        ("size = [48, 27]", "size = [48]", "display.size = [48]"),
        ("fps = 20.0", "fps = 0", "display.fps = 0"),
        ("test = { params = { j1 = 0.001 } }", "test = { params = { j9 = 1 } }", "j9"),
        ("test = { params = { j1 = 0.001 } }", 'test = { model = "nobody" }', "nobody"),
        ("[conditions.control]", "[conditions.sideways]", "conditions.sideways"),
        ("repeats = { control = 4 }", "repeats = { control = 3 }", "repeats.control = 3"),
        ("repeats = { control = 4 }", "repeats = { other = 4 }", "repeats.other = 4"),
        ('block = "training"', 'block = "warmup"', "exclusion.block = 'warmup'"),
        ("feedback = true", 'feedback = "yes"', "blocks[1].feedback = 'yes'"),
        ("feedback = true", "feedback = true\nintro = 3", "blocks[1].intro = 3"),
        ("fps = 20.0", "fps = 20.0\nbrightness = 3", "display.brightness = 3: unknown key"),
        ('name = "tiny"', 'name = "tiny"\ncolour = 1', "colour = 1: unknown key"),
    ],
)
def test_the_loader_refuses_a_bad_value_naming_key_and_value(old: str, new: str, says: str) -> None:
    assert old in TINY
    with pytest.raises(DesignError) as e:
        parse_design(TINY.replace(old, new, 1), "bad.toml")
    assert str(e.value).startswith("bad.toml: ") and says in str(e.value)


def test_the_loader_refuses_what_is_not_toml_or_missing(tmp_path: Path) -> None:
    with pytest.raises(DesignError, match="not TOML"):
        parse_design("name = ", "x.toml")
    with pytest.raises(DesignError, match=r"\[stimulus\] is missing"):
        parse_design('name = "a"\n')
    with pytest.raises(DesignError, match="the presets: afterimage-brightness"):
        load_design(tmp_path / "absent.toml")
    with pytest.raises(DesignError, match=r"4\.4: cannot read the design"):
        load_design("4.4")  # not a preset: a path, which is not there
    with pytest.raises(DesignError, match="no preset 'moon'"):
        preset_path("moon")
    # A file with keys of its own: loaded from the path.
    path = tmp_path / "mine.toml"
    path.write_text(TINY)
    assert load_design(path).source == str(path)


@pytest.mark.parametrize("preset", ["afterimage-brightness", "4.1", "mesopic-brightness", "4.2"])
def test_the_paper_presets_have_its_blocks_and_counts(preset: str) -> None:
    """Sec. 4.1.1: 20 training trials (unmanipulated, large differences), a control block with
    each test paired with the standard 20 times, a final block of 30 manipulated and 10 more
    control repetitions of each test; five tests around the standard; the 70 % rule."""
    d = load_design(preset)
    assert [b.name for b in d.blocks] == ["training", "control", "final"]
    training, control, final = d.blocks
    assert training.trials == 20 and training.feedback and set(training.repeats) == {"training"}
    assert min(training.tests) < d.standard < max(training.tests)
    assert control.repeats == {"control": 20} and control.trials == 100
    assert "brightness settings" in final.intro  # "the experimenter claimed to adjust" them
    assert final.repeats == {"manipulated": 30, "control": 10} and final.trials == 200
    assert len(d.tests) == 5 and d.standard in d.tests
    assert d.exclusion_block == "training" and d.min_correct == 0.7
    assert d.conditions["training"].test == d.conditions["control"].test
    assert d.conditions["control"].test == d.conditions["control"].standard
    assert d.conditions["manipulated"].test != d.conditions["manipulated"].standard
    assert d.conditions["manipulated"].standard == d.conditions["control"].standard


@pytest.mark.parametrize(("preset", "looks"), [("4.1", 2), ("4.2", 2), ("4.3", 3)])
def test_a_run_renders_one_clip_per_look(preset: str, looks: int) -> None:
    """The clips depend on the look, not the intensity: 4.1's weak and strong afterimages,
    4.2's photopic and mesopic renderings, 4.3's three flash strengths."""
    assert len(trial_looks(load_design(preset))) == looks


def test_the_presets_timing_and_intensities_are_the_papers() -> None:
    a, m = load_design("4.1"), load_design("4.2")
    assert (a.scene, a.on, a.off, a.standard) == ("flash", 0.05, 2.5, 27.0)
    assert a.tests == (14.0, 19.0, 27.0, 35.0, 49.0)
    assert a.conditions["control"].test.params == {"j1": 0.0003}
    assert a.conditions["manipulated"].test.params == {"j1": 0.001}
    assert (m.scene, m.on, m.off, m.standard) == ("checker-night", 1.25, 0.75, 0.055)
    assert m.tests == (0.041, 0.048, 0.055, 0.068, 0.075)
    # No Purkinje shift in the manipulated test, the rest of the model as the paper's.
    from gazehdr.sim import Params

    mesopic = Params.from_dict(m.conditions["manipulated"].test.params)
    assert mesopic == Params(purkinje=False)
    assert a.frames(a.on) == 3 and a.frames(a.off) == 150  # whole steps at 60 Hz


@pytest.mark.parametrize("preset", ["4.1", "4.2"])
def test_the_schedule_counterbalances_every_cell_exactly(preset: str) -> None:
    d = load_design(preset)
    trials = schedule(d, seed=11)
    assert [t.number for t in trials] == list(range(1, 321))
    blocks = [t.block for t in trials]
    assert blocks == sorted(blocks)  # blocks in order, randomised within
    cells = Counter((t.block, t.condition, t.test, t.test_interval) for t in trials)
    for b, block in enumerate(d.blocks, 1):
        for condition, n in block.repeats.items():
            for test in block.tests:
                assert cells[(b, condition, test, 1)] == cells[(b, condition, test, 2)] == n // 2
    assert sum(cells.values()) == len(trials)


def test_the_seed_fixes_the_order_and_another_seed_changes_it() -> None:
    d = load_design("4.1")
    assert schedule(d, 3) == schedule(d, 3)
    assert schedule(d, 3) != schedule(d, 4)
    # randomised within each block: not the order the cells were listed in
    listed = [(t.condition, t.test, t.test_interval) for t in schedule(d, 3) if t.block == 2]
    assert listed != sorted(listed, key=lambda c: (c[1], c[2]))


def _trial(test: float, interval: int, block: int = 1) -> Trial:
    return Trial(1, block, "training", "training", 27.0, test, interval, True)


def test_correct_means_the_brighter_image_was_chosen() -> None:
    brighter_first = _trial(49.0, 1)
    assert brighter_first.correct(1) is True and brighter_first.correct(2) is False
    darker_second = _trial(14.0, 2)
    assert darker_second.correct(1) is True and darker_second.correct(2) is False
    assert _trial(27.0, 1).correct(1) is None  # equal: nothing to be right about
    assert brighter_first.intensities == (49.0, 27.0) and darker_second.intensities == (27.0, 14.0)


def test_the_seventy_percent_rule() -> None:
    """Sec. 4.1.1: excluded when correct less than 70 % of the time in training."""
    t = _trial(49.0, 1)
    results = [(t, True)] * 14 + [(t, False)] * 6 + [(_trial(49.0, 1, block=2), False)] * 9
    assert training_score(results, 1) == 0.7 and not excluded(0.7, 0.7)
    results[0] = (t, False)
    assert training_score(results, 1) == pytest.approx(0.65) and excluded(0.65, 0.7)
    assert training_score([], 1) is None and not excluded(None, 0.7)
    assert training_score([(t, None)], 1) is None  # equal intensities are not scored


#: Sec. 4.3 in small: two flashes, then a palette of our model's and Ritschel's afterimage.
PALETTE = """\
name = "pal"
[stimulus]
scene = "flash"
at = 1.0
on = 0.05
off = 0.1
standard = 100.0
tests = [100.0]
[display]
fps = 20.0
size = [48, 27]
[conditions.palette]
[[blocks]]
name = "bright"
repeats = { palette = 1 }
tests = [1e7]
[[blocks]]
name = "dim"
repeats = { palette = 1 }
tests = [1e5]
[palette]
scaled = ["halo_luminance"]
choices = [
  { label = "H1", flash = 1e7, model = "jacobs" },
  { label = "C1", flash = 1e7, model = "ritschel" },
]
"""


def test_the_palette_preset_is_fig_15() -> None:
    """Sec. 4.3: flashes in three strengths (unobstructed, 4x and 32x ND), brightest first; the
    options include our model after 1e7, 1e5, 1e4, 1e3 cd/m^2 flashes (H1-H4) and Ritschel's
    (C1-C4), untransformed (the other columns of Fig. 15: tests/test_palette.py)."""
    d = load_design("4.3")
    assert [b.tests for b in d.blocks] == [(1e7,), (2.5e6,), (3.125e5,)]
    assert all(b.repeats == {"palette": 1} for b in d.blocks)
    options = {c.label: (c.flash, c.look.model, str(c.transform)) for c in d.palette}
    assert {k: v for k, v in options.items() if k[0] in "HC"} == {
        f"{m}{i}": (f, model, "none")
        for m, model in (("H", "jacobs+stochastic"), ("C", "ritschel+stochastic"))
        for i, f in enumerate((1e7, 1e5, 1e4, 1e3), 1)
    }
    # a weaker flash dims its glow in step: an ND filter darkens the whole flash
    h4 = next(c for c in d.palette if c.label == "H4")
    look = d.flash_look(h4.look, 1e3)
    assert look.scene_options == {"flash_luminance": 1e3, "halo_luminance": (10.0, 1.0)}
    trials = schedule(d, 0)
    assert [(t.condition, t.test, t.intensities) for t in trials] == [
        ("palette", 1e7, (100.0,)),
        ("palette", 2.5e6, (100.0,)),
        ("palette", 3.125e5, (100.0,)),
    ]
    assert trials[0].correct(1) is None


@pytest.mark.parametrize(
    ("old", "new", "says"),
    [
        ('label = "C1"', 'label = "H1"', "palette.choices[2].label = 'H1'"),
        ('label = "C1"', 'label = "C 1"', "palette.choices[2].label = 'C 1'"),
        ('model = "ritschel"', 'model = "ritschel2"', "palette.choices[2].model = 'ritschel2'"),
        ("flash = 1e7, model", "flash = -1.0, model", "palette.choices[1].flash = -1.0"),
        ('scaled = ["halo_luminance"]', 'scaled = ["colour"]', "palette.scaled = 'colour'"),
        ('scaled = ["halo_luminance"]', 'option = "name"\nscaled = []', "palette.option = 'name'"),
        (  # a pair of luminances: the flashes cannot be scaled by it
            'scaled = ["halo_luminance"]',
            'option = "halo_luminance"\nscaled = []',
            "palette.option = 'halo_luminance'",
        ),
        ("repeats = { palette = 1 }", "repeats = { palette = 0 }", "repeats.palette = 0"),
        ("[palette]", "[palette]\ncrop = 2.0", "palette.crop = 2.0"),
        ("[conditions.palette]", "[conditions.palette]\n[conditions.control]", "blocks[1]"),
    ],
)
def test_the_loader_refuses_a_bad_palette(old: str, new: str, says: str) -> None:
    text = PALETTE.replace(old, new, 1)
    if "conditions.control" in new:
        mixed = "repeats = { palette = 1, control = 2 }"
        text = text.replace("repeats = { palette = 1 }", mixed, 1)
    with pytest.raises(DesignError) as e:
        parse_design(text, "p.toml")
    assert says in str(e.value)


def test_palette_trials_need_choices() -> None:
    cut = PALETTE[: PALETTE.index("[palette]")]
    with pytest.raises(DesignError, match=r"palette trials need \[palette\] choices"):
        parse_design(cut)
