"""A viewing session recorded as a session log, and that log rendered offline to its frames.

`Session` journals what it ran with and every change (server/session.py), `gazehdr serve
--record` writes the journal as it runs (server/live.py), and `gazehdr render --gaze LOG`
applies the log's changes where the live session made them (server/render.py).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from sessions import new_session, tick

from gazehdr.cli import main
from gazehdr.drivers.sessionlog import (
    EyeReset,
    GazeEvent,
    ModelChange,
    Note,
    ParamsChange,
    SceneChange,
    SessionLogWriter,
    read_session_log,
)
from gazehdr.protocol import (
    Choose,
    Encoding,
    Eyes,
    Gaze,
    ModelPick,
    ParamChange,
    Reset,
    decode_frame,
)
from gazehdr.protocol import ModelChange as ModelControl
from gazehdr.render import recorded_changes, render
from gazehdr.scenes.library import SceneLibrary
from gazehdr.scenes.procedural import Flash
from gazehdr.session import Session, SessionSettings
from tests.test_server import Client, http, run
from tests.waiting import wait_until

W, H, FPS = 64, 36, 30
SETTINGS = SessionSettings(
    width=W, height=H, fps=FPS, scene="lamp", seed=5, backend="reference",
    encoding=Encoding.f16, fit_viewport=False, record=True,
)  # fmt: skip
#: (tick, control): a session at exactly 1/FPS per tick, its first frame at the centre.
SCRIPT = [
    (2, Gaze(0.3, 0.4, 1)),
    (6, Gaze(0.7, 0.6, 2)),
    (8, Reset()),  # the afterimage of the first place goes
    (10, Eyes(False)),
    (12, Eyes(True)),
    (14, ParamChange({"gamma": 0.5})),
    (16, ModelControl(ModelPick("ritschel"))),
    (18, Choose("scene", "checker-night")),
    (20, Gaze(0.5, 0.5, 3)),
]
TICKS = 23


def play(session: Session, writer: SessionLogWriter | None = None) -> list[np.ndarray]:
    """Tick through SCRIPT; the frames as H×W×3 float32 `v`, the journal into `writer`."""
    frames = []
    for i in range(TICKS):
        controls = [(c, 0.0) for at, c in SCRIPT if at == i]
        frame, notes = tick(session, 0.0 if i == 0 else 1 / FPS, controls)
        assert [n for n in notes if n["type"] == "error"] == []
        frames.append(decode_frame(frame.header.pack() + frame.payload)[1])
        if writer is not None:
            writer.write_all(session.take_journal())
    if writer is not None:
        writer.write_all(session.end_journal())
    return frames


def ns(tick: int) -> int:
    """The journal time of a control sent with tick `tick`: the end of that tick's step."""
    return round(tick / FPS * 1e9)


def test_the_journal_holds_what_the_session_ran_with_and_every_change() -> None:
    session = new_session(SETTINGS, "rec")
    play(session)
    journal = session.take_journal()
    assert session.take_journal() == []  # taken once
    changes = [r for r in journal if not isinstance(r, GazeEvent) and not hasattr(r, "valid")]
    assert changes == [
        SceneChange(0, "lamp"),
        ModelChange(0, "jacobs+stochastic", None),
        ParamsChange(0, {"tracker_accuracy_deg": 0.0}),  # the pointer's figures: exact
        Note(0, "gaze source mouse"),
        EyeReset(ns(8)),
        ParamsChange(ns(14), {"gamma": 0.5}),
        ModelChange(ns(16), "ritschel+stochastic", None),
        SceneChange(ns(18), "checker-night"),
    ]
    screen = session.log_screen
    assert (screen.screen_width_px, screen.screen_height_px) == (1920, 1080)
    events = [e for e in journal if isinstance(e, GazeEvent)]
    fixations = [(e.t_ns, e.x, e.y) for e in events if e.kind == "fixation_start"]
    assert fixations == [
        (0, 960.0, 540.0),
        (ns(2), pytest.approx(0.3 * 1920), pytest.approx(0.4 * 1080)),
        (ns(6), pytest.approx(0.7 * 1920), pytest.approx(0.6 * 1080)),
        (ns(20), 960.0, 540.0),
    ]
    samples = [(r.t_ns, r.x, r.y) for r in journal if hasattr(r, "valid")]
    assert samples == fixations  # one sample per position followed
    blinks = [(e.kind, e.id, e.t_ns) for e in events if e.kind.startswith("blink")]
    assert blinks == [("blink_start", 1, ns(10)), ("blink_end", 1, ns(12))]
    # At its end the session says how long the last gaze was held.
    end = session.end_journal()
    assert [(r.t_ns, r.x, r.y) for r in end[:1]] == [(ns(TICKS - 1), 960.0, 540.0)]
    assert end[1:] == [Note(ns(TICKS - 1), "session ended")]
    header = session.log_header()
    assert header.clock.source == "simulation_ns" and header.tracker["seed"] == 5


