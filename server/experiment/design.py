"""An experiment's declarative file (TOML) and its loader, which refuses a bad file with an error
naming the key and the value (docs/experiments.md has the format).

A design says what one 2AFC trial shows (a scene, on for `on` s then black for `off` s, two
intervals: the standard and a test), how each condition renders the two (model parameters,
models), which blocks of which conditions and tests make the run, and the texts and keys of
the page. The paper's Sec. 4 experiments ship as presets (presets/*.toml).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from gazehdr.drivers.errors import InputError
from gazehdr.experiment import transforms
from gazehdr.experiment.columns import CONDITIONS
from gazehdr.experiment.transforms import NONE, Transform
from gazehdr.scenes.procedural import BUILTIN
from gazehdr.sim import Params
from gazehdr.sim.display import PAPER_DISPLAY, DisplayModel
from gazehdr.sim.models import Models

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: tomli, as the batch manifest
    import tomli as tomllib  # type: ignore[no-redef]

#: Preset names and the paper's section numbers they stand for.
PRESETS = {
    "afterimage-brightness": "4.1",
    "mesopic-brightness": "4.2",
    "afterimage-palette": "4.3",
}
SCALES = ("peak", "mean")
_LABEL = re.compile(r"[A-Za-z0-9]+")
_KEY = re.compile(r"[A-Za-z0-9]|Arrow(Left|Right|Up|Down)|Space")


class DesignError(InputError):
    """A design file that cannot be run; the message names the file, key and value."""


@dataclass(frozen=True)
class Look:
    """How one interval is rendered: `Params` overrides, the `AFTERIMAGE+ACUITY` models, and
    scene options over the design's (a palette trial's flash strength)."""

    params: dict[str, Any] = field(default_factory=dict)
    model: str = "jacobs+stochastic"
    scene_options: dict[str, Any] = field(default_factory=dict)

    def key(self) -> tuple[Any, ...]:
        def items(d: dict[str, Any]) -> tuple[tuple[str, str], ...]:
            return tuple(sorted((k, repr(v)) for k, v in d.items()))

        return (items(self.params), self.model, items(self.scene_options))

    def with_scene(self, **options: Any) -> Look:
        return Look(self.params, self.model, {**self.scene_options, **options})


@dataclass(frozen=True)
class Choice:
    """An option of the palette (Sec. 4.3, Fig. 15): the first frame of black after a flash of
    `flash` cd/m^2, rendered with `look`, then given the colour `transform`
    (`gazehdr.experiment.transforms`: none, hue+D, hue-D, tint=H/S)."""

    label: str
    flash: float
    look: Look
    transform: Transform = NONE


@dataclass(frozen=True)
class Condition:
    name: str
    standard: Look
    test: Look


@dataclass(frozen=True)
class Block:
    """Trials of `repeats[condition]` repetitions of each test (half with the test first),
    presented in random order."""

    name: str
    repeats: dict[str, int]
    tests: tuple[float, ...]
    feedback: bool = False
    intro: str | None = None  # shown before the block's first trial, until Space

    @property
    def trials(self) -> int:
        return sum(self.repeats.values()) * len(self.tests)


@dataclass(frozen=True)
class Texts:
    consent: str = "I agree to take part in this experiment."
    instructions: str = "Look at the cross. Two images follow; say which was brighter."
    question: str = "Which was brighter?"
    thanks: str = "Thank you for taking part."
    excluded: str = "Thank you. The training showed that we cannot use your answers today."
    right: str = "Right."
    wrong: str = "Wrong."


@dataclass(frozen=True)
class Design:
    name: str  # the BIDS task label
    title: str
    scene: str
    scene_options: dict[str, Any]
    at: float  # the scene's time whose image is the stimulus
    on: float  # s of the image (the flash)
    off: float  # s of black after it
    scale: str  # what `intensity` measures on screen: the frame's "peak" or its "mean"
    standard: float  # cd/m^2
    tests: tuple[float, ...]
    conditions: dict[str, Condition]
    blocks: tuple[Block, ...]
    #: The lab's monitor, as the experimenter measured it: its white (cd/m^2) and gamma.
    display: DisplayModel = PAPER_DISPLAY
    fps: float = 60.0
    size: tuple[int, int] = (640, 360)
    fixation: tuple[float, float] = (0.5, 0.5)
    keys: tuple[str, str] = ("1", "2")  # first interval brighter, second brighter
    texts: Texts = field(default_factory=Texts)
    exclusion_block: str | None = None
    min_correct: float = 0.7
    render_seed: int = 0
    #: Sec. 4.3: the options observers pick from, and the scene option a flash strength sets.
    palette: tuple[Choice, ...] = ()
    palette_option: str = "flash_luminance"
    palette_scaled: tuple[str, ...] = ()  # scene options scaled with the flash (its glow)
    palette_crop: float = 0.4  # the options' images: this many frame heights around their peak
    source: str = "<memory>"

    @property
    def dt(self) -> float:
        return 1.0 / self.fps

    def flash_look(self, look: Look, flash: float) -> Look:
        """`look` with a flash of `flash` cd/m^2 (a palette trial's, or an option's): the
        palette option set, and the options it scales with (e.g. the flash's glow) in step."""
        base = make_scene(self.scene, {**self.scene_options, **look.scene_options})
        k = flash / getattr(base, self.palette_option)
        scaled = {n: _scaled(getattr(base, n), k) for n in self.palette_scaled}
        return look.with_scene(**{self.palette_option: flash}, **scaled)

    def frames(self, seconds: float) -> int:
        """Whole frames of a phase: `seconds` rounded to the nearest step, at least one."""
        return max(1, round(seconds * self.fps))


def _scaled(value: Any, k: float) -> Any:
    return tuple(v * k for v in value) if isinstance(value, tuple) else value * k


def make_scene(name: str, options: dict[str, Any]) -> Any:
    """The built-in scene `name` with `options` replacing its defaults."""
    return replace(BUILTIN[name](), **options)


def preset_path(name: str) -> Path:
    """The file of a shipped preset, by name or by the paper's section number (4.1, 4.2)."""
    by_section = {v: k for k, v in PRESETS.items()}
    stem = by_section.get(name, name)
    if stem not in PRESETS:
        known = ", ".join(f"{k} ({v})" for k, v in PRESETS.items())
        raise DesignError(f"no preset {name!r}; the presets are {known}")
    return Path(str(resources.files("gazehdr.experiment") / "presets" / f"{stem}.toml"))


def load_design(source: str | Path) -> Design:
    """A preset (by name) or a design file (by path), checked."""
    named = str(source)
    is_preset = named in PRESETS or named in PRESETS.values()
    path = preset_path(named) if is_preset else Path(source)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        presets = ", ".join(f"{k} ({v})" for k, v in PRESETS.items())
        raise DesignError(
            f"{path}: cannot read the design: {e.strerror} (the presets: {presets})"
        ) from None
    return parse_design(text, str(path))


def parse_design(text: str, where: str = "<design>") -> Design:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DesignError(f"{where}: not TOML: {e}") from None
    return _Reader(where).design(data)


class _Reader:
    """Takes keys out of tables with their checks; what is left over is an unknown key."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, key: str, value: Any, why: str) -> DesignError:
        return DesignError(f"{self.where}: {key} = {value!r}: {why}")

    def table(self, data: dict[str, Any], key: str, required: bool = False) -> dict[str, Any]:
        if key not in data:
            if required:
                raise DesignError(f"{self.where}: the table [{key}] is missing")
            return {}
        value = data.pop(key)
        if not isinstance(value, dict):
            raise self.fail(key, value, "must be a table")
        return value

    def done(self, data: dict[str, Any], prefix: str) -> None:
        for key, value in data.items():
            raise self.fail(f"{prefix}{key}", value, "unknown key")

    def number(self, data: dict, key: str, path: str, default: float | None = None) -> float:
        value = data.pop(key, default)
        if value is None:
            raise DesignError(f"{self.where}: {path}{key} is missing")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(path + key, value, "must be a number")
        if not (math.isfinite(value) and value > 0):
            raise self.fail(path + key, value, "must be a finite number > 0")
        return float(value)

    def text(self, data: dict, key: str, path: str, default: str | None = None) -> str:
        value = data.pop(key, default)
        if value is None:
            raise DesignError(f"{self.where}: {path}{key} is missing")
        if not isinstance(value, str) or not value.strip():
            raise self.fail(path + key, value, "must be a non-empty string")
        return value

    def pair(self, data: dict, key: str, path: str, default: tuple, kind: type) -> tuple:
        value = data.pop(key, list(default))
        ok = isinstance(value, list) and len(value) == 2
        ok = ok and all(isinstance(v, kind) and not isinstance(v, bool) for v in value)
        if not ok:
            raise self.fail(path + key, value, f"must be two {kind.__name__}s")
        return tuple(value)

    def intensities(self, value: Any, key: str) -> tuple[float, ...]:
        ok = isinstance(value, list) and value
        if not ok or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            raise self.fail(key, value, "must be a non-empty list of luminances (cd/m^2)")
        if not all(math.isfinite(v) and v > 0 for v in value):
            raise self.fail(key, value, "every luminance must be a finite number > 0")
        return tuple(float(v) for v in value)

    def look(self, data: Any, path: str) -> Look:
        if not isinstance(data, dict):
            raise self.fail(path, data, "must be a table with params and/or model")
        data = dict(data)
        params = data.pop("params", {})
        if not isinstance(params, dict):
            raise self.fail(path + ".params", params, "must be a table of model parameters")
        try:
            Params.from_dict(params)
        except (TypeError, ValueError) as e:
            raise self.fail(path + ".params", params, str(e)) from None
        model = data.pop("model", "jacobs+stochastic")
        try:
            model = str(Models.parse(model)) if isinstance(model, str) else None
        except ValueError as e:
            raise self.fail(path + ".model", model, str(e)) from None
        if model is None:
            raise self.fail(path + ".model", data.get("model"), "must be AFTERIMAGE+ACUITY")
        self.done(data, path + ".")
        return Look(dict(params), model)

    def palette(self, table: dict[str, Any], scene: str, options: dict) -> tuple[Any, ...]:
        if not table:
            return (), "flash_luminance", (), 0.4
        option = self.text(table, "option", "palette.", "flash_luminance")
        crop = self.number(table, "crop", "palette.", 0.4)
        if crop > 1:
            raise self.fail("palette.crop", crop, "a fraction of the frame's height, up to 1")
        scaled = table.pop("scaled", [])
        if not isinstance(scaled, list) or not all(isinstance(n, str) for n in scaled):
            raise self.fail("palette.scaled", scaled, "must be a list of scene option names")
        base = make_scene(scene, options)
        for key, names in (("option", [option]), ("scaled", scaled)):
            for n in names:
                value = getattr(base, n, None)
                ok = isinstance(value, int | float) or (
                    isinstance(value, tuple) and all(isinstance(v, int | float) for v in value)
                )
                if not ok or n.startswith("_"):
                    raise self.fail(f"palette.{key}", n, f"not a luminance option of {scene}")
                scalar = isinstance(value, int | float)
                if key == "option" and not (scalar and math.isfinite(value) and value > 0):
                    raise self.fail("palette.option", n, "must be a positive luminance in the "
                                    "scene: the palette's flashes are scaled by it")  # fmt: skip
        value = table.pop("choices", [])
        if not isinstance(value, list):
            raise self.fail("palette.choices", value, "must be an array of tables")
        choices: list[Choice] = []
        for i, spec in enumerate(value, 1):
            path = f"palette.choices[{i}]"
            if not isinstance(spec, dict):
                raise self.fail(path, spec, "must be a table with label, flash, model, transform")
            spec = dict(spec)
            label = self.text(spec, "label", path + ".")
            if not _LABEL.fullmatch(label) or label in {c.label for c in choices}:
                raise self.fail(path + ".label", label, "letters and digits, once each")
            flash = self.number(spec, "flash", path + ".")
            name = spec.pop("transform", "none")
            try:
                transform = transforms.parse(name)
            except ValueError as e:
                raise self.fail(path + ".transform", name, str(e)) from None
            look = self.look(spec, path)
            choices.append(Choice(label, flash, look, transform))
        self.done(table, "palette.")
        return tuple(choices), option, tuple(scaled), crop

    def design(self, data: dict[str, Any]) -> Design:
        name = self.text(data, "name", "")
        if not _LABEL.fullmatch(name):
            raise self.fail("name", name, "the BIDS task label: letters and digits only")
        title = self.text(data, "title", "", name)
        seed = data.pop("render_seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise self.fail("render_seed", seed, "must be an integer >= 0")
        stim = self.table(data, "stimulus", required=True)
        scene = self.text(stim, "scene", "stimulus.")
        if scene not in BUILTIN:
            raise self.fail("stimulus.scene", scene, f"not a built-in scene ({', '.join(BUILTIN)})")
        options = stim.pop("scene_options", {})
        if not isinstance(options, dict):
            raise self.fail("stimulus.scene_options", options, "must be a table")
        try:
            make_scene(scene, options)
        except (TypeError, ValueError) as e:
            raise self.fail("stimulus.scene_options", options, str(e)) from None
        at = stim.pop("at", 0.0)
        if isinstance(at, bool) or not isinstance(at, int | float) or not math.isfinite(at):
            raise self.fail("stimulus.at", at, "must be a finite number of seconds")
        on = self.number(stim, "on", "stimulus.")
        off = self.number(stim, "off", "stimulus.")
        scale = stim.pop("scale", "peak")
        if scale not in SCALES:
            raise self.fail("stimulus.scale", scale, f"must be one of {', '.join(SCALES)}")
        standard = self.number(stim, "standard", "stimulus.")
        tests = self.intensities(stim.pop("tests", None), "stimulus.tests")
        self.done(stim, "stimulus.")

        display = self.table(data, "display")
        white = self.number(display, "white", "display.", PAPER_DISPLAY.white_cd_m2)
        gamma = self.number(display, "gamma", "display.", PAPER_DISPLAY.gamma)
        fps = self.number(display, "fps", "display.", 60.0)
        size = self.pair(display, "size", "display.", (640, 360), int)
        if not all(8 <= s <= 4096 for s in size):
            raise self.fail("display.size", list(size), "each side must be 8 to 4096 px")
        fixation = self.pair(display, "fixation", "display.", (0.5, 0.5), float)
        if not all(0.0 <= f <= 1.0 for f in fixation):
            raise self.fail("display.fixation", list(fixation), "must be frame fractions in [0, 1]")
        self.done(display, "display.")
        too_bright = [v for v in (standard, *tests) if v > white]
        if too_bright:
            raise self.fail(
                "stimulus.tests", list(tests),
                f"{too_bright[0]:g} cd/m^2 is over the monitor's white (display.white = {white:g})",
            )  # fmt: skip

        keys_t = self.table(data, "keys")
        keys = (self.text(keys_t, "first", "keys.", "1"), self.text(keys_t, "second", "keys.", "2"))
        for k, v in zip(("first", "second"), keys, strict=True):
            if not _KEY.fullmatch(v):
                raise self.fail(f"keys.{k}", v, "a letter, a digit, Space or an arrow key")
        if keys[0] == keys[1]:
            raise self.fail("keys.second", keys[1], "must differ from keys.first")
        self.done(keys_t, "keys.")

        text_t = self.table(data, "text")
        texts = Texts(**{f: self.text(text_t, f, "text.", getattr(Texts(), f)) for f in _TEXTS})
        self.done(text_t, "text.")

        conditions = self.conditions(self.table(data, "conditions", required=True))
        blocks = self.blocks(data.pop("blocks", None), conditions, tests)
        choices, option, scaled, crop = self.palette(self.table(data, "palette"), scene, options)
        if any("palette" in b.repeats for b in blocks) and not choices:
            raise DesignError(f"{self.where}: palette trials need [palette] choices to pick from")
        exclusion = self.table(data, "exclusion")
        block = exclusion.pop("block", None)
        if block is not None and block not in {b.name for b in blocks}:
            raise self.fail("exclusion.block", block, "names no block")
        min_correct = exclusion.pop("min_correct", 0.7)
        if not isinstance(min_correct, int | float) or not 0 <= min_correct <= 1:
            raise self.fail("exclusion.min_correct", min_correct, "must be a fraction in [0, 1]")
        self.done(exclusion, "exclusion.")
        self.done(data, "")
        return Design(
            name=name, title=title, scene=scene, scene_options=options, at=float(at), on=on,
            off=off, scale=scale, standard=standard, tests=tests, conditions=conditions,
            blocks=blocks, display=DisplayModel(white, gamma), fps=fps, size=size,
            fixation=fixation, keys=keys, texts=texts, exclusion_block=block,
            min_correct=float(min_correct),
            render_seed=seed, palette=choices, palette_option=option, palette_scaled=scaled,
            palette_crop=crop, source=self.where,
        )  # fmt: skip

    def conditions(self, table: dict[str, Any]) -> dict[str, Condition]:
        out = {}
        for name, spec in table.items():
            if name not in CONDITIONS:
                known = ", ".join(CONDITIONS)
                raise self.fail(f"conditions.{name}", spec, f"unknown condition; known: {known}")
            if not isinstance(spec, dict):
                raise self.fail(f"conditions.{name}", spec, "must be a table")
            spec = dict(spec)
            standard = self.look(spec.pop("standard", {}), f"conditions.{name}.standard")
            test = self.look(spec.pop("test", {}), f"conditions.{name}.test")
            self.done(spec, f"conditions.{name}.")
            out[name] = Condition(name, standard, test)
        if not out:
            raise DesignError(f"{self.where}: [conditions] names no condition")
        return out

    def blocks(self, value: Any, conditions: dict[str, Condition], tests: tuple) -> tuple:
        if not isinstance(value, list) or not value:
            raise self.fail("blocks", value, "must be a non-empty array of tables [[blocks]]")
        out = []
        for i, spec in enumerate(value, 1):
            path = f"blocks[{i}]."
            if not isinstance(spec, dict):
                raise self.fail(f"blocks[{i}]", spec, "must be a table")
            spec = dict(spec)
            name = self.text(spec, "name", path)
            if name in {b.name for b in out}:
                raise self.fail(path + "name", name, "another block has this name")
            repeats = spec.pop("repeats", None)
            if not isinstance(repeats, dict) or not repeats:
                raise self.fail(path + "repeats", repeats, "must be a table condition = count")
            for cond, n in repeats.items():
                if cond not in conditions:
                    raise self.fail(f"{path}repeats.{cond}", n, "no such condition in [conditions]")
                if cond == "palette":
                    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
                        raise self.fail(f"{path}repeats.{cond}", n, "must be a count >= 1")
                    if len(repeats) > 1:
                        raise self.fail(path + "repeats", repeats, "a palette block holds only "
                                        "palette trials")  # fmt: skip
                elif not isinstance(n, int) or isinstance(n, bool) or n < 2 or n % 2:
                    raise self.fail(
                        f"{path}repeats.{cond}", n,
                        "must be an even count >= 2: half the trials show the test first",
                    )  # fmt: skip
            block_tests = spec.pop("tests", None)
            block_tests = tests if block_tests is None else self.intensities(block_tests, path)
            feedback = spec.pop("feedback", False)
            if not isinstance(feedback, bool):
                raise self.fail(path + "feedback", feedback, "must be true or false")
            intro = self.text(spec, "intro", path) if "intro" in spec else None
            self.done(spec, path)
            out.append(Block(name, dict(repeats), block_tests, feedback, intro))
        return tuple(out)


_TEXTS = tuple(f.name for f in fields(Texts))
