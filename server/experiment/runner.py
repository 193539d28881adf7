"""A run of an experiment: the trial state machine the browser page and the headless path share.

`ExperimentRun.present()` renders the current trial's two intervals (clips, `stimulus`) on the
run's simulation clock, `respond(key, ...)` records the answer and moves on; `finish()` writes
the BIDS results. Each step is written to the run's session log as it happens (a crash keeps
what was answered). `run_headless` answers with a simulated observer through the same calls:
the model observer (`observer.ModelObserver`) judges the frames each interval shows, the echo
observer (`observer.EchoObserver`) answers from a PSE it is given.

Trials are pre-rendered, not stepped live in a viewer's session: the paper showed the same
pre-made videos to every observer with the gaze on a fixation target (Sec. 4.1.1), nothing in a
trial depends on the viewer while it runs, and a pre-rendered 50 ms flash is shown for exactly
its frames however long a step takes to compute (a live step at 720p takes ~18 ms on a GPU,
far more on a CPU). A tracker's gaze, when one is connected, is recorded, not followed.
"""

from __future__ import annotations

import json
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazehdr.drivers import sessionlog
from gazehdr.drivers.errors import InputError
from gazehdr.drivers.formats.bids.files import LABEL, file_stem
from gazehdr.drivers.samples import GazeSample, ScreenGeometry
from gazehdr.experiment.bids import refuse_existing, start_dataset, write_results
from gazehdr.experiment.brightness import Interval
from gazehdr.experiment.design import Design, load_design
from gazehdr.experiment.observer import Observer
from gazehdr.experiment.schedule import Trial, excluded, schedule, training_score
from gazehdr.experiment.stimulus import Clip, clip
from gazehdr.sim import Params


class RunError(InputError):
    """A call out of order (an answer to a trial not shown, a run already finished)."""


@dataclass(frozen=True)
class Presented:
    """A trial as shown: its two clips at their intensities, from `onset` on the run clock."""

    trial: Trial
    clips: tuple[Clip, ...]
    onset: float

    def durations(self) -> tuple[float, float]:
        """(flash, black) measured from the frames of interval 1 (both intervals are alike)."""
        m = self.clips[0].measured()
        return m["on"], m["off"]

    def end(self) -> float:
        return self.onset + sum(c.end for c in self.clips)

    def timeline(self) -> list[tuple[float, int, str]]:
        """(run time, interval, phase) of every frame, in order."""
        out, start = [], self.onset
        for interval, c in enumerate(self.clips, 1):
            out += [(start + float(t), interval, p) for t, p in zip(c.times, c.phases, strict=True)]
            start += c.end
        return out

    def shown(self) -> list[tuple[Clip, float, Clip]]:
        """(clip, intensity, the clip whose rendering `mean` scaling matches) per interval: the
        standard's (interval 3 - test_interval)."""
        standard = self.clips[-1 if len(self.clips) == 1 else 2 - self.trial.test_interval]
        return [(c, i, standard) for c, i in zip(self.clips, self.trial.intensities, strict=True)]

    def intervals(self, design: Design) -> Iterator[Interval]:
        """Each interval as the page shows it: float16 `v` for the design's monitor."""
        for c, intensity, like in self.shown():
            yield Interval(c.shown(intensity, design, like=like), c.times, c.end, design.display)

    def frames(self, design: Design) -> Iterator[tuple[float, int, str, np.ndarray]]:
        """`timeline()` with each frame's float16 `v`, made an interval at a time."""
        times = iter(self.timeline())
        for c, intensity, like in self.shown():
            for v in c.shown(intensity, design, like=like):
                yield (*next(times), v)


@dataclass(frozen=True)
class Outcome:
    correct: bool | None
    feedback: str | None  # what the page says after the answer (feedback blocks only)
    finished: bool
    excluded: bool