def test_a_session_that_does_not_record_keeps_no_journal() -> None:
    settings = SessionSettings(**{**vars(SETTINGS), "record": False})
    session = new_session(settings, "rec")
    tick(session, 0.0, [(Gaze(0.2, 0.2, 1), 0.0)])
    assert not session.recording and session.take_journal() == []


def test_split_view_journals_the_gaze_on_the_scene() -> None:
    """Either pane under the pointer looks at the same point of the scene: that point is what
    the log holds, so a one-pane replay looks where the session did."""
    settings = SessionSettings(**{**vars(SETTINGS), "width": 96, "split": SETTINGS.model})
    session = new_session(settings, "rec")
    tick(session, 0.0, [(Gaze(0.25, 0.5, 1), 0.0)])  # left pane, a quarter of the frame
    tick(session, 0.1, [(Gaze(0.75, 0.5, 2), 0.0)])  # the same point in the right pane
    tick(session, 0.1, [(Gaze(0.5, 0.25, 3), 0.0)])  # the right pane's left edge
    starts = [
        (e.x, e.y) for e in session.take_journal() if getattr(e, "kind", "") == "fixation_start"
    ]
    assert starts == [(960.0, 540.0), (0.0, 270.0)]


def write_recording(path: Path) -> list[np.ndarray]:
    """Play SCRIPT in a recording session, its journal written as `serve --record` does."""
    session = new_session(SETTINGS, "rec")
    with SessionLogWriter(path, session.log_header()) as writer:
        return play(session, writer)


def exr_frames(out: Path) -> list[np.ndarray]:
    files = sorted(out.glob("frame_*.exr"))
    return [OpenEXR.File(str(f)).channels()["RGB"].pixels for f in files]


def test_a_recorded_session_renders_offline_to_the_frames_it_showed(tmp_path: Path) -> None:
    """The same steps with the same gaze, eyes, scene, parameters, models and resets: the
    render's float32 frames, rounded to float16 as the session's were, equal them within one
    float16 step of 1.0 (2^-10: the two may differ in the last bit of a float32 before it)."""
    log_path = tmp_path / "session.jsonl"
    live = write_recording(log_path)
    log = read_session_log(log_path)
    track = log.fixation_track()
    changes = recorded_changes(log, track.t0_ns, SceneLibrary())
    render(
        SceneLibrary().open("lamp"), track, seconds=TICKS / FPS, fps=FPS, width=W, height=H,
        seed=5, backend="reference", out_dir=tmp_path / "out", exr=True, progress=False,
        changes=changes,
    )  # fmt: skip
    offline = exr_frames(tmp_path / "out")
    assert len(offline) == len(live) == TICKS
    worst = [
        float(np.abs(a.astype(np.float16) - b).max()) for a, b in zip(offline, live, strict=True)
    ]
    assert max(worst) <= 2**-10, worst
    # and it is not trivially so: each recorded change stands out (10x) from the ticks around it
    steps = [float(np.abs(b - a).mean()) for a, b in itertools.pairwise(live)]
    for n in (8, 10, 12, 14, 16, 18):
        assert steps[n - 1] > 10 * max(steps[n - 2], steps[n]), (n, steps)
    # Without the log's changes the same gaze gives other frames from tick 8 on.
    render(
        SceneLibrary().open("lamp"), track, seconds=TICKS / FPS, fps=FPS, width=W, height=H,
        seed=5, backend="reference", out_dir=tmp_path / "plain", exr=True, progress=False,
    )  # fmt: skip
    plain = exr_frames(tmp_path / "plain")
    assert all(np.array_equal(a, b) for a, b in zip(plain[:8], offline[:8], strict=True))
    assert not np.allclose(plain[8], offline[8], atol=1e-3)


