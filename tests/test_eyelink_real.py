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
from types import SimpleNamespace
from typing import Any

import pytest

from gazehdr.cli import main
from gazehdr.drivers.daemon_cli import daemon_main
from gazehdr.drivers.formats import import_recording
from gazehdr.drivers.formats.eyelink import read_eyelink_asc
from gazehdr.drivers.samples import ScreenGeometry
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
        {
            "eye": "left",
            "type": "HV13",
            "result": "GOOD",
            "error_avg_deg": 0.38,
            "error_max_deg": 0.69,
        }
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
    assert "918 samples (4 invalid), 28 events" in capsys.readouterr().out
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


# --- EDF2ASC's options ------------------------------------------------------------------------
#
# SR Research's EDF2ASC cannot run here, so each option's output is derived from a real default
# conversion by the rules its usage text and the manual give (EDF2ASC 3.0's `-h`, EyeLink 1000
# Plus User Manual §4.8 and §4.9; docs/formats.md has the table). The reference is the default
# conversion of the same EDF: import must give the same samples, invalid samples and events, or
# refuse, naming the option to convert with.


def _is_sample(line: str) -> bool:
    return line[:1].isdigit()


def _fields(line: str) -> list[str]:
    return line.split()


def _flags_at(tokens: list[str]) -> int | None:
    """The index of the CR flags field of a sample's tokens (None without one)."""
    for i, token in enumerate(tokens[1:], 1):
        if set(token) <= set(".ICR") and len(token) in (3, 5) and token != ".":
            return i
    return None


def _with_values(lines: list[str], make: Any) -> list[str]:
    """Each sample line with `make(tokens)` values inserted before its flags (or at its end)."""
    out = []
    for line in lines:
        if not _is_sample(line):
            out.append(line)
            continue
        tokens = _fields(line)
        at = _flags_at(tokens) or len(tokens)
        out.append("\t".join([*tokens[:at], *make(tokens), *tokens[at:]]))
    return out


def opt_miss(value: str) -> Any:
    """`-miss VALUE`: a missing x or y written as VALUE (the pupil is not replaced)."""

    def apply(lines: list[str]) -> list[str]:
        out = []
        for line in lines:
            if _is_sample(line):
                tokens = _fields(line)
                positions = (1, 2, 4, 5) if len(tokens) >= 8 else (1, 2)
                for i in positions:
                    if tokens[i] == ".":
                        tokens[i] = value
                line = "\t".join(tokens)
            out.append(line)
        return out

    return apply


def opt_samples_only(lines: list[str]) -> list[str]:
    """`-s`: sample lines only."""
    return [line for line in lines if _is_sample(line)]


def opt_events_only(lines: list[str]) -> list[str]:
    """`-e`: no sample lines, no SAMPLES lines; START says EVENTS only."""
    out = []
    for line in lines:
        if _is_sample(line) or line.startswith("SAMPLES"):
            continue
        if line.startswith("START"):
            line = "\t".join(t for t in _fields(line) if t != "SAMPLES")
        out.append(line)
    return out


def opt_right(lines: list[str]) -> list[str]:
    """`-r` of a binocular file: the right eye's columns, flags and events only."""
    out = []
    for line in lines:
        tokens = _fields(line)
        if _is_sample(line):
            at = _flags_at(tokens)
            flags = tokens[at]
            tokens = [tokens[0], *tokens[4:7], *tokens[7:at], flags[0] + flags[3:5]]
            line = "\t".join(tokens)
        elif tokens and tokens[0] in ("START", "SAMPLES", "EVENTS"):
            line = "\t".join(t for t in tokens if t != "LEFT")
        elif tokens and tokens[0][:1] in "SE" and tokens[1:2] == ["L"]:
            continue  # a left-eye event
        out.append(line)
    return out


def opt_vel(lines: list[str]) -> list[str]:
    """`-vel`: x, y velocity per eye after the pupils (missing where the eye is)."""

    def velocity(tokens: list[str]) -> list[str]:
        eyes = ((1, 2), (4, 5)) if (_flags_at(tokens) or 0) >= 7 else ((1, 2),)
        return [v for i, _ in eyes for v in (("." if tokens[i] == "." else "12.5"), "-3.0")]

    return _with_values(lines, velocity)


