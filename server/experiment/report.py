"""The analysis report: one self-contained HTML page (figures inlined as base64 PNG, no external
URLs, every text escaped), with `results.json` and `pse.tsv` beside it holding every number the
page shows (docs/experiment-analysis.md)."""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Sequence
from pathlib import Path

from gazehdr.atomic import write_text
from gazehdr.drivers.errors import InputError
from gazehdr.experiment import psychometric as pm
from gazehdr.experiment.analysis import (
    ConditionFit,
    ObserverResult,
    Settings,
    TaskResult,
    representatives,
)

PSE_COLUMNS = (
    "task",
    "participant_id",
    "condition",
    "trials",
    "missed",
    "flag",
    "pse",
    "pse_rank_value",
    "ci_low",
    "ci_high",
    "sigma",
    "lapse",
    "resamples",
)


def _r(x: float | None) -> float | None:
    """A finite float for JSON (numpy scalars become floats); a non-finite one is a bug."""
    if x is None:
        return None
    if not math.isfinite(x):
        raise InputError(f"non-finite number in the results: {x!r}")
    return float(x)


def _fit_record(f: ConditionFit) -> dict:
    lo_open, hi_open = f.ci_open
    return {
        "trials": f.levels.trials,
        "missed": f.missed,
        "levels": [
            {"x": _r(x), "n": int(n), "k": int(k), "proportion": _r(k / n)}
            for x, n, k in zip(f.levels.x, f.levels.n, f.levels.k, strict=True)
        ],
        "flag": f.fit.flag,
        "flag_meaning": pm.FLAGS[f.fit.flag],
        "pse": _r(f.fit.pse),
        "pse_rank_value": _r(f.fit.rank_value),
        "sigma": _r(f.fit.sigma),
        "lapse": _r(f.fit.lapse),
        "neg_log_likelihood": _r(f.fit.nll),
        "pse_search_bounds": [_r(b) for b in f.fit.bounds] if f.fit.bounds else None,
        "ci": [_r(c) for c in f.ci] if f.ci else None,
        "ci_open": {"low": lo_open, "high": hi_open},
        "resamples": f.resamples,
    }


def _observer_record(o: ObserverResult) -> dict:
    correct, scored = o.observer.training
    return {
        "participant_id": o.observer.participant,
        "excluded": o.observer.excluded,
        "exclusion": o.observer.exclusion or None,
        "training_correct": correct,
        "training_trials": scored,
        "training_score_participants_tsv": _r(o.observer.training_score),
        "files": o.observer.files,
        "pse_shift": _r(o.shift()),
        "conditions": {c: _fit_record(f) for c, f in o.fits.items()},
    }


def results(tasks: Sequence[TaskResult], settings: Settings) -> dict:
    """Everything the report shows, as JSON-ready data."""
    out: dict = {
        "model": "P(test) = lapse/2 + (1 - lapse) * Phi((x - pse) / sigma), x = log10 relative "
        "intensity; maximum likelihood (scipy.optimize L-BFGS-B); PSE = where Phi is 50 %",
        "settings": {
            "bootstrap": settings.bootstrap,
            "bootstrap_kind": "parametric, percentile interval",
            "seed": settings.seed,
            "ci": settings.ci,
            "lapse_max": settings.lapse_max,
        },
        "flags": pm.FLAGS,
        "tasks": [],
    }
    for t in tasks:
        g = t.group
        rs = g.ranksum
        out["tasks"].append(
            {
                "task": t.task,
                "observers_included": len(t.included),
                "observers_excluded": len(t.excluded),
                "group": {
                    "n_control": g.n_control,
                    "n_manipulated": g.n_manipulated,
                    "median_control": _r(g.median_control),
                    "median_manipulated": _r(g.median_manipulated),
                    "ranksum": None
                    if rs is None
                    else {
                        "W_control": _r(rs.W),
                        "U_control": _r(rs.U),
                        "z": _r(rs.z),
                        "p": _r(rs.p),
                        "method": rs.method,
                        "p_exact": _r(rs.p_exact),
                        "p_approximate": _r(rs.p_approximate),
                    },
                    "signed_rank": None
                    if g.signed_rank is None
                    else {
                        "n_pairs": g.signed_rank.n,
                        "statistic": _r(g.signed_rank.statistic),
                        "p": _r(g.signed_rank.p),
                    },
                },
                "representatives": [
                    {"label": label, "participant_id": o.observer.participant}
                    for label, o in representatives(t)
                ],
                "palette": {
                    "trials": [
                        {"test_intensity": _r(k), "trials": v} for k, v in t.palette_trials.items()
                    ],
                    "chosen": {
                        opt: [{"test_intensity": _r(k), "count": v} for k, v in by.items()]
                        for opt, by in t.palette.items()
                    },
                },
                "observers": [_observer_record(o) for o in t.observers],
            }
        )
    return out