class ExperimentRun:
    """One observer's run of `design`; results go to the BIDS dataset at `out_dir`."""

    def __init__(
        self,
        design: Design,
        observer_id: str,
        out_dir: str | Path,
        *,
        seed: int,
        size: tuple[int, int] | None = None,
        backend: str = "opencl",
        run: int | None = None,
        source: str = "browser",
    ) -> None:
        if not LABEL.fullmatch(observer_id):
            raise InputError(f"observer id {observer_id!r}: letters and digits only (BIDS sub-)")
        self.design, self.observer_id, self.seed = design, observer_id, int(seed)
        self.out_dir, self.backend, self.run = Path(out_dir), backend, run
        self.size = tuple(size or design.size)
        self.trials = schedule(design, self.seed)
        self.index = 0
        self.clock = 0.0  # the run's simulation clock, s
        self.rows: list[dict[str, Any]] = []
        self.scored: list[tuple[Trial, bool | None]] = []
        self.presented: Presented | None = None
        self.excluded = False
        self.finished = False
        self.result: Path | None = None
        entities = {"sub": observer_id, "task": design.name}
        if run is not None:
            entities["run"] = str(run)
        self.stem = file_stem(entities, "beh")
        start_dataset(self.out_dir, design)
        refuse_existing(self.out_dir, observer_id, self.stem)
        log_dir = self.out_dir / "sourcedata" / f"sub-{observer_id}"
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log = sessionlog.SessionLogWriter(
            log_dir / f"{file_stem(entities, 'sessionlog')}.jsonl", self._header(source)
        )
        self._note("run", design=design.name, source=design.source, seed=self.seed,
                   trials=len(self.trials), size=list(self.size), backend=backend)  # fmt: skip

    def _header(self, source: str) -> sessionlog.SessionHeader:
        g = Params().geometry
        screen = ScreenGeometry(
            g.screen_diagonal_m, g.screen_width_px, g.screen_height_px, g.viewing_distance_m
        )
        tracker = {
            "name": "gazehdr experiment", "observer": self.observer_id, "via": source,
            "seed": self.seed, "frame": list(self.size), "backend": self.backend,
        }  # fmt: skip
        return sessionlog.SessionHeader(tracker, screen, sessionlog.ClockInfo("simulation_ns"))

    def _ns(self, t: float) -> int:
        return round(t * 1e9)

    def _note(self, event: str, t: float | None = None, **fields: Any) -> None:
        text = json.dumps({"event": event, **fields}, separators=(",", ":"))
        self.log.note(self._ns(self.clock if t is None else t), text)

    @property
    def current(self) -> Trial | None:
        return None if self.finished or self.index >= len(self.trials) else self.trials[self.index]

    def present(self, tracker_gaze: tuple[float, float] | None = None) -> Presented:
        """Render (or take from the cache) the current trial's intervals, on the run clock;
        `tracker_gaze` (frame fractions), a connected tracker's gaze now, is logged."""
        trial = self.current
        if trial is None:
            raise RunError("the run is finished: no trial to present")
        if self.presented is not None and self.presented.trial == trial:
            return self.presented
        condition = self.design.conditions[trial.condition]
        looks = [condition.test, condition.standard]
        if trial.palette:  # one interval: the flash at the trial's strength
            looks = [self.design.flash_look(condition.test, trial.test)]
        elif trial.test_interval == 2:
            looks.reverse()
        clips = tuple(clip(self.design, look, self.size, self.backend) for look in looks)
        shown = Presented(trial, clips, self.clock)
        self.presented = shown
        w, h = self.design.fixation
        g = Params().geometry
        self.log.write(GazeSample(self._ns(shown.onset), w * g.screen_width_px,
                                  h * g.screen_height_px))  # fmt: skip
        if tracker_gaze is not None:
            self._note("tracker_gaze", shown.onset, x=tracker_gaze[0], y=tracker_gaze[1])
        self._note("trial", shown.onset, trial=trial.number, block=trial.block_name,
                   condition=trial.condition, test=trial.test, standard=trial.standard,
                   test_interval=trial.test_interval)  # fmt: skip
        start = shown.onset
        for interval, c in enumerate(clips, 1):
            for phase in ("on", "off"):
                t = start + float(c.times[c.phases.index(phase)])
                self._note(f"interval {interval} {phase}", t, frame_time=t)
            start += c.end
        self.clock = shown.end()
        self._note("prompt", self.clock, trial=trial.number)
        return shown

    def respond(
        self,
        key: str | None = None,
        response_time: float | None = None,
        trial_number: int | None = None,
        tracker_gaze: tuple[float, float] | None = None,
        frames_late: int | None = None,
        palette: Sequence[str] | None = None,
    ) -> Outcome:
        """The answer to the presented trial: `key` (one of the design's two), or for a palette
        trial the labels of the options picked; `response_time` (s from the prompt, as the page
        measured it) and `frames_late` (frames the page did not have in time): None headless."""
        trial, shown = self.current, self.presented
        if trial is None or shown is None or shown.trial != trial:
            raise RunError("no trial is waiting for an answer; present one first")
        if trial_number is not None and trial_number != trial.number:
            raise RunError(f"trial {trial_number} is not the one waiting ({trial.number})")
        if response_time is not None and not (math.isfinite(response_time) and response_time >= 0):
            raise InputError(f"response_time must be seconds >= 0, got {response_time!r}")
        answer = self._palette_answer(palette) if trial.palette else self._key_answer(trial, key)
        if palette is not None and not trial.palette:
            raise InputError("only a palette trial is answered with palette choices")
        correct = answer.pop("_correct")
        if response_time is not None:
            self.clock += response_time
        flash, black = shown.durations()
        self.rows.append({
            "trial": trial.number, "block": trial.block, "condition": trial.condition,
            "standard_intensity": trial.standard, "test_intensity": trial.test,
            "log_relative_intensity": round(trial.log_relative_intensity, 6),
            "test_interval": trial.test_interval, "correct": correct, "palette_choice": None,
            "response_time": response_time, "onset": shown.onset, "flash_duration": flash,
            "black_duration": black, "frames_late": frames_late, **answer,
        })  # fmt: skip
        if tracker_gaze is not None:
            self._note("tracker_gaze", x=tracker_gaze[0], y=tracker_gaze[1])
        logged = {k: v for k, v in answer.items() if k in ("palette_choice", "chose_test")}
        self._note("response", trial=trial.number, key=key, response_time=response_time,
                   **logged, correct=correct, frames_late=frames_late)  # fmt: skip
        self.scored.append((trial, correct))
        self.index += 1
        self.presented = None
        block_done = self.current is None or self.current.block != trial.block
        if block_done and trial.block_name == self.design.exclusion_block:
            self.excluded = excluded(self.score, self.design.min_correct)
            self._note("training", score=self.score, excluded=self.excluded)
        if self.excluded or self.index >= len(self.trials):
            self.finish()
        texts = self.design.texts
        feedback = None if correct is None or not trial.feedback else (
            texts.right if correct else texts.wrong
        )  # fmt: skip
        return Outcome(correct, feedback, self.finished, self.excluded)

    def _key_answer(self, trial: Trial, key: str | None) -> dict[str, Any]:
        if key not in self.design.keys:
            raise InputError(f"key {key!r} is not an answer; press {' or '.join(self.design.keys)}")
        interval = self.design.keys.index(key) + 1
        correct = trial.correct(interval) if trial.condition == "training" else None
        return {"response_key": key, "chose_test": int(trial.chose_test(interval)),
                "_correct": correct}  # fmt: skip

    def _palette_answer(self, palette: Sequence[str] | None) -> dict[str, Any]:
        labels = [c.label for c in self.design.palette]
        picked = list(palette or [])
        if not picked or len(set(picked)) != len(picked) or not set(picked) <= set(labels):
            raise InputError(
                f"a palette trial is answered with one or more of {', '.join(labels)}, each "
                f"once; got {picked!r}"
            )
        return {
            "palette_choice": ",".join(picked), "standard_intensity": None,
            "log_relative_intensity": None, "test_interval": None, "_correct": None,
        }  # fmt: skip

    @property
    def score(self) -> float | None:
        """Fraction correct in the exclusion block (None without one or before it)."""
        names = [b.name for b in self.design.blocks]
        if self.design.exclusion_block is None:
            return None
        return training_score(self.scored, names.index(self.design.exclusion_block) + 1)

    def finish(self) -> Path:
        """Write the results (also for a run stopped early) and close the log; idempotent."""
        if self.result is not None:
            return self.result
        self.finished = True
        self._note("end", answered=len(self.rows), excluded=self.excluded)
        self.log.close()
        self.result = write_results(
            self.out_dir, self.design, self.observer_id, self.stem, self.rows,
            score=self.score, excluded=self.excluded,
        )  # fmt: skip
        return self.result


