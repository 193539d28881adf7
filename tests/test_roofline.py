"""`gazehdr bench --roofline`: the per-launch accounting follows the backend's own buffers, and
the table has a line per stage of the live step (no timing asserts)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gazehdr.bench import roofline
from gazehdr.bench.pipeline import main
from gazehdr.scenes import open_scene
from gazehdr.sim import Simulator

W, H = 96, 54


def _live_step_launches(new_scene: bool = False):
    """A live step's launches on a scene that stays (acuity from the level stack), or with
    `new_scene` on a scene just changed (acuity in the tiled bank)."""
    sim = Simulator(W, H, backend="opencl", seed=0)
    sim.start(open_scene("lamp").render(0.0, W, H), (W / 2, H / 2))
    b = sim._backend
    sim.step(1 / 60)
    while b.level_stack_pending:  # a scene that stays moves to its level stack
        sim.step(1 / 60)
    if new_scene:
        b.put("scene", b.get("scene"))
    rec = roofline.Recorder(b)
    gaze = (30.0, 20.0)
    for stage, fn in (
        ("adapt", lambda: b.adapt(gaze, 1 / 60, False)),
        ("retina", lambda: sim._afterimage.retina(gaze, 1 / 60, False)),
        ("acuity", lambda: b.acuity(sim._noise.at(0.1))),
        ("compose", lambda: b.compose(gaze, 1.0)),
    ):
        rec.stage = stage
        fn()
    b.queue.finish()
    rec.restore()
    return sim, b, gaze, rec.launches


def test_bytes_are_the_buffers_each_stage_reads_and_writes() -> None:
    sim, b, gaze, launches = _live_step_launches()
    lay, buf = sim.layout, b.buf
    full = W * H
    d = b.get("d")
    costs = roofline.account(launches, lay, sim.params, d)
    assert [ln.stage for ln in launches][-1] == "compose"
    # the acuity stage: acuity_levels reads rho_full and the noise, writes d; acuity_pick
    # reads d and, for each run of VEC pixels, every level from its lowest d to its highest
    # (the row's last pixels one each), and writes G
    picked = [ln.name for ln in launches if ln.stage == "acuity"]
    assert picked == ["acuity_levels", "acuity_pick"]
    kept = float(np.mean(d == 0))
    assert 0 < kept < 1, "the lamp scene should drop bands at some pixels, not all"
    expect = buf["rho_full"].size + b._noise_buf.size + 2 * buf["d"].size + b.P.size
    read = 0  # pixels' worth of levels read, run by run
    for row in d.astype(int):
        for x in range(0, W, b.vec):
            run = row[x : x + b.vec]
            read += (run.max() - run.min() + 1) * b.vec if len(run) == b.vec else len(run)
    assert read > full  # some runs span levels
    expect += 2 * 3 * read + buf["G"].size  # the levels read (16-bit, 3 channels), G written
    assert costs["acuity"].bytes == pytest.approx(expect)
    assert buf["G"].size == 3 * 2 * full and buf["d"].size == full  # 16 bits a channel
    # compose: G, rho at every pixel, the maps of the cells the screen shows, A, the fovea
    # factors, and the frame it writes
    cells = roofline._cells(b._screen_window(gaze))
    maps = buf["maps"].size * cells / (lay.grid_w * lay.grid_h)
    expect = b.P.size + buf["G"].size + buf["rho_full"].size + maps + buf["A"].size
    expect += buf["fovea"].size + buf["v"].size
    assert costs["compose"].bytes == pytest.approx(expect)
    # retina: the state is read and its blurred copy written through grid_a, both whole
    assert costs["retina"].bytes > 2 * (buf["state"].size + buf["grid_a"].size)
    assert costs["retina"].kernels == ["retina_update", "retina_blur", "afterimage_maps"]
    for c in costs.values():
        assert c.bytes > 0 and c.flops > 0


def test_the_bank_reads_the_scene_and_d_and_writes_g() -> None:
    sim, b, _, launches = _live_step_launches(new_scene=True)
    buf = b.buf
    costs = roofline.account(launches, sim.layout, sim.params, b.get("d"))
    assert [ln.name for ln in launches if ln.stage == "acuity"] == ["acuity_levels", "acuity_bank"]
    # plus the bank's small constant buffers
    bank = b._bank
    consts = b.P.size + bank["taps"].size + bank["levels"].size
    expect = buf["rho_full"].size + b._noise_buf.size + 2 * buf["d"].size + consts
    expect += buf["scene"].size + buf["G"].size
    assert costs["acuity"].bytes == pytest.approx(expect)


def test_flops_follow_the_launch_and_unknown_kernels_are_refused() -> None:
    sim, _, _, launches = _live_step_launches(new_scene=True)
    bank = next(ln for ln in launches if ln.name == "acuity_bank")
    lay, p = sim.layout, sim.params
    none = roofline.launch_cost(
        bank.name, bank.gsize, bank.args, lay, p, np.zeros((H, W), np.uint8)
    )
    every = roofline.launch_cost(bank.name, bank.gsize, bank.args, lay, p, None)
    assert none.flops == 0 < every.flops  # no level dropped: the bank only copies
    assert none.bytes == every.bytes
    blur = next(ln for ln in launches if ln.name == "retina_blur")
    wide = list(blur.args)
    wide[3] = np.int32(int(blur.args[3]) + 2)  # a wider map blur costs more arithmetic
    assert (
        roofline.launch_cost(blur.name, blur.gsize, tuple(wide), lay, p).flops
        > roofline.launch_cost(blur.name, blur.gsize, blur.args, lay, p).flops
    )
    with pytest.raises(KeyError, match="no accounting"):
        roofline.launch_cost("made_up", (8,), (), lay, p)


def test_afterimage_maps_count_the_cells_of_the_window_not_made_yet() -> None:
    """The late gaze's maps (`OpenCLBackend._more_maps`): one launch over the whole grid, the
    cells of a box less those of the window made with the step."""
    sim, b, gaze, _ = _live_step_launches()
    rec = roofline.Recorder(b)
    box, made = (2, 3, 41, 22), (10, 5, 29, 14)
    for inner in ((0, 0, -1, -1), made):
        b._map_cells(gaze, box, inner)
    rec.restore()
    full, rest = (
        roofline.launch_cost(ln.name, ln.gsize, ln.args, sim.layout, sim.params)
        for ln in rec.launches
    )
    assert full.flops == 40 * 20 * roofline.MAPS_FLOPS
    assert rest.flops == (40 * 20 - 20 * 10) * roofline.MAPS_FLOPS


NUM = r"-?\d+(?:\.\d+)?"


def test_bench_roofline_prints_a_line_per_stage(capsys) -> None:
    args = ["--roofline", "--opencl-only", "--frames", "1", "--sizes", f"{W}x{H}"]
    assert main([*args, "--roof-mib", "8"]) == 0
    out = capsys.readouterr().out
    assert re.search(rf"roofs: copy {NUM} GB/s, triad {NUM} GB/s \(8 MiB", out)
    assert re.search(rf"FMA {NUM} GFLOP/s; balance {NUM} flop/B", out)
    rows = {}
    for line in out.splitlines():
        m = re.match(rf"  (\w[\w ]*?)\s+((?:{NUM}\s+){{11}})\s*(memory|compute) \(roof", line)
        if m:
            rows[m.group(1)] = [float(v) for v in m.group(2).split()]
    assert list(rows) == ["prepare", "adapt", "retina", "acuity", "compose", "live step"]
    live = rows.pop("live step")
    rows.pop("prepare")  # not part of a live step (the scene maps are kept)
    assert live[2] == pytest.approx(sum(r[2] for r in rows.values()), abs=0.02)  # MB
    assert live[3] == pytest.approx(live[2] * 1e6 / (W * H), rel=0.01)  # bytes per pixel
    assert "OpenCL ms" in out  # the stage table is still there
    assert f"{W}x{H}  scene=lamp  roofline, rgb10a2 out" in out  # what the live path composes


def test_roofline_refuses_models() -> None:
    with pytest.raises(SystemExit):
        main(["--roofline", "--models", "all"])


def test_a_launch_the_timer_reads_as_zero_counts_one_nanosecond() -> None:
    """Rates divide by launch times; a coarse device timer can give a short kernel start == end."""
    from types import SimpleNamespace

    from gazehdr.bench.roofline import _event_s

    assert _event_s(SimpleNamespace(profile=SimpleNamespace(start=7, end=7))) == 1e-9
    assert _event_s(SimpleNamespace(profile=SimpleNamespace(start=0, end=2500))) == 2.5e-6


def test_the_pick_reads_every_level_a_run_spans() -> None:
    """Runs of 2: [0, 2] reads levels 0..2 (3 levels, 2 pixels each), [1, 1] one; the row's
    last pixel its own level."""
    d = np.array([[0, 2, 1, 1, 3], [0, 0, 0, 0, 0]], np.uint8)
    assert roofline._pick_levels_read(d, 2) == (3 * 2 + 1 * 2 + 1) + (2 + 2 + 1)