def _tsv_value(v: object) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def pse_tsv(tasks: Sequence[TaskResult]) -> str:
    """One row per included observer and condition (BIDS-style: tab-separated, n/a missing)."""
    lines = ["\t".join(PSE_COLUMNS)]
    for t in tasks:
        for o in t.included:
            for c, f in o.fits.items():
                ci = f.ci or (None, None)
                row = (
                    t.task,
                    o.observer.participant,
                    c,
                    f.levels.trials,
                    f.missed,
                    f.fit.flag,
                    _r(f.fit.pse),
                    _r(f.fit.rank_value),
                    _r(ci[0]),
                    _r(ci[1]),
                    _r(f.fit.sigma),
                    _r(f.fit.lapse),
                    f.resamples,
                )
                lines.append("\t".join(_tsv_value(v) for v in row))
    return "\n".join(lines) + "\n"


# --- HTML -------------------------------------------------------------------------------------

_CSS = (
    "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
    "table{border-collapse:collapse;margin:.5em 0;font-size:.9em}"
    "td,th{border:1px solid #ccc;padding:.2em .5em;text-align:right}th{background:#f3f3f3}"
    "td.l,th.l{text-align:left}img{max-width:100%}.flag{color:#a33}.note{color:#555}"
)


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _f(x: float | None, digits: int = 3) -> str:
    return "n/a" if x is None else f"{x:.{digits}f}"


