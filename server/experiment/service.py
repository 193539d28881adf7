"""The experiment's routes on `gazehdr serve` (`serve --experiment` / `gazehdr experiment run`):
the page at /experiment and its API under /api/experiment, which needs the credential for every
call, reads included (`gazehdr.security.PRIVATE_READS`): a run's trials, answers and gaze are
an observer's data, and starting a run or answering changes state.

The page asks for the current trial (JSON: its number, the frames' times and phases), fetches
its frames (binary: the viewer's frame messages, docs/protocol.md, one after another; a frame
equal to the one before is sent once and shown again), plays them, takes the key press with
its time from the prompt, and posts the answer.
"""

from __future__ import annotations

import asyncio
import dataclasses
import io
import logging
import secrets
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, Response, StreamingResponse
from PIL import Image
from pydantic import BaseModel, Field

from gazehdr.dither import dither8
from gazehdr.experiment.design import Design
from gazehdr.experiment.runner import ExperimentRun, RunError
from gazehdr.experiment.stimulus import clip, palette_images, trial_looks
from gazehdr.protocol import Encoding, FrameHeader, payload

log = logging.getLogger("gazehdr.experiment")
PAGE = "experiment.html"
BINARY = "application/octet-stream"
MAX_RUNS = 16  # in progress at once; a finished run is forgotten (its results are written)


@dataclass(frozen=True)
class ExperimentConfig:
    """What `serve` runs: the design, where the results go, the frame size and backend, and
    the seed of each run (None: a new one per run, recorded in its log and announced)."""

    design: Design
    out_dir: Path
    size: tuple[int, int] | None = None
    backend: str = "opencl"
    seed: int | None = None


class StartRun(BaseModel):
    observer: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9]+$")
    run: int | None = Field(default=None, ge=1, le=999)
    consent: bool


class Answer(BaseModel):
    trial: int = Field(ge=1)
    key: str | None = Field(default=None, min_length=1, max_length=16)
    palette: list[str] | None = Field(default=None, min_length=1, max_length=64)
    response_time: float = Field(ge=0, le=3600)
    frames_late: int | None = Field(default=None, ge=0, le=10**6)


class _Runs:
    """The runs of this server, by id, each used under its own lock (rendering is a thread)."""

    def __init__(self) -> None:
        self.runs: dict[str, tuple[ExperimentRun, threading.Lock]] = {}

    def get(self, rid: str) -> tuple[ExperimentRun, threading.Lock]:
        try:
            return self.runs[rid]
        except KeyError:
            raise HTTPException(404, f"no run {rid!r}") from None


