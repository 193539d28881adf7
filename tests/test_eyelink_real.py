"""The EyeLink importer on real EDF2ASC output (tests/data/formats/eyelink_real, README there):
every sample, fixation and blink EyeLink wrote is imported, no line is left unread; a seeded
fuzz of their lines gives a log or a clear `FormatError`, nothing else; and an imported real
recording replays through `gazehdr daemon` and renders through `gazehdr render`.

The counts a file is checked against are read from the file by the simplest rule that can be:
a sample line begins with a digit, EyeLink's parser wrote one `EFIX` per fixation and one
`EBLINK` per blink (EyeLink 1000 Plus User Manual §4.9); the tables below hold them as well,
so a changed fixture is noticed too.
"""

from __future__ import annotations

import gzip
import math
import os
import random
from collections import Counter
from pathlib import Path

import pytest

from gazehdr.cli import main
from gazehdr.drivers.daemon_cli import daemon_main
from gazehdr.drivers.formats import import_recording
from gazehdr.drivers.formats.eyelink import read_eyelink_asc
from gazehdr.drivers.sessionlog import FormatError, read_session_log, write_session_log

REAL = Path(__file__).parent / "data" / "formats" / "eyelink_real"
MS = 1_000_000
FUZZ_CASES = int(os.environ.get("GAZEHDR_FUZZ_CASES", "240"))  # `GAZEHDR_FUZZ_CASES=20000` soaks

# file: (sample lines, blocks, EFIX, EBLINK, rate Hz, eyes, screen)
FILES = {
    "cili_mono250": (914, 4, 9, 0, 250.0, ["left"], (1024, 768)),
    "cili_bino250": (910, 4, 18, 0, 250.0, ["left", "right"], (1024, 768)),
    "cili_mono2000": (8976, 4, 13, 0, 2000.0, ["right"], (1024, 768)),
    "cili_monoRemote250": (5129, 4, 4, 0, 250.0, ["left"], (1024, 768)),
    "cili_binoRemote250": (5125, 4, 8, 0, 250.0, ["left", "right"], (1024, 768)),
    "syelink_left_eye_excerpt": (1544, 1, 6, 1, 500.0, ["left"], (1280, 1024)),
    "pymovements_binocular": (368, 1, 4, 2, 1000.0, ["left", "right"], (1921, 1081)),
}


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each real file unpacked, as the .asc a user would import."""
    folder = tmp_path_factory.mktemp("eyelink_real")
    paths = {}
    for name in FILES:
        path = folder / f"{name}.asc"
        path.write_bytes(gzip.decompress((REAL / f"{name}.asc.gz").read_bytes()))
        paths[name] = path
    return paths


def _counted(path: Path) -> tuple[int, int, int, int]:
    """(sample lines, valid ones, EFIX lines, EBLINK lines), read off the text alone: a sample
    is valid when some eye has both coordinates (`.` is missing)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    samples = [line.split() for line in lines if line[:1].isdigit()]
    binocular = any(
        line.startswith("SAMPLES") and {"LEFT", "RIGHT"} <= set(line.split()) for line in lines
    )
    eyes = ((1, 2), (4, 5)) if binocular else ((1, 2),)
    valid = sum(any("." not in (s[i], s[j]) for i, j in eyes) for s in samples)
    starts = Counter(line.split()[0] for line in lines if line[:1].isalpha())
    return len(samples), valid, starts["EFIX"], starts["EBLINK"]


@pytest.mark.parametrize("name", FILES)
def test_every_sample_fixation_and_blink_eyelink_recorded_is_imported(
    real: dict[str, Path], name: str
) -> None:
    lines, blocks, efix, eblink, rate, eyes, screen = FILES[name]
    path = real[name]
    sample_lines, valid, efix_lines, eblink_lines = _counted(path)
    assert (sample_lines, efix_lines, eblink_lines) == (lines, efix, eblink)

    log = read_eyelink_asc(path)
    assert [n.text for n in log.notes if " not read: " in n.text] == []
    assert "unread_lines" not in log.header.tracker
    # each block's END adds one invalid sample, so that a replay holds no stale gaze
    assert len(log.samples) == lines + blocks
    assert sum(s.valid for s in log.samples) == valid
    assert all(a.t_ns <= b.t_ns for a, b in zip(log.samples, log.samples[1:], strict=False))
    kinds = Counter(e.kind for e in log.events)
    assert (kinds["fixation_end"], kinds["blink_end"]) == (efix, eblink)
    assert kinds["fixation_start"] >= efix and kinds["blink_start"] == eblink
    fixations = [e for e in log.events if e.kind == "fixation_end"]
    assert all(math.isfinite(e.x) and math.isfinite(e.y) for e in fixations)
    tracker = log.header.tracker
    assert (tracker["rate_hz"], tracker["eyes"], tracker["blocks"]) == (rate, eyes, blocks)
    assert (log.header.screen.screen_width_px, log.header.screen.screen_height_px) == screen
    assert read_eyelink_asc(path, strict=True).samples == log.samples  # nothing left unread