def opt_res(lines: list[str]) -> list[str]:
    """`-res`: x, y resolution after the pupils (and velocity); RES on the SAMPLES line."""
    lines = _with_values(lines, lambda tokens: ["23.20", "23.40"])
    return [
        line.replace("SAMPLES\tGAZE", "SAMPLES\tGAZE\tRES") if line.startswith("SAMPLES") else line
        for line in lines
    ]


def opt_input(lines: list[str]) -> list[str]:
    """`-input`: the input port's value after the other values."""
    return _with_values(lines, lambda tokens: ["127.0"])


def opt_nflags(lines: list[str]) -> list[str]:
    """`-nflags`: no CR flags field."""
    out = []
    for line in lines:
        if _is_sample(line) and (at := _flags_at(tokens := _fields(line))) is not None:
            line = "\t".join(tokens[:at] + tokens[at + 1 :])
        out.append(line)
    return out


def opt_ftime(lines: list[str]) -> list[str]:
    """`-ftime`: times with their fraction (the second row of a 2000 Hz stamp at .5)."""
    out, last = [], None
    for line in lines:
        if _is_sample(line):
            tokens = _fields(line)
            stamp = tokens[0]
            tokens[0] = f"{stamp}.5" if stamp == last else f"{stamp}.0"
            last = stamp
            line = "\t".join(tokens)
        out.append(line)
    return out


def opt_avg(lines: list[str]) -> list[str]:
    """`-avg` (derived, not seen in a real file): a binocular sample as the mean of the eyes
    with a position, in one eye's layout and flags."""
    out = []
    for line in lines:
        if _is_sample(line):
            t = _fields(line)
            at = _flags_at(t)
            eyes = [(float(t[i]), float(t[i + 1]), float(t[i + 2])) for i in (1, 4) if t[i] != "."]
            if eyes:
                mean = [repr(sum(e[k] for e in eyes) / len(eyes)) for k in range(3)]
            else:
                mean = [".", ".", "0.0"]
            line = "\t".join([t[0], *mean, t[at][0] + t[at][1:3]])
        out.append(line)
    return out


def opt_nse(lines: list[str]) -> list[str]:
    """`-nse`: no start events (SFIX, SSACC, SBLINK)."""
    return [x for x in lines if not x.startswith(("SFIX", "SSACC", "SBLINK"))]


def opt_nmsg(lines: list[str]) -> list[str]:
    """`-nmsg`: no messages (nor the lines that continue them)."""
    keep = []
    for line in lines:
        first = line[:1]
        if line.startswith("MSG") or (line.strip() and not (first.isalnum() or first == "*")):
            continue
        keep.append(line)
    return keep


def opt_hpos(lines: list[str]) -> list[str]:
    """`-hpos` (EyeLink II's head markers; derived: the usage text gives no layout): eight
    values, four markers' x and y, after the others."""
    return _with_values(
        lines, lambda tokens: [f"{v:.1f}" for v in (101, 52, 87, 48, 64, 33, 120, 61)]
    )


def opt_neye(lines: list[str]) -> list[str]:
    """`-neye`: no eye-movement events; samples, messages, buttons and data block lines stay
    (the EyeLink II manual, §4.8.2.3: "just samples, messages, button events, and data block
    events")."""
    eye_events = ("SFIX", "EFIX", "SSACC", "ESACC", "SBLINK", "EBLINK")
    return [x for x in lines if not x.startswith(eye_events)]


def opt_href(lines: list[str]) -> list[str]:
    """`-sh`: HREF samples."""
    return [x.replace("SAMPLES\tGAZE", "SAMPLES\tHREF") for x in lines]


def _variant(real: dict[str, Path], tmp_path: Path, name: str, *options: Any) -> Path:
    lines = real[name].read_text(encoding="utf-8").splitlines()
    for option in options:
        lines = option(lines)
    path = tmp_path / f"{name}-{len(list(tmp_path.iterdir()))}.asc"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _xyv(log: Any) -> list[tuple]:
    return [(s.t_ns, repr(s.x), repr(s.y), s.valid) for s in log.samples]