def install(app: FastAPI, config: ExperimentConfig, web_dir: Path, trackers: Any) -> None:
    """Add the page and the API to `app` (before its static files are mounted)."""
    design, runs = config.design, _Runs()

    def warm() -> None:
        """Render every clip (and the palette) now, so the first observer does not wait."""
        size = config.size or design.size
        try:
            for look in trial_looks(design):
                clip(design, look, size, config.backend)
            if design.palette:
                palette_png(design.palette[0].label)
        except Exception:  # the trial that needs it will say what is wrong
            log.exception("could not render the experiment's stimuli ahead")

    @app.get("/experiment", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(web_dir / PAGE, media_type="text/html")

    @app.get("/api/experiment")
    async def describe() -> dict[str, Any]:
        t = design.texts
        return {
            "name": design.name, "title": design.title, "keys": list(design.keys),
            "fixation": list(design.fixation), "fps": design.fps,
            "texts": dataclasses.asdict(t),
            "trials": sum(b.trials for b in design.blocks),
            "palette": [c.label for c in design.palette],
        }  # fmt: skip

    pngs: dict[str, bytes] = {}
    lock = threading.Lock()

    def palette_png(label: str) -> bytes:
        with lock:
            if not pngs:
                size = config.size or design.size
                images = palette_images(design, size, config.backend)
                pngs.update(zip((c.label for c in design.palette), map(_png, images), strict=True))
        return pngs[label]

    threading.Thread(target=warm, name="experiment-warm", daemon=True).start()

    @app.get("/api/experiment/palette/{label}.png", response_class=Response,
             responses={200: {"content": {"image/png": {}}}})  # fmt: skip
    async def palette(label: str) -> Response:
        if label not in {c.label for c in design.palette}:
            raise HTTPException(404, f"no palette option {label!r}")
        return Response(await asyncio.to_thread(palette_png, label), media_type="image/png")

    @app.post("/api/experiment/runs", status_code=201)
    async def start(body: StartRun) -> dict[str, Any]:
        if not body.consent:
            raise HTTPException(400, "consent: the observer has not consented")
        for rid in [rid for rid, (run, _) in runs.runs.items() if run.finished]:
            del runs.runs[rid]  # written: nothing more to ask of it
        if len(runs.runs) >= MAX_RUNS:
            raise HTTPException(503, f"{MAX_RUNS} runs are in progress already; finish one first")
        seed = config.seed if config.seed is not None else secrets.randbelow(2**31)
        try:
            run = ExperimentRun(
                design, body.observer, config.out_dir, seed=seed, size=config.size,
                backend=config.backend, run=body.run,
            )  # fmt: skip
        except (ValueError, FileExistsError) as e:
            raise HTTPException(409 if isinstance(e, FileExistsError) else 400, str(e)) from None
        rid = secrets.token_urlsafe(9)
        runs.runs[rid] = (run, threading.Lock())
        return {"run": rid, "seed": seed, "trials": len(run.trials)}

    @app.get("/api/experiment/runs/{rid}")
    async def status(rid: str) -> dict[str, Any]:
        run, _ = runs.get(rid)
        return {
            "observer": run.observer_id, "answered": len(run.rows), "trials": len(run.trials),
            "finished": run.finished, "excluded": run.excluded, "score": run.score,
            "result": None if run.result is None else str(run.result),
        }  # fmt: skip

    def tracker_gaze() -> tuple[float, float] | None:
        """The gaze of the one connected tracker, if exactly one is: recorded, not followed."""
        feed = trackers.sole_connected()
        return None if feed is None else (feed.reading.x, feed.reading.y)

    def presented(rid: str) -> tuple[ExperimentRun, Any]:
        run, lock = runs.get(rid)
        with lock:
            try:
                return run, run.present(tracker_gaze())
            except RunError as e:
                raise HTTPException(409, str(e)) from None

    @app.get("/api/experiment/runs/{rid}/trial")
    async def trial(rid: str) -> dict[str, Any]:
        run, shown = await asyncio.to_thread(presented, rid)
        t = shown.trial
        first = t.number == 1 or run.trials[t.number - 2].block != t.block
        return {
            "intro": design.blocks[t.block - 1].intro if first else None,
            "trial": t.number, "of": len(run.trials), "block": t.block_name,
            "feedback": t.feedback, "end": shown.end(), "palette": t.palette,
            "frames": [list(frame) for frame in shown.timeline()],
        }  # fmt: skip

    @app.get("/api/experiment/runs/{rid}/trial/frames")
    async def trial_frames(rid: str) -> StreamingResponse:
        _, shown = await asyncio.to_thread(presented, rid)
        return StreamingResponse(_frame_messages(shown, design), media_type=BINARY)

    @app.post("/api/experiment/runs/{rid}/response")
    async def respond(rid: str, body: Answer) -> dict[str, Any]:
        run, lock = runs.get(rid)
        gaze = tracker_gaze()

        def answer() -> Any:
            with lock:
                return run.respond(
                    body.key, body.response_time, body.trial, gaze, body.frames_late, body.palette
                )

        try:
            out = await asyncio.to_thread(answer)
        except RunError as e:
            raise HTTPException(409, str(e)) from None
        except ValueError as e:
            raise HTTPException(400, str(e)) from None
        return {
            "correct": out.correct, "feedback": out.feedback, "finished": out.finished,
            "excluded": out.excluded, "score": run.score,
        }  # fmt: skip


def _png(v: np.ndarray) -> bytes:
    """An option's image as an 8-bit PNG, dithered as the renderer dithers (seeded)."""
    out = io.BytesIO()
    Image.fromarray(dither8(v, np.random.default_rng(0))).save(out, format="PNG")
    return out.getvalue()


def _frame_messages(shown: Any, design: Design) -> Iterator[bytes]:
    """The trial's frames as frame messages, each with its run time, as they are made (the
    page starts once it has the first second); a frame identical to the one before is left
    out (the page shows the last one it has until the next one's time)."""
    last = None
    for i, (t, _, _, v) in enumerate(shown.frames(design)):
        data = payload(v)
        if data == last:
            continue
        last = data
        h, w = v.shape[:2]
        header = FrameHeader(
            frame=i, gaze_seq=0, time=t, gaze_x=design.fixation[0], gaze_y=design.fixation[1],
            adaptation=0.0, rho=0.0, width=w, height=h, encoding=Encoding.f16,
        )  # fmt: skip
        yield header.pack() + data