def test_a_flash_between_two_frames_renders_offline_as_it_was_seen_live(tmp_path: Path) -> None:
    """Live and offline rendering step the same way (gazehdr.eye): a flash that starts and ends
    between two frames is seen for exactly its 20 ms by both, and leaves the same afterimage."""
    brief = Flash(first=0.51, duration=0.02, period=10.0)  # between ticks 15 and 16
    scenes = SceneLibrary(None, {"brief": brief})
    session = Session(
        "rec", dataclasses.replace(SETTINGS, scene="brief"), scenes, clock=time.perf_counter
    )
    log_path = tmp_path / "flash.jsonl"
    with SessionLogWriter(log_path, session.log_header()) as writer:
        live = []
        for i in range(TICKS):
            frame, _ = tick(session, 0.0 if i == 0 else 1 / FPS, [])
            live.append(decode_frame(frame.header.pack() + frame.payload)[1])
            writer.write_all(session.take_journal())
        writer.write_all(session.end_journal())
    log = read_session_log(log_path)
    track = log.fixation_track()
    render(
        brief, track, seconds=TICKS / FPS, fps=FPS, width=W, height=H, seed=5,
        backend="reference", out_dir=tmp_path / "out", exr=True, progress=False,
        changes=recorded_changes(log, track.t0_ns, scenes),
    )  # fmt: skip
    offline = exr_frames(tmp_path / "out")
    worst = [
        float(np.abs(a.astype(np.float16) - b).max()) for a, b in zip(offline, live, strict=True)
    ]
    assert max(worst) <= 2**-10, worst
    # The flash was seen: the frame after it differs from the one before far more than the
    # frames around it do.
    steps = [float(np.abs(b - a).mean()) for a, b in itertools.pairwise(live)]
    assert steps[15] > 10 * max(steps[13], steps[14]), steps


def test_cli_render_takes_the_scene_seed_and_length_from_the_log(tmp_path: Path) -> None:
    log_path = tmp_path / "session.jsonl"
    live = write_recording(log_path)
    args = ["render", "--gaze", str(log_path), "--size", f"{W}x{H}", "--backend", "reference",
            "--exr", "--quiet"]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "cli")]) == 0
    frames = exr_frames(tmp_path / "cli")
    # The log spans the session, to its end (the last tick), so the render has every frame.
    assert len(frames) == TICKS
    for a, b in zip(frames, live, strict=True):
        assert np.abs(a.astype(np.float16) - b).max() <= 2**-10
    # A model named on the command line replaces the log's: from tick 16 the frames differ.
    assert main([*args, "--afterimage", "jacobs", "--out", str(tmp_path / "jacobs")]) == 0
    jacobs = exr_frames(tmp_path / "jacobs")
    assert all(np.array_equal(a, b) for a, b in zip(jacobs[:16], frames[:16], strict=True))
    assert not np.allclose(jacobs[16], frames[16], atol=1e-3)


def test_cli_render_of_a_log_that_names_no_scene_or_a_missing_one(tmp_path: Path, capsys) -> None:
    log_path = tmp_path / "session.jsonl"
    write_recording(log_path)
    lines = log_path.read_text(encoding="utf-8").splitlines()
    missing = tmp_path / "missing.jsonl"
    missing.write_text("\n".join(s.replace('"checker-night"', '"my-upload"') for s in lines) + "\n")
    out = ["--out", str(tmp_path / "x"), "--quiet"]
    assert main(["render", "--gaze", str(missing), "--data-dir", str(tmp_path), *out]) == 2
    assert "no scene named 'my-upload'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before anything was written
    assert main(["render", "--gaze", str(log_path), "--fps", "0", *out]) == 2
    assert "fps must be a finite positive number, got 0.0" in capsys.readouterr().err
    no_scene = tmp_path / "daemon.jsonl"
    no_scene.write_text("\n".join(s for s in lines if '"k":"scene"' not in s) + "\n")
    assert main(["render", "--gaze", str(no_scene), *out]) == 2
    assert "SCENE is needed" in capsys.readouterr().err


