"""`gazehdr bench` runs, names its device, and its OpenCV side computes what the kernels do."""

from __future__ import annotations

import re

import pytest

from gazehdr.bench.pipeline import main
from gazehdr.sim.models import each_beside_default


def test_bench_prints_stages_ratios_and_agrees(capsys) -> None:
    assert main(["--frames", "1", "--sizes", "96x54", "--scene", "lamp"]) == 0
    out = capsys.readouterr().out
    assert "OpenCL device:" in out
    for stage in ("prepare", "adapt", "retina", "acuity", "compose", "pipeline"):
        row = re.search(rf"^\s+{stage}\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.M)
        assert row, f"no row for {stage}:\n{out}"
        cl_ms, cv_ms, ratio = map(float, row.groups())
        assert cl_ms > 0 and cv_ms > 0
        # the printed figures are rounded to 0.01: the ratio must lie within what they allow
        lo = (cl_ms - 0.005) / (cv_ms + 0.005) - 0.005
        hi = (cl_ms + 0.005) / max(cv_ms - 0.005, 1e-9) + 0.005
        assert lo <= ratio <= hi, (stage, cl_ms, cv_ms, ratio)
    diff = float(re.search(r"mean \|v_OpenCL - v_OpenCV\| = ([\d.e+-]+)", out).group(1))
    assert diff < 0.01  # the same work on both sides (edge sampling differs slightly)
    live_step_is_timed_as_the_server_sends_it(out, "rgb10a2")


def live_step_is_timed_as_the_server_sends_it(out: str, encoding: str) -> None:
    row = re.search(r"live step ([\d.]+) ms \(([\d.]+) fps\): scene maps kept, (\w+) out", out)
    assert row, out
    ms, fps = float(row[1]), float(row[2])  # ms rounded to 0.01: fps within what that allows
    assert 1000 / (ms + 0.005) - 0.1 <= fps <= 1000 / max(ms - 0.005, 1e-9) + 0.1, (ms, fps)
    assert row[3] == encoding


def test_bench_opencl_only_times_the_live_step_in_half_floats(capsys) -> None:
    assert main(["--frames", "1", "--sizes", "64x48", "--opencl-only", "--half"]) == 0
    live_step_is_timed_as_the_server_sends_it(capsys.readouterr().out, "float16")


def test_bench_times_each_model_beside_the_default(capsys) -> None:
    assert main(["--frames", "1", "--sizes", "64x48", "--models", "all"]) == 0
    out = capsys.readouterr().out
    for m in each_beside_default():
        row = re.search(rf"^\s+{re.escape(str(m))}\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.M)
        assert row, f"no row for {m}:\n{out}"
        ms, fps, ratio = map(float, row.groups())
        assert ms > 0 and abs(fps - 1000 / ms) < 0.1 * fps + 0.1
        assert ratio == 1.0 if m == each_beside_default()[0] else ratio > 0
    with pytest.raises(SystemExit):
        main(["--models", "jacobs+sharp"])


def test_bench_live_measures_a_client_in_this_process_and_in_its_own(capsys) -> None:
    """`gazehdr bench-live` with plain WebSocket clients, in the server's process and in one of
    their own, with the late gaze on and off: a row each, with frames delivered and latencies
    (a real server on loopback; 1 s each, so figures only, nothing timed is asserted)."""
    from gazehdr.bench import live as bench_live

    argv = ["--sizes", "96x54", "--encodings", "rgb10a2", "--clients", "socket,process"]
    argv += ["--seconds", "1", "--warmup", "0.5", "--fps", "30", "--late-gaze", "on,off"]
    assert bench_live.main(argv) == 0
    rows = re.findall(
        r"^\s+96x54\s+rgb10a2\s+(\w+)\s+(on|off)\s+([\d.]+)\s+([\d.]+)\s+(\d+)",
        capsys.readouterr().out,
        re.M,
    )
    assert [(c, late) for c, late, _, _, _ in rows] == [
        ("socket", "on"),
        ("socket", "off"),
        ("process", "on"),
        ("process", "off"),
    ]
    for _, _, fps, steps, kib in rows:
        # Frames delivered, the session's steps a second, 96 x 54 x 4 bytes and a header in KiB.
        assert float(fps) > 0 and float(steps) > 0 and int(kib) == 20
    with pytest.raises(SystemExit):
        bench_live.main(["--clients", "socket,telnet"])


def test_first_draw_times_each_new_tab_in_order(capsys) -> None:
    """`python -m gazehdr.bench.first_draw`: a real server and headless Chromium, two new tabs
    one after another; each row's marks come in the page's order (its socket, opened, the hello,
    the first frame, drawn). Nothing timed is asserted."""
    import os

    from gazehdr.bench import first_draw
    from gazehdr.bench.live import CHROMIUM

    pytest.importorskip("playwright")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    assert first_draw.main(["--tabs", "2", "--burn", "0", "--size", "96x54"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines()[2:4]]
    assert len(rows) == 2 and "2 new tabs, 0 CPU burner(s), 96x54" in out
    for row in rows:
        marks = [float(x) for x in row]
        assert marks == sorted(marks) and marks[0] > 0, out
    assert re.search(r"^median first draw \d+ ms$", out, re.M)
