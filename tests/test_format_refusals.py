"""Files that are not what their names claim, through `gazehdr import`: each refused with one
line that says what the file is not and why, not with an error about a part of the format the
file never had."""

from __future__ import annotations

import random
import re

import pytest
from test_formats import DATA

from gazehdr.cli import main as gazehdr_main
from gazehdr.drivers.formats.eyelink import read_eyelink_asc

PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x01\x00\x00\x00\x00\xc0\x08\x02\x00\x00\x00"


def import_error(capsys, path) -> str:
    """`gazehdr import PATH`'s exit status 2 and its one line on stderr."""
    assert gazehdr_main(["import", str(path), "--out", str(path.with_suffix(".jsonl"))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


@pytest.mark.parametrize(
    "content",
    [PNG + bytes(range(256)) * 8, random.Random(12).randbytes(4096)],
    ids=["png", "random bytes"],
)
def test_a_binary_file_named_asc_is_not_text(tmp_path, capsys, content: bytes) -> None:
    path = tmp_path / "rec.asc"
    path.write_bytes(content)
    err = import_error(capsys, path)
    assert err == f"gazehdr: error: {path}: not an EyeLink ASC file: binary, not text\n"


def test_a_tobii_tsv_named_asc_has_none_of_the_asc_lines(tmp_path, capsys) -> None:
    path = tmp_path / "rec.asc"
    path.write_bytes((DATA / "tobii_pygaze.tsv").read_bytes())
    err = import_error(capsys, path)
    assert err.startswith(
        f"gazehdr: error: {path}:1: not an EyeLink ASC file: it has no '**' preamble, MSG, "
        "START or SAMPLES line, and this line is none of what EDF2ASC writes: 'Recording date:"
    )
    assert "sample-only" not in err


def test_an_asc_file_is_still_read_after_lines_of_another_tool(tmp_path) -> None:
    """The refusals need no ASC line at all (in the first 64 KiB, for a binary one): a real file
    with a line of another tool, or a stray NUL, is read, those lines becoming notes."""
    eyelink = (DATA / "eyelink_mono.asc").read_text()
    path = tmp_path / "rec.asc"
    path.write_text("Recording date:\t2024/03/05\n\x00\x01\x02 stray\n" + eyelink)
    log = read_eyelink_asc(path)
    assert log.samples and log.header.tracker["unread_lines"] == 2


def test_an_edf_is_binary_convert_it_with_edf2asc(tmp_path, capsys) -> None:
    path = tmp_path / "rec.edf"
    path.write_bytes(b"SR_RESEARCH_COMPRESSED\x00\x01\x02" + bytes(512))
    err = import_error(capsys, path)
    assert err.startswith(f"gazehdr: error: {path}: an EyeLink EDF file is SR Research's binary")
    assert "edf2asc rec.edf" in err
    # named as ASC on the command line, the content says the same
    out = tmp_path / "o.jsonl"
    assert gazehdr_main(["import", str(path), "--format", "eyelink", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not an EyeLink ASC file: binary, not text" in err and "edf2asc rec.edf" in err


@pytest.mark.parametrize("cut", [30, 225], ids=["file header", "stream header"])
def test_an_xdf_cut_inside_a_header_is_called_truncated(tmp_path, capsys, cut: int) -> None:
    """xdf-modules' example file (tests/data/formats/xdf) cut short inside the XML of its file
    header or of its first stream's header: pyxdf's XML parser stops there."""
    data = (DATA / "xdf" / "minimal.xdf").read_bytes()
    assert data.startswith(b"XDF:") and len(data) > 1000
    path = tmp_path / "cut.xdf"
    path.write_bytes(data[:cut])
    err = import_error(capsys, path)
    assert re.fullmatch(
        f"gazehdr: error: {re.escape(str(path))}: truncated, or malformed XML in its file header "
        r"or a stream header \([a-z ]+: line 1, column \d+\): pyxdf cannot read it\n",
        err,
    ), err