_percepts: OrderedDict[tuple[Any, ...], tuple[Any, float]] = OrderedDict()
_percepts_lock = threading.Lock()
_PERCEPTS_KEPT = 256


def percept(observer: Any, design: Design, c: Clip, intensity: float, like: Clip) -> float:
    """`observer.perceive` of clip `c` shown at `intensity` (`mean` scaling matching `like`), made
    from the frames the page gets (`Clip.shown`). A clip at an intensity is shown alike in every
    trial, so each percept is computed once per process and observer model
    (`observer.perception`) and kept; the frames are not."""
    key = (id(c), id(like), float(intensity), design.scale, design.display,
           observer.perception)  # fmt: skip
    with _percepts_lock:
        hit = _percepts.get(key)
    if hit is None:
        frames = c.shown(intensity, design, like=like)
        value = observer.perceive(Interval(frames, c.times, c.end, design.display))
        hit = ((c, like), value)  # the clips held: their ids are not reused meanwhile
        with _percepts_lock:
            _percepts[key] = hit
            while len(_percepts) > _PERCEPTS_KEPT:
                _percepts.popitem(last=False)
    return hit[1]


def percepts(shown: Presented, design: Design, observer: Any) -> tuple[float, ...]:
    """`percept` of each interval of a trial as shown, in the order shown."""
    return tuple(percept(observer, design, c, i, like) for c, i, like in shown.shown())