def _p(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{data}">'


def _pse_text(f: ConditionFit) -> str:
    fit = f.fit
    if fit.flag == "below_range":
        return f"&lt; {_f(float(f.levels.x[0]))}"
    if fit.flag == "above_range":
        return f"&gt; {_f(float(f.levels.x[-1]))}"
    return _f(fit.pse)


def _ci_text(f: ConditionFit) -> str:
    if f.ci is None:
        return "n/a"
    lo_open, hi_open = f.ci_open
    lo = f"≤ {_f(f.ci[0])}" if lo_open else _f(f.ci[0])
    hi = f"≥ {_f(f.ci[1])}" if hi_open else _f(f.ci[1])
    return f"[{lo}, {hi}]"


def _observer_table(task: TaskResult) -> str:
    head = (
        "<tr><th class=l>participant</th><th class=l>condition</th><th>trials</th><th>missed</th>"
        "<th>PSE</th><th>CI</th><th>σ</th><th>lapse</th><th class=l>flag</th></tr>"
    )
    rows = []
    for o in task.included:
        for c, f in o.fits.items():
            flag = f.fit.flag
            cls = "l" if flag == "ok" else "l flag"
            rows.append(
                f"<tr><td class=l>{_e(o.observer.participant)}</td><td class=l>{_e(c)}</td>"
                f"<td>{f.levels.trials}</td><td>{f.missed}</td><td>{_pse_text(f)}</td>"
                f"<td>{_ci_text(f)}</td><td>{_f(f.fit.sigma)}</td><td>{_f(f.fit.lapse)}</td>"
                f'<td class="{cls}" title="{_e(pm.FLAGS[flag])}">{_e(flag)}</td></tr>'
            )
        if not o.fits:
            rows.append(
                f"<tr><td class=l>{_e(o.observer.participant)}</td>"
                "<td class=l colspan=8>no control or manipulated trials</td></tr>"
            )
    return f"<table>{head}{''.join(rows)}</table>"


def _group_text(task: TaskResult) -> str:
    g = task.group
    n_obs = len(task.included)
    parts = [
        f"<p>{n_obs} observer{'s' if n_obs != 1 else ''} analysed, {len(task.excluded)} excluded. "
        f"PSEs entering the test: {g.n_control} control, {g.n_manipulated} manipulated. "
        f"Median PSE: control {_f(g.median_control)}, manipulated {_f(g.median_manipulated)} "
        "(log10 units).</p>"
    ]
    rs = g.ranksum
    if rs is None:
        parts.append("<p>No rank-sum test: it needs usable PSEs in both conditions.</p>")
    else:
        parts.append(
            f"<p><b>Wilcoxon rank-sum</b> (the paper's MATLAB <code>ranksum</code>), control "
            f"({rs.n_x}) vs manipulated ({rs.n_y}) PSEs: W = {_f(rs.W, 1)}, U = {_f(rs.U, 1)}, "
            f"<b>p = {_p(rs.p)}</b> ({_e(rs.method)}; exact {_p(rs.p_exact)}, normal "
            f"approximation {_p(rs.p_approximate)}, z = {_f(rs.z, 2)}).</p>"
        )
    sr = g.signed_rank
    if sr is not None:
        parts.append(
            f"<p class=note>Not in the paper: the same observers did both conditions, so a paired "
            f"Wilcoxon signed-rank test over the {sr.n} with both PSEs gives p = {_p(sr.p)} "
            f"(statistic {_f(sr.statistic, 1)}).</p>"
        )
    return "".join(parts)


def _excluded_list(task: TaskResult) -> str:
    if not task.excluded:
        return "<p>No observer excluded.</p>"
    items = "".join(
        f"<li>{_e(o.observer.participant)}: {_e(o.observer.exclusion)}</li>" for o in task.excluded
    )
    return f"<p>Excluded, not fitted:</p><ul>{items}</ul>"


def _training_table(task: TaskResult) -> str:
    rows = []
    for o in task.observers:
        correct, scored = o.observer.training
        score = "n/a" if not scored else f"{correct}/{scored} ({correct / scored:.0%})"
        rows.append(
            f"<tr><td class=l>{_e(o.observer.participant)}</td><td>{score}</td>"
            f"<td>{_f(o.observer.training_score, 2)}</td>"
            f"<td class=l>{'excluded' if o.observer.excluded else 'included'}</td></tr>"
        )
    head = (
        "<tr><th class=l>participant</th><th>training correct (trials)</th>"
        "<th>training score (participants.tsv)</th><th class=l>status</th></tr>"
    )
    return f"<table>{head}{''.join(rows)}</table>"


def _palette_table(task: TaskResult) -> str:
    if not task.palette_trials:
        return ""
    strengths = list(task.palette_trials)
    head = "".join(f"<th>{_e(f'{s:g}')}</th>" for s in strengths)
    counts = "".join(f"<td>{task.palette_trials[s]}</td>" for s in strengths)
    rows = [f"<tr><td class=l>trials</td>{counts}</tr>"]
    for option, by in task.palette.items():
        cells = "".join(f"<td>{by.get(s, 0)}</td>" for s in strengths)
        rows.append(f"<tr><td class=l>{_e(option)}</td>{cells}</tr>")
    return (
        "<h3>Palette choices (Sec. 4.3, Fig. 15)</h3><p>How often each option was picked, per "
        "flash strength (test_intensity, cd/m²), over the included observers.</p>"
        f"<table><tr><th class=l>option</th>{head}</tr>{''.join(rows)}</table>"
    )


def _task_section(task: TaskResult, images: dict[str, bytes]) -> str:
    parts = [f"<h2>Task: {_e(task.task)}</h2>", _group_text(task)]
    if "fig13" in images:
        picks = ", ".join(
            f"{_e(o.observer.participant)} ({_e(label)})" for label, o in representatives(task)
        )
        parts += [
            "<h3>Representative observers (as Fig. 13)</h3>",
            f"<p class=note>Ordered by PSE shift, manipulated minus control: {picks}. Dots: "
            "proportion 'test brighter' per level (area grows with trials); solid: the fit; "
            "dashed: the PSE; an arrowhead: a PSE beyond the levels.</p>",
            _img(images["fig13"], f"{task.task}: representative observers"),
        ]
    if "fig14" in images:
        parts += [
            "<h3>PSE distributions (as Fig. 14)</h3>",
            _img(images["fig14"], f"{task.task}: PSEs"),
        ]
    parts += ["<h3>Every observer</h3>", _observer_table(task)]
    if "grid" in images:
        parts.append(_img(images["grid"], f"{task.task}: every observer"))
    parts += ["<h3>Training and exclusions</h3>", _training_table(task), _excluded_list(task)]
    parts.append(_palette_table(task))
    return "".join(parts)


def html_page(
    tasks: Sequence[TaskResult], settings: Settings, images: dict[str, dict[str, bytes]]
) -> str:
    flags = "".join(f"<li><b>{_e(k)}</b>: {_e(v)}</li>" for k, v in pm.FLAGS.items())
    intro = (
        "<h1>gazehdr experiment analysis</h1>"
        "<p>Per observer and condition (control, manipulated; training trials scored, not "
        "fitted): a cumulative Gaussian in log10 relative intensity with a lapse rate λ, "
        "P = λ/2 + (1 − λ)·Φ((x − PSE)/σ), fitted by maximum likelihood. A lapse is a random "
        "guess, so P(PSE) = 50 % whatever λ. "
        f"{settings.ci:.0%} intervals: percentile, {settings.bootstrap} parametric bootstrap "
        f"resamples, seed {settings.seed}; λ ≤ {settings.lapse_max:g}. Every number here is in "
        "results.json and pse.tsv beside this page.</p>"
        f"<details><summary>Flags</summary><ul>{flags}</ul></details>"
    )
    body = "".join(_task_section(t, images.get(t.task, {})) for t in tasks)
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        "<title>gazehdr experiment analysis</title>"
        f"<style>{_CSS}</style></head><body>{intro}{body}</body></html>\n"
    )


def write_report(tasks: Sequence[TaskResult], settings: Settings, out: Path) -> list[Path]:
    """The page at `out`, results.json and pse.tsv beside it; returns the paths written."""
    from gazehdr.experiment import plots

    images: dict[str, dict[str, bytes]] = {}
    for t in tasks:
        mine: dict[str, bytes] = {}
        picks = representatives(t)
        if picks:
            mine["fig13"] = plots.figure13(t, picks)
        if any(o.fits for o in t.included):
            mine["fig14"] = plots.figure14(t)
            mine["grid"] = plots.observer_grid(t)
        images[t.task] = mine
    out.parent.mkdir(parents=True, exist_ok=True)
    data = json.dumps(results(tasks, settings), indent=1, allow_nan=False, ensure_ascii=False)
    paths = [out, out.with_name("results.json"), out.with_name("pse.tsv")]
    write_text(paths[1], data + "\n")
    write_text(paths[2], pse_tsv(tasks))
    write_text(paths[0], html_page(tasks, settings, images))
    return paths