def _eye_data(log: Any) -> list[tuple]:
    def eye(e: Any) -> Any:
        return None if e is None else (repr(e.x), repr(e.y))

    return [(s.t_ns, eye(s.left), eye(s.right)) for s in log.samples]


def _events(log: Any) -> list[tuple]:
    return [(e.kind, e.id, e.t_ns, repr(e.x), repr(e.y), e.duration_ns, e.eye) for e in log.events]


def _without_end_marker(log: Any) -> SimpleNamespace:
    """The samples of sample lines of a one-block file: its END marker, the last sample
    (invalid, its eyes lost, after the block's last sample line), left out."""
    *lines, end = log.samples
    assert not end.valid and all(e is None or math.isnan(e.x) for e in (end.left, end.right))
    return SimpleNamespace(samples=lines)


SCREEN = {"pymovements_binocular": (1921, 1081), "syelink_left_eye_excerpt": (1280, 1024)}


@pytest.mark.parametrize("name", ["pymovements_binocular", "syelink_left_eye_excerpt"])
@pytest.mark.parametrize("value", ["-1", "0", "NaN"])
def test_edf2asc_miss_gives_the_default_conversion(
    real: dict[str, Path], tmp_path: Path, name: str, value: str
) -> None:
    """`edf2asc -miss VALUE` writes a lost eye's x, y as VALUE and its pupil as 0.0: read as
    missing whether `--missing VALUE` is given or not (a pupil of 0 is lost track), so the
    samples are the default conversion's; the header says what lost track was written as.
    Guards: a pupil of 0 read as a valid gaze at (-1, -1) or (0, 0)."""
    reference = read_eyelink_asc(real[name])
    path = _variant(real, tmp_path, name, opt_miss(value))
    text = path.read_text(encoding="utf-8")
    assert f"\t{value}\t{value}\t" in text  # the variant does write lost track so
    for missing in (None, value):
        log = read_eyelink_asc(path, missing=missing, strict=True)
        assert _xyv(log) == _xyv(reference) and _eye_data(log) == _eye_data(reference)
        assert _events(log) == _events(reference)
        if missing is None and value != "NaN":  # NaN is no number: missing by its value alone
            assert log.header.tracker["lost_track_written_as"][value] > 0


@pytest.mark.parametrize(
    ("options", "what"),
    [
        ((opt_vel,), "-vel"),
        ((opt_res,), "-res"),
        ((opt_input,), "-input"),
        ((opt_nflags,), "-nflags"),
        ((opt_vel, opt_res, opt_input, opt_nflags), "-vel -res -input -nflags"),
        ((opt_ftime,), "-ftime"),
        ((opt_nse,), "-nse"),
        ((opt_hpos,), "-hpos"),
    ],
)
@pytest.mark.parametrize("name", ["pymovements_binocular", "syelink_left_eye_excerpt"])
def test_edf2asc_options_that_add_columns_or_leave_lines_out_change_nothing(
    real: dict[str, Path], tmp_path: Path, name: str, options: tuple, what: str
) -> None:
    """With events (the SAMPLES lines name the eyes): `-vel`, `-res`, `-input`, `-nflags`,
    `-ftime`, `-nse` and `-hpos` give the default conversion's samples, eyes and events. Guards: a
    column read at a shifted place; a start event needed for its end."""
    reference = read_eyelink_asc(real[name])
    log = read_eyelink_asc(_variant(real, tmp_path, name, *options), strict=True)
    assert _xyv(log) == _xyv(reference), what
    assert _eye_data(log) == _eye_data(reference), what
    expected = _events(reference)
    if opt_nse in options:  # a start whose end the file does not hold has no line left
        ended = {(e[0].partition("_")[0], e[1], e[-1]) for e in expected if "_end" in e[0]}
        expected = [e for e in expected if (e[0].partition("_")[0], e[1], e[-1]) in ended]
    assert _events(log) == expected, what


