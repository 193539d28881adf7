"""`python -m gazehdr.bench.ab`: the installed kernels against a changed copy, in one process."""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path

import pyopencl as cl
import pytest

from gazehdr.bench.ab import main

KERNELS = resources.files("gazehdr.sim") / "kernels"


def test_times_both_builds_of_each_kernel(tmp_path: Path, capsys) -> None:
    """A copy that does more work in compose: both builds run, from the files each was given."""
    display = (KERNELS / "sec2_4_display.cl").read_text()
    slower = display.replace(
        "out.r = gammav(P, J.r);",
        "out.r = gammav(P, gammav(P, gammav(P, J.r)));",
    )
    assert slower != display
    (tmp_path / "sec2_4_display.cl").write_text(slower)
    argv = [str(tmp_path), "--kernels", "compose_rgb10,retina_update", "--size", "96x54"]
    assert main([*argv, "--reps", "6"]) == 0
    out = capsys.readouterr().out
    for name in ("compose_rgb10", "retina_update"):
        row = re.search(rf"^{name}\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.M)
        assert row, out
        installed, changed, ratio = map(float, row.groups())
        assert installed > 0 and changed > 0 and ratio > 0


def test_a_copy_that_does_not_build_is_refused_by_the_compiler(tmp_path: Path) -> None:
    (tmp_path / "common.cl").write_text((KERNELS / "common.cl").read_text() + "\nnot C;\n")
    with pytest.raises(cl.RuntimeError, match="BUILD_PROGRAM_FAILURE"):
        main([str(tmp_path), "--kernels", "compose_rgb10", "--size", "96x54", "--reps", "4"])


def test_a_kernel_no_live_step_launches_is_named(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no_such_kernel: not launched by a live step"):
        main([str(tmp_path), "--kernels", "no_such_kernel", "--size", "96x54", "--reps", "4"])