def run_headless(
    design: Design | str | Path,
    observer: Observer,
    out_dir: str | Path,
    *,
    seed: int = 0,
    size: tuple[int, int] = (96, 54),
    observer_id: str = "sim",
    backend: str = "opencl",
    run: int | None = None,
    palette_chooser: Callable[[Trial, list[str]], Sequence[str]] | None = None,
) -> Path:
    """Run `design` answered by `observer` through the same trial code as the page, without a
    browser; the path of the `_beh.tsv` written under `out_dir` (a BIDS dataset root).
    Each 2AFC trial is answered by `observer.answer(trial, percepts)`, where `percepts()` gives
    `observer.perceive` of each interval's frames as shown (an observer that does not look,
    the echo observer, never calls it, and no frames are made for it). Palette trials
    (Sec. 4.3) are answered by `palette_chooser(trial, labels)`."""
    if not isinstance(design, Design):
        design = load_design(design)
    r = ExperimentRun(design, observer_id, out_dir, seed=seed, size=size, backend=backend,
                      run=run, source="simulated observer")  # fmt: skip
    while r.current is not None:
        shown = r.present()
        trial = shown.trial
        if trial.palette:
            if palette_chooser is None:
                raise InputError("palette trials need a palette_chooser: the observer answers 2AFC")
            r.respond(palette=palette_chooser(trial, [c.label for c in design.palette]))
            continue
        chose = observer.answer(trial, lambda shown=shown: percepts(shown, design, observer))
        interval = trial.test_interval if chose else 3 - trial.test_interval
        r.respond(design.keys[interval - 1])
    return r.finish()