def test_calibration_report_and_validation_of_an_eyelink_1000(real: dict[str, Path]) -> None:
    """cili's mono250: `!CAL` reports continue on `>>>>>>>` and indented lines, one of which
    begins with a number as a sample would; the validation and configuration go to the header."""
    log = read_eyelink_asc(real["cili_mono250"])
    cal = [n for n in log.notes if n.text.startswith("!CAL")]
    assert cal[0].t_ns == 5859496 * MS
    assert cal[0].text == "!CAL\n>>>>>>> CALIBRATION (HV13,P-CR) FOR LEFT: <<<<<<<<<"
    coefficients = next(n.text for n in cal if n.text.startswith("!CAL Cal coeff"))
    assert coefficients.splitlines()[1:] == [
        "   5344.9  187.69 -21.205  0.92517 -0.053489",
        "   30795  130.36  1101.7 -0.44998  13.294",
    ]
    tracker = log.header.tracker
    assert tracker["validations"] == [
        {"eye": "left", "result": "GOOD", "error_avg_deg": 0.38, "error_max_deg": 0.69}
    ]
    assert (tracker["tracking"], tracker["mount"], tracker["pupil"]) == ("CR", "MTABLER", "area")
    assert tracker["model"] == "EYELINK II CL v5.03 Jul  3 2014"
    first = log.samples[0]
    assert (first.t_ns, first.x, first.y) == (5885949 * MS, *_xy(real["cili_mono250"], 0))


