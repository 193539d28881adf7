"""The command line tells a refusal from a bug (drivers/errors.py): what gazehdr refuses on
purpose is one line and status 2; anything else is the bug it is, with its traceback, a line
saying how to report it, and status 3. Each test names the mutation it guards."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gazehdr import cli
from gazehdr.drivers.errors import GazehdrError, InputError


def _broken(args, extra) -> int:
    np.zeros(2) + np.zeros(3)  # a NumPy broadcast error: a bug, though a ValueError
    return 0


def test_an_unexpected_error_is_shown_as_the_bug_it_is(monkeypatch, capsys) -> None:
    """A ValueError no code of ours meant, inside a subcommand: a traceback and how to report
    it, status 3, never `gazehdr: error: ...` with the usage error's status. Guards the old
    rule (every ValueError printed as a one-line usage error: users reported bugs as their own
    mistakes)."""
    broken = dataclasses.replace(cli.COMMANDS["scenes"], run=_broken)
    monkeypatch.setitem(cli.COMMANDS, "scenes", broken)
    status = cli.main(["scenes"])
    err = capsys.readouterr().err
    assert status == cli.BUG_STATUS != 2
    assert "Traceback" in err and "operands could not be broadcast" in err
    assert "gazehdr: error:" not in err and "report it" in err


def test_a_refusal_is_one_line_and_status_2(tmp_path: Path, capsys) -> None:
    """A deliberate refusal (a scene file that does not exist, a parameter out of its bound)
    is one line naming what is wrong, status 2, no traceback. Guards refusals raised as plain
    ValueErrors (they would now show as bugs)."""
    out = str(tmp_path / "out")
    assert cli.main(["render", "nowhere.exr", "--out", out, "--seconds", "0.1"]) == 2
    params = tmp_path / "p.json"
    params.write_text('{"sigma_0": 1e9}')
    assert cli.main(["render", "flash", "--params", str(params), "--out", out]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("gazehdr: error:") == 2
    assert "sigma_0" in err


def test_every_deliberate_error_is_a_gazehdr_error() -> None:
    """The exception classes gazehdr raises on purpose derive from GazehdrError (input errors
    from InputError, also ValueErrors). Guards a new refusal class outside the hierarchy."""
    from gazehdr.drivers.formats import FormatError
    from gazehdr.drivers.hid.descriptor import DescriptorError, ReportError
    from gazehdr.drivers.wire import WireError
    from gazehdr.experiment.design import DesignError
    from gazehdr.protocol import ProtocolError
    from gazehdr.scenes.decoding import SceneError
    from gazehdr.security import SecretError

    for kind in (FormatError, DescriptorError, ReportError, WireError, DesignError,
                 ProtocolError, SceneError, SecretError):  # fmt: skip
        assert issubclass(kind, InputError) and issubclass(kind, ValueError), kind
    assert issubclass(cli.UsageError, GazehdrError)
    with pytest.raises(ValueError):  # callers' `except ValueError` keep working
        raise SceneError("x")