def test_serve_records_each_session_where_viewers_can_replay_it(live_server) -> None:
    """A real server with --record: the viewer's pointer and scene choice are in the log as it
    runs, and the log is at once a recording the next session can replay."""
    server = live_server(record=True, scene="lamp")
    folder = server.config.data_dir / "recordings"

    async def record() -> None:
        client = await Client.open(server)
        await client.send(type="gaze", x=0.2, y=0.3, seq=1)
        await client.frame(lambda h: h.gaze_seq == 1)
        await client.send(type="scene", name="checker-night")
        assert (await client.note("state"))["scene"] == "checker-night"
        await client.frame()
        await client.ws.close()

    run(record())
    wait_until(lambda: not server.hub.sessions, "the session to end as its viewer left")
    (path,) = folder.glob("session-*.jsonl")
    log = read_session_log(path)
    assert log.header.tracker["name"] == "gazehdr serve"
    assert [s.name for s in log.scenes] == ["lamp", "checker-night"]
    assert (0.2 * 1920, 0.3 * 1080) in [(e.x, e.y) for e in log.events]
    # the session has ended (its viewer left): the pointer's place was held to the end
    assert log.notes[-1].text == "session ended"
    assert (log.samples[-1].x, log.samples[-1].y) == (0.2 * 1920, 0.3 * 1080)
    assert log.samples[-1].t_ns >= log.scenes[-1].t_ns
    name = path.stem
    assert name in http("GET", server.url + "/api/recordings", **server.auth)[1]["recordings"]

    async def replay() -> None:
        client = await Client.open(server)
        await client.send(type="gaze_source", name=f"replay:{name}")
        assert (await client.note("state"))["gaze_source"] == f"replay:{name}"
        header, _ = await client.frame(lambda h: h.tracker and abs(h.gaze_x - 0.2) < 1e-6)
        assert header.gaze_y == pytest.approx(0.3)
        await client.ws.close()

    run(replay())


def test_serve_refuses_to_record_without_a_data_directory() -> None:
    from gazehdr.app import ServerConfig, create_app

    config = ServerConfig(session=SessionSettings(record=True), data_dir=None)
    with pytest.raises(ValueError, match="recording sessions needs a data directory"):
        create_app(config)


def test_a_log_that_cannot_be_written_stops_recording_not_the_session(
    tmp_path: Path, monkeypatch
) -> None:
    from gazehdr.live import LiveSession
    from gazehdr.metrics import Metrics

    session = new_session(SETTINGS, "rec")
    writer = SessionLogWriter(tmp_path / "s.jsonl", session.log_header())
    live = LiveSession(session, Metrics(), writer)

    def refuse(records) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer, "write_all", refuse)  # the disk fills up
    frame, notes = live._tick(0.0, [])
    assert frame.payload and live.log is None
    assert notes == [{"type": "error", "message": "recording stopped: [Errno 28] No space left "
                      "on device", "in": None}]  # fmt: skip
    live.submit(Gaze(0.1, 0.1, 1))
    frame, notes = live._tick(1 / FPS, [])
    assert frame.header.gaze_seq == 1 and notes == []
    assert read_session_log(tmp_path / "s.jsonl").header.tracker["session"] == "rec"


def test_journal_lines_are_the_documented_format(tmp_path: Path) -> None:
    path = tmp_path / "session.jsonl"
    write_recording(path)
    kinds = [json.loads(line)["k"] for line in path.read_text(encoding="utf-8").splitlines()[1:]]
    assert kinds[:6] == ["scene", "model", "params", "note", "s", "fixation_start"]
    assert {"params", "reset", "blink_start", "blink_end"} <= set(kinds)