def test_2000_hz_without_ftime_and_remote_target_columns(real: dict[str, Path]) -> None:
    """Two rows per time stamp at 2000 Hz, the second 0.5 ms later (§4.9.2); the remote mode's
    target x, y, distance and flags follow the CR flags and do not move the gaze; binocular
    remote files declare HTARGET without writing its columns."""
    log = read_eyelink_asc(real["cili_mono2000"])
    assert [s.t_ns for s in log.samples[:3]] == [8258957 * MS, 8258957 * MS + MS // 2, 8258958 * MS]
    assert (log.samples[1].x, log.samples[1].y) == _xy(real["cili_mono2000"], 1)
    remote = read_eyelink_asc(real["cili_monoRemote250"])
    text = real["cili_monoRemote250"].read_text(encoding="utf-8")
    assert "HTARGET" in text and "\t 4717.0\t 2908.0\t  611.2 ............." in text
    assert (remote.samples[0].x, remote.samples[0].y) == (513.2, 402.0)
    bino = read_eyelink_asc(real["cili_binoRemote250"])
    first = bino.samples[0]
    assert (first.left.x, first.left.y, first.right.x, first.right.y) == (
        507.2,
        377.1,
        506.6,
        402.1,
    )
    assert (first.x, first.y) == pytest.approx(((507.2 + 506.6) / 2, (377.1 + 402.1) / 2))


def test_an_eyelink_1000_plus_recording_and_a_portable_duo_one(real: dict[str, Path]) -> None:
    """syelink's excerpt: a 1000 Plus, its last fixation's SFIX cut (started at its <stime>);
    pymovements' binocular file: one eye lost, then both, and an END stamped before its last
    samples (the end marker still comes after them)."""
    plus = read_eyelink_asc(real["syelink_left_eye_excerpt"])
    assert plus.header.tracker["model"] == "EYELINK II CL v5.50 Jun 16 2022 (EyeLink 1000 Plus)"
    last = [e for e in plus.events if e.kind.startswith("fixation")][-2:]
    assert [(e.kind, e.t_ns) for e in last] == [
        ("fixation_start", 890953 * MS),
        ("fixation_end", 895795 * MS),
    ]
    assert (last[1].x, last[1].y, last[1].duration_ns) == (684.5, 713.5, 4844 * MS)
    duo = read_eyelink_asc(real["pymovements_binocular"])
    by_time = {s.t_ns: s for s in duo.samples}
    one_eye = by_time[1408787 * MS]  # left lost ('.C...'), right 933.4, 568.2
    assert one_eye.valid and (one_eye.x, one_eye.y) == (933.4, 568.2)
    assert math.isnan(one_eye.left.x)
    assert not by_time[1408793 * MS].valid  # both lost
    assert duo.samples[-2].t_ns == 1409027 * MS and not duo.samples[-1].valid
    assert duo.samples[-1].t_ns == 1409027 * MS + 1


def _xy(path: Path, index: int) -> tuple[float, float]:
    """The x, y of the file's `index`-th sample line, as written."""
    lines = path.read_text(encoding="utf-8").splitlines()
    sample = [line for line in lines if line[:1].isdigit()][index].split()
    return float(sample[1]), float(sample[2])


# --- fuzz -------------------------------------------------------------------------------------

JUNK = [
    *("", ".", "..", "-", "x", "nan", "inf", "-1e999", "1e308", "0", "-1", "9" * 40, "1.5.5"),
    *("L", "R", "LEFT", "GAZE", "HREF", "=", "\u0663", "\u00bd", "\u2003", "\x00"),
]
JUNK_LINES = [
    *("", "\t  12  34", ">>>>", "FOO 1 2", "MSG", "EFIX L", "START", "SAMPLES GAZE", "123"),
    *("PRESCALER 0", "END x", "\ufeff**", "MSG 5 DISPLAY_COORDS 0 0 1e308 9"),
]


def _mutate(lines: list[str], rng: random.Random) -> list[str]:
    """1 to 6 edits of real lines: delete, duplicate, truncate, garble or swap fields, insert."""
    lines = list(lines)
    for _ in range(rng.randint(1, 6)):
        i = rng.randrange(len(lines))
        op = rng.randrange(6)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[i])
        elif op == 2:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
        elif op == 3 and (tokens := lines[i].split(sep := rng.choice("\t "))):
            tokens[rng.randrange(len(tokens))] = rng.choice(JUNK)
            lines[i] = sep.join(tokens)
        elif op == 4 and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        else:
            lines.insert(i, rng.choice(JUNK_LINES))
    return lines


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cili_mono250", "pymovements_binocular"])
def test_fuzzed_real_lines_give_a_log_or_a_clear_format_error(
    real: dict[str, Path], tmp_path: Path, name: str
) -> None:
    """Whatever is done to a real file's lines, the reader returns a log the session log format
    holds, or raises `FormatError` naming the file and the line (or, for the two whole-file
    reasons, the missing screen or samples); anything else fails the test. Strict mode refuses
    exactly the files read with lines left unread, and reads the others as the default does."""
    lines = real[name].read_text(encoding="utf-8").splitlines()
    path, out = tmp_path / f"{name}.asc", tmp_path / "log.jsonl"
    outcomes: Counter[str] = Counter()
    for case in range(FUZZ_CASES // 2):
        rng = random.Random(f"{name}:{case}")
        path.write_text("\n".join(_mutate(lines, rng)) + "\n", encoding="utf-8")
        logs = {}
        for strict in (False, True):
            try:
                logs[strict] = read_eyelink_asc(path, strict=strict)
            except FormatError as err:
                assert err.path == str(path) and str(err).startswith(f"{path}:"), (case, err)
                assert err.line is not None or err.field in ("DISPLAY_COORDS", "samples")
                outcomes[f"{'strict' if strict else 'default'} refused"] += 1
        if False in logs and case % 4 == 0:  # writing a log costs more than reading the file
            write_session_log(out, logs[False], overwrite=True)
            assert len(read_session_log(out).samples) == len(logs[False].samples)
        # strict refuses exactly the files the default reads with lines left unread
        unread = False in logs and "unread_lines" in logs[False].header.tracker
        assert (True in logs) == (False in logs and not unread), case
        if True in logs:
            assert logs[True].samples == logs[False].samples, case
            assert logs[True].events == logs[False].events, case
    assert outcomes["default refused"] < FUZZ_CASES // 4  # most mutated files are still read
    assert outcomes["strict refused"] > 0  # and the mutations do break lines


# --- end to end -------------------------------------------------------------------------------


def test_a_real_recording_imports_replays_through_the_daemon_and_renders(
    real: dict[str, Path], tmp_path: Path, live_server, capsys
) -> None:
    """`gazehdr import` then `gazehdr render --gaze` of the log; `gazehdr daemon --source
    replay:FILE.asc@max` sends the server every sample and event the import holds."""
    asc = real["cili_mono250"]
    imported = import_recording(asc)
    log = tmp_path / "mono250.jsonl"
    assert main(["import", str(asc), "--out", str(log)]) == 0
    assert "918 samples (4 invalid), 18 events" in capsys.readouterr().out
    assert read_session_log(log).samples == imported.samples
    frames = tmp_path / "frames"
    tiny = ["--size", "32x18", "--fps", "10", "--seconds", "0.5", "--backend", "reference"]
    assert main(["render", "lamp", "--gaze", str(log), *tiny, "--quiet", "--out", str(frames)]) == 0
    assert len(sorted(frames.glob("frame_*.png"))) == 5

    server = live_server(token="t")
    sent = tmp_path / "sent.jsonl"
    argv = ["--source", f"replay:{asc}@max", "--server", server.ws_url, "--token", "t", "-q"]
    assert daemon_main([*argv, "--record", str(sent)]) == 0
    replayed = read_session_log(sent)
    assert replayed.samples == imported.samples
    assert [(e.kind, e.t_ns) for e in replayed.events] == [
        (e.kind, e.t_ns) for e in imported.events
    ]