@pytest.mark.parametrize(
    "options",
    [
        (),
        (opt_vel,),
        (opt_input,),
        (opt_res,),
        (opt_vel, opt_res, opt_input),
        (opt_vel, opt_nflags),
        (opt_hpos,),
    ],
    ids=[
        "-s",
        "-s -vel",
        "-s -input",
        "-s -res",
        "-s -vel -res -input",
        "-s -vel -nflags",
        "-s -hpos",
    ],
)
def test_edf2asc_sample_only_files_tell_binocular_samples_by_their_flags(
    real: dict[str, Path], tmp_path: Path, options: tuple
) -> None:
    """`edf2asc -s` of a binocular recording, with extra columns: the 5-character CR flags (or,
    without them, 6 values) say both eyes, so the samples are the default's (less the END
    marker: no line says where the block ends). Guards: refusing `-s -vel`/`-s -input` by
    their count of values; one eye's columns taken for the other's."""
    name = "pymovements_binocular"
    reference = read_eyelink_asc(real[name])
    path = _variant(real, tmp_path, name, opt_samples_only, *options)
    log = read_eyelink_asc(path, geometry=ScreenGeometry(0.6, *SCREEN[name]), strict=True)
    assert _xyv(log) == _xyv(_without_end_marker(reference))
    assert _eye_data(log) == _eye_data(_without_end_marker(reference))
    assert log.header.tracker["eyes"] == ["left", "right"] and log.events == []


def test_edf2asc_sample_only_files_of_one_eye_need_the_eye(
    real: dict[str, Path], tmp_path: Path
) -> None:
    """`edf2asc -s -r` (a binocular recording's right eye, samples only) names no eye: refused,
    saying to pass --eye; with `eye="right"` the samples are the right eye's of the default
    conversion. `-s -nflags` of both eyes (6 values; 7 with `-input`) is refused as ambiguous
    unless `eye="both"`. Guards: a monocular sample-only file labelled left."""
    name = "pymovements_binocular"
    screen = ScreenGeometry(0.6, *SCREEN[name])
    reference = read_eyelink_asc(real[name])
    path = _variant(real, tmp_path, name, opt_right, opt_samples_only)
    with pytest.raises(FormatError, match="--eye left or --eye right") as info:
        read_eyelink_asc(path, geometry=screen)
    assert (info.value.line, info.value.field) == (1, "eye")
    log = read_eyelink_asc(path, geometry=screen, eye="right")
    right = [
        (s.t_ns, repr(s.right.x), repr(s.right.y), math.isfinite(s.right.x))
        for s in _without_end_marker(reference).samples
        if s.right is not None
    ]
    assert [(t, x, y, v) for t, x, y, v in _xyv(log)] == [
        (t, x if v else "nan", y if v else "nan", v) for t, x, y, v in right
    ]
    assert log.header.tracker["eyes"] == ["right"]
    for extra in ((), (opt_input,)):  # 6 or 7 values: both eyes, or one with -vel -input...
        ambiguous = _variant(real, tmp_path, name, opt_samples_only, opt_nflags, *extra)
        with pytest.raises(FormatError, match="without -nflags"):
            read_eyelink_asc(ambiguous, geometry=screen)
        both = read_eyelink_asc(ambiguous, geometry=screen, eye="both")
        assert _xyv(both) == _xyv(_without_end_marker(reference))


def test_edf2asc_one_eye_with_events_avg_and_href(real: dict[str, Path], tmp_path: Path) -> None:
    """`-r` with events: the SAMPLES line names the right eye, so its samples and events are
    the default's right eye's; `-avg` (derived): one eye's layout in a binocular block is the
    gaze without per-eye data, the default's gaze; `-sh`: refused, naming `-sg`. Guards: a
    `-r` file's eye taken from the column count; an averaged sample refused or misread."""
    name = "pymovements_binocular"
    reference = read_eyelink_asc(real[name])
    right = read_eyelink_asc(_variant(real, tmp_path, name, opt_right), strict=True)
    assert right.header.tracker["eyes"] == ["right"]
    expected = [
        (s.t_ns, *((repr(s.right.x), repr(s.right.y)) if s.right else ("nan", "nan")))
        for s in reference.samples
    ]
    assert [(t, x, y) for t, x, y, _ in _xyv(right)] == expected
    assert _events(right) == [e for e in _events(reference) if e[-1] == "right"]
    avg = read_eyelink_asc(_variant(real, tmp_path, name, opt_avg), strict=True)
    assert [(t, v) for t, _, _, v in _xyv(avg)] == [(t, v) for t, _, _, v in _xyv(reference)]
    for a, b in zip(avg.samples, reference.samples, strict=True):
        assert a.left is None and (not b.valid or (a.x, a.y) == pytest.approx((b.x, b.y)))
    assert avg.header.tracker["averaged_samples"] == 368
    with pytest.raises(FormatError, match="edf2asc -sg"):
        read_eyelink_asc(_variant(real, tmp_path, name, opt_href))


@pytest.mark.parametrize("name", ["pymovements_binocular", "syelink_left_eye_excerpt"])
def test_edf2asc_neye_keeps_samples_and_messages(
    real: dict[str, Path], tmp_path: Path, name: str
) -> None:
    """`-neye`: the default's samples and notes, no event; `-ns -neye` (the manual's "file
    structure outline"): its notes alone. Guards: a file without eye events refused, or its
    messages lost."""
    reference = read_eyelink_asc(real[name])
    log = read_eyelink_asc(_variant(real, tmp_path, name, opt_neye), strict=True)
    assert _xyv(log) == _xyv(reference) and _eye_data(log) == _eye_data(reference)
    assert log.events == [] and log.notes == reference.notes
    outline = read_eyelink_asc(_variant(real, tmp_path, name, opt_events_only, opt_neye))
    assert outline.samples == [] and outline.events == [] and outline.notes == reference.notes


def test_edf2asc_events_only_and_no_messages(
    real: dict[str, Path], tmp_path: Path, live_server: Any
) -> None:
    """`-e`: a log of the default's events and notes with no sample, which the daemon replays
    (its fixations are sent); `-nmsg`: no screen in the file, so `geometry` gives it, and the
    samples and events are the default's. Guards: an events-only file refused; a replay that
    sends nothing without samples."""
    name = "pymovements_binocular"
    reference = read_eyelink_asc(real[name])
    path = _variant(real, tmp_path, name, opt_events_only)
    events = read_eyelink_asc(path, strict=True)
    assert events.samples == [] and _events(events) == _events(reference)
    assert events.notes == reference.notes
    assert events.header.tracker["events_only"] is True
    assert events.header.tracker["eyes"] == ["left", "right"]
    quiet = _variant(real, tmp_path, name, opt_nmsg)
    with pytest.raises(FormatError, match="--screen"):
        read_eyelink_asc(quiet)
    log = read_eyelink_asc(quiet, geometry=ScreenGeometry(0.6, *SCREEN[name]), strict=True)
    assert _xyv(log) == _xyv(reference) and _events(log) == _events(reference)

    server = live_server(token="t")
    sent = tmp_path / "sent.jsonl"
    argv = ["--source", f"replay:{path}@max", "--server", server.ws_url, "--token", "t", "-q"]
    assert daemon_main([*argv, "--record", str(sent)]) == 0
    replayed = read_session_log(sent)
    fixations = [e for e in replayed.events if e.kind.startswith("fixation")]
    assert fixations and replayed.samples == []


def test_an_end_long_after_the_last_sample_ends_the_block_there(
    real: dict[str, Path], tmp_path: Path
) -> None:
    """An END 52 minutes after its block's last sample (MNE's test file has one): the END
    marker goes one sample period after the last sample, with a note, so a replay does not
    hold the last gaze for 52 minutes. Guards: the marker at the END's time."""
    lines = real["syelink_left_eye_excerpt"].read_text(encoding="utf-8").splitlines()
    i = next(i for i, line in enumerate(lines) if line.startswith("END"))
    tokens = _fields(lines[i])
    last = int(_fields(next(x for x in reversed(lines[:i]) if _is_sample(x)))[0])
    tokens[1] = str(last + 52 * 60 * 1000)
    lines[i] = "\t".join(tokens)
    path = tmp_path / "late_end.asc"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    log = read_eyelink_asc(path, strict=True)
    marker = next(s for s in log.samples if not s.valid and s.t_ns > last * MS)
    assert marker.t_ns == last * MS + 2 * MS  # 500 Hz
    assert any("s after its block's last sample" in n.text for n in log.notes)
