"""The HTML report of a ``piezocomp reproduce`` run: one file, readable offline.

The paper's figures and Table I redrawn from the run beside the published numbers, the
speed sweep, the identification, the configuration used and the command that reproduces it.
Figures are PNG files written beside the report and embedded in it (base64), so the one HTML
file is enough.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_write_text, staged_path
from piezocomp.experiments import fig8, fig9, fig10
from piezocomp.experiments.contract import DRIFT_METHOD, default_first
from piezocomp.experiments.drift_session import unresolved_note
from piezocomp.experiments.methods import DESCRIPTIONS, IDENTIFICATIONS
from piezocomp.experiments.reproduce import Reproduction
from piezocomp.experiments.results import (
    DriftNoiseSummary,
    DriftSessionRun,
    Results,
    Stat,
    session_methods,
)
from piezocomp.identification.estimation.findings import line_drift_text
from piezocomp.plotting import experiments as P
from piezocomp.virtual_afm import config_to_toml

__all__ = ["CSS", "FIGURES", "embedded_image", "mean_std", "write_figures", "write_report"]

FIGURES = ("table1", "fig9", "fig8", "fig10", "speeds")
"""The figures' file names (``DIR/NAME.png``)."""

SHOWN = ("uncompensated", "compensated", DRIFT_METHOD)
"""Methods whose images the figures show (the others are in the tables)."""

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.45;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
.paper{background:#fff8e6}.good{color:#0a6b2b;font-weight:600}.bad{color:#a11;font-weight:600}
.warn{background:#fdecea;border:1px solid #e0a4a0;padding:.6em 1em;margin:1em 0}
img{max-width:100%;border:1px solid #ddd;margin:.5em 0}
pre{background:#f6f6f6;padding:.6em;white-space:pre-wrap;font-size:.85em}
table.text td{text-align:left}
.note{color:#555;font-size:.9em}
"""


def _f(v: Any, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def mean_std(stat: Stat, of: int | None = None) -> str:
    """``mean +- std``, with ``(n of N)`` when fewer than ``of`` experiments counted; the
    value alone when one experiment counted (one value has no spread)."""
    if stat["mean"] is None:
        return "n/a"
    count = f" ({stat['n']} of {of})" if of is not None and stat["n"] < of else ""
    if stat["n"] == 1:
        return f"{stat['mean']:.2f}{count}"
    return f"{stat['mean']:.2f} &plusmn; {stat['std']:.2f}{count}"


def _by_method(rep: Reproduction, experiment: str, keep_only: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for t, r in rep.outcomes:
        if t.experiment == experiment and not isinstance(r, str) and (t.keep or not keep_only):
            out.setdefault(t.method, r)
    return out


def write_figures(rep: Reproduction, out: Path) -> list[str]:
    """The figures of the run as PNG files in ``out``; their names."""
    res = rep.results
    names = []
    t1 = [r for r in res["table1"] if r["speed_nm_per_s"] == res["paper"]["speed_nm_per_s"]]
    P.plot_table1(res, out / "table1.png", default_first(t1[0]["methods"]) if t1 else None)
    names.append("table1.png")
    shown = default_first(SHOWN)
    got9 = _by_method(rep, fig9.NAME)
    f9 = {m: got9[m] for m in shown if m in got9}
    if f9:
        P.plot_fig9(f9, out / "fig9.png")
        names.append("fig9.png")
    got8 = _by_method(rep, fig8.NAME)
    f8 = {m: got8[m] for m in shown if m in got8}
    if f8:
        P.plot_fig8(f8, out / "fig8.png")
        names.append("fig8.png")
    f10 = {
        m: rs
        for m in shown
        if (rs := [r for t, r in rep.outcomes if t.experiment == fig10.NAME and t.method == m])
    }
    if f10:
        P.plot_fig10(f10, out / "fig10.png")
        names.append("fig10.png")
    P.plot_speeds(res, out / "speeds.png", default_first(res["fig9"]["methods"]),
                  _speeds_note(res))  # fmt: skip
    names.append("speeds.png")
    if "drift_session" in res:
        P.plot_drift_session(res["drift_session"], out / "drift.png")
        names.append("drift.png")
    return names


def _fig10_drift(res: Results) -> str:
    """Fig. 10 inside the drift compensator (empty on a scanner without drift)."""
    f = res.get("fig10_drift")
    if not f:
        return ""
    cells = []
    methods = session_methods(f)
    for m in (DRIFT_METHOD, "compensated"):
        r = methods.get(m)
        if r is None:
            cells.append(f"<tr><td>{m}</td><td colspan=2>not run</td></tr>")
            continue
        cells.append(f"<tr><td>{m}</td><td>{html.escape(fig10.outcome_text(r))}</td>"
                     f"<td>{mean_std(r['true_max_error_nm'], f['trials'])}</td></tr>")  # fmt: skip
    return f"""<h3>Fig. 10 on the drifting sample</h3>
<p class=note>The same assembly ({f["trials"]} trials), the drift compensator tracking landmarks
outside the area worked in (<b>{DRIFT_METHOD}</b>), beside the default model alone.</p>
<table><tr><th>method</th><th>assemblies</th><th>worst site's true error (nm), mean &plusmn; std
over the assemblies (n of N: where fewer had one)</th></tr>
{"".join(cells)}</table>
"""


def _drift(res: Results) -> str:
    """The drift session's section (empty when the run had none)."""
    ds = res.get("drift_session")
    if not ds:
        return _fig10_drift(res)
    rows, notes = [], []
    got = session_methods(ds)
    for m in default_first(got):
        r = got[m]
        what = html.escape(ds["descriptions"].get(m, ""))
        name = html.escape(m)
        if "error" in r:
            rows.append(f"<tr><td>{name}</td><td>{what}</td>"
                        f"<td colspan=4>failed: {html.escape(r['error'])}</td></tr>")  # fmt: skip
            continue
        over = r["measurement_overhead_fraction"]
        rows.append(
            f"<tr><td>{name}</td><td>{what}</td><td>{_f(r['true_max_error_nm'])} / "
            f"{_f(r['max_error_nm'])}</td><td>{_f(r.get('true_final_error_nm'))} / "
            f"{_f(r.get('final_error_nm'))}</td><td>{100 * over:.1f} %</td>"
            f"<td>{r['drift_measurements']}</td>"
            f"<td>{_noise(r.get('drift_noise'), ds['minutes'])}</td></tr>"
        )
        notes.append(_limitation(m, r))
    return f"""<h2>Drift: {ds["minutes"]:g} minutes on a drifting sample</h2>
<p class=note>Areas {ds["d_nm"]:g} nm apart visited in turn at {ds["speed_nm_per_s"]:g} nm/s,
two random points between visits, each visit imaged; the error of an image is its offset from
the first image of its area. Overhead: the share of the session spent imaging landmarks.</p>
<table><tr><th>method</th><th>what it is</th><th>worst error (nm), true / measured</th>
<th>final error (nm), true / measured</th><th>overhead</th><th>drift measurements</th>
<th>drift noise used (nm/&radic;s)</th></tr>
{"".join(rows)}</table>
{"".join(notes)}{_fig10_drift(res)}"""


def _noise(noise: DriftNoiseSummary | None, minutes: float) -> str:
    """The drift noise a session's filter ran with: learnt (from how many measurements) or
    the generic prior (with :func:`unresolved_note`)."""
    if not noise:
        return ""
    n = noise["learnt_from_measurements"]
    how = f"learnt from {n}{unresolved_note(noise, minutes)}" if n else "prior"
    return f"{noise['position_nm_per_sqrt_s']:.3g} ({how})"


def _limitation(method: str, r: DriftSessionRun) -> str:
    """A method's limit by design, said under the table (empty for the others)."""
    limit, stopped = r["limitation"], r["stopped"]
    if not limit:
        return ""
    m = html.escape(method)
    why = html.escape(limit)
    if stopped:
        return (f"<p class=note><b>{m}</b> could not go on ({r['images']} images): "
                f"{html.escape(stopped)}. This is a limit of the method, not a failure "
                f"of the run: {why}.</p>\n")  # fmt: skip
    err = r["scanner_error_nm"]
    seen = "" if not err else (f" Its landmarks measured that error at {err[0]:.1f} nm (x) and "
                               f"{err[1]:.1f} nm (y) per sighting.")  # fmt: skip
    return (f"<p class=note><b>{m}</b>: {why}; the estimate follows it as drift, and the "
            f"areas move by about as much.{seen}</p>\n")  # fmt: skip


def embedded_image(out: Path, name: str, alt: str) -> str:
    p = staged_path(out / name)  # written in this run, maybe not yet in place
    if not p.exists():
        return ""
    data = base64.b64encode(p.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _table1(res: Results) -> str:
    v0 = res["paper"]["speed_nm_per_s"]
    rows = [r for r in res["table1"] if r["speed_nm_per_s"] == v0]
    if not rows:
        return "<p>Table I was not run at the paper's speed.</p>"
    methods = default_first(rows[0]["methods"])
    head = "".join(f"<th>{html.escape(m)}</th>" for m in methods)
    body = []
    for r in rows:
        p = res["paper"]["table1"].get(str(int(r["d_nm"])))
        paper = "<td></td><td></td>"
        if p:
            paper = "".join(
                f"<td class=paper>{p[k][0]:.2f} &plusmn; {p[k][1]:.2f}</td>"
                for k in ("uncompensated", "compensated")
            )
        n = res["table1_settings"]["experiments"]
        true = "".join(
            f"<td>{mean_std(r['methods'][m]['true_max_error_nm'], n)}</td>" for m in methods
        )
        meas = "".join(f"<td>{mean_std(r['methods'][m]['max_error_nm'], n)}</td>" for m in methods)
        body.append(f"<tr><td>{r['d_nm']:g} (true)</td>{paper}{true}</tr>")
        body.append(f"<tr><td>{r['d_nm']:g} (measured)</td><td></td><td></td>{meas}</tr>")
    note = ""
    if DRIFT_METHOD in methods:
        note = (
            f"<p class=note>The scanner drifts. The first column, <b>{DRIFT_METHOD}</b>, the "
            "package's default on a drifting instrument, runs the default model inside the "
            "drift compensator (landmarks re-imaged between moves). Every other method runs "
            "without drift compensation: its images are minutes apart and carry the drift "
            "between them, as the paper's without its drift compensator.</p>"
        )
    return (
        "<table><tr><th>d (nm)</th><th class=paper>paper, without</th><th class=paper>paper, "
        f"with</th>{head}</tr>{''.join(body)}</table>{note}"
    )


def _speeds_note(res: Results) -> str:
    """What changes with Fig. 9's speed besides the speed: the time between its two images,
    in which a drifting sample moves under the tip (figures from the experiment's path and
    images; whether the scanner drifts from the run's drift compensator)."""
    path = np.asarray(fig9.PATH_NM)
    length = float(np.sum(np.hypot(*np.diff(path, axis=0).T)))
    st = fig9.Fig9Settings()
    image_s = st.pixels / st.line_rate_hz
    speeds = sorted(s["speed_nm_per_s"] for s in res["fig9"]["speeds"])
    if not speeds:
        return ""
    lo, hi = speeds[0], speeds[-1]
    text = (
        f"Fig. 9's error is the offset between two images ({image_s:.0f} s each) taken before "
        f"and after its {length / 1000:.1f} um path, which takes {length / lo:.1f} s at "
        f"{lo:g} nm/s and {length / hi:.1f} s at {hi:g} nm/s."
    )
    if DRIFT_METHOD in res["methods_compared"]:
        text += (
            " The scanner drifts: the sample moves under the tip all that time, and a slower "
            "path gives it longer, so a compensated method without drift compensation can show "
            "less error at a higher speed (on the drift-free twin its error rises with the "
            "speed instead: docs/experiments.md)."
        )
    return text


def _speeds(res: Results) -> str:
    methods = default_first(res["fig9"]["methods"])
    head = "".join(f"<th>{html.escape(m)}</th>" for m in methods)
    body = []
    for s in sorted(res["fig9"]["speeds"], key=lambda s: s["speed_nm_per_s"]):
        got = s["methods"]
        cells = "".join(
            f"<td>{_f(got[m]['true_error_nm'])} / {_f(got[m]['error_nm'])}</td>"
            if m in got else "<td>not run</td>" for m in methods
        )  # fmt: skip
        body.append(f"<tr><td>Fig. 9 at {s['speed_nm_per_s']:g}</td>{cells}</tr>")
    speeds = sorted({r["speed_nm_per_s"] for r in res["table1"]})
    for v in speeds:
        worst = []
        n_run = res["table1_settings"]["experiments"]
        for m in methods:
            stats = [r["methods"][m]["true_max_error_nm"]
                     for r in res["table1"] if r["speed_nm_per_s"] == v
                     and m in r["methods"]]  # fmt: skip
            known = [st for st in stats if st["mean"] is not None]
            top = max(known, key=lambda st: st["mean"] or 0.0) if known else None
            cell = "n/a" if top is None else _f(top["mean"])
            if top is not None and top["n"] < n_run:
                cell += f" ({top['n']} of {n_run})"
            worst.append(f"<td>{cell}</td>")
        body.append(f"<tr><td>Table I at {v:g}, worst d</td>{''.join(worst)}</tr>")
    corner = "nm/s: true / measured (nm); Table I: the worst distance's mean"
    return f"<table><tr><th>{corner}</th>{head}</tr>{''.join(body)}</table>"


def _fig8_fig10(res: Results) -> str:
    f8 = res["fig8"]["methods"]
    f10: dict[str, Any] = dict(res["fig10"]["methods"])
    inside = session_methods(res["fig10_drift"]) if "fig10_drift" in res else {}
    if inside.get(DRIFT_METHOD):  # Fig. 10 inside the drift compensator: the default there
        f10[DRIFT_METHOD] = inside[DRIFT_METHOD]
    methods = default_first(list(f10) or list(f8))
    head = "".join(f"<th>{html.escape(m)}</th>" for m in methods)
    trials = res["fig10"]["trials"]
    row8 = "".join(
        f"<td>{_f(f8[m]['true_spread_nm'])} / {_f(f8[m]['spread_nm'])}{_seen(f8[m])}</td>"
        if m in f8 else "<td>not run</td>" for m in methods
    )  # fmt: skip
    row10 = "".join(
        f"<td>{_rate(f10[m], 'true_success_rate', trials)} / "
        f"{_rate(f10[m], 'success_rate', trials)}</td>" if m in f10 else "<td></td>"
        for m in methods
    )  # fmt: skip
    failed10 = "".join(
        f"<td>{html.escape(_failed_worst(f10[m]))}</td>" if m in f10 else "<td></td>"
        for m in methods
    )
    err10 = "".join(
        f"<td>{mean_std(f10[m]['true_max_error_nm'], trials)}</td>" if m in f10 else "<td></td>"
        for m in methods
    )
    fail10 = "".join(
        f"<td>{sum(f10[m]['failed_pushes'].values())} / {f10[m].get('unrecovered', 0)}</td>"
        if m in f10 and "failed_pushes" in f10[m] else "<td>not counted</td>"
        for m in methods
    )  # fmt: skip
    p8 = "<td class=paper colspan=2>traces drawn, no figure given</td>"
    p10 = "<td class=paper>fails most of the time</td><td class=paper>succeeds</td>"
    return (
        "<table><tr><th></th><th class=paper>paper, without</th><th class=paper>paper, with</th>"
        f"{head}</tr>"
        f"<tr><td>Fig. 8: worst peak spread (nm), true / measured</td>{p8}{row8}</tr>"
        f"<tr><td>Fig. 10: assemblies that succeeded, of {trials}, true / measured</td>"
        f"{p10}{row10}</tr><tr><td>Fig. 10: the failed assemblies' worst site, true (nm)</td>"
        f"<td class=paper></td><td class=paper></td>{failed10}</tr>"
        f"<tr><td>Fig. 10: worst site's true error (nm), mean &plusmn; std over the "
        f"assemblies</td><td class=paper></td>"
        f"<td class=paper></td>{err10}</tr><tr><td>Fig. 10: failed pushes seen in the images / "
        f"those whose site was still off at the end, the planner's retries included (a site "
        f"can fail more than once)"
        f"</td><td class=paper></td><td class=paper></td>"
        f"{fail10}</tr></table>"
    )


def _seen(r: Any) -> str:
    """`` (n of N particles)`` when the measured spread counts fewer than all particles."""
    per = r.get("per_particle_nm") or []
    n = sum(v is not None for v in per)
    return f" ({n} of {len(per)} particles)" if per and n < len(per) else ""


def _rate(r: Any, key: str, trials: int) -> str:
    """A success rate as ``n of N (x %)`` (``x %`` alone where the key is missing)."""
    if key not in r:
        return "n/a"
    runs = r.get("assemblies")
    n = len(runs) if runs is not None else trials
    return f"{round(r[key] * n)} of {n} ({100 * r[key]:.0f} %)"


def _failed_worst(r: Any) -> str:
    """The worst site of a method's failed assemblies (``fig10.outcome_text``'s part)."""
    text = fig10.outcome_text(r)
    _, sep, failed = text.partition("; of the ")
    return f"of the {failed}" if sep else "none failed"


def _orders(orders: dict[str, int] | None) -> str:
    return "" if not orders else f"N_H = {orders['n_play']}, N_c = {orders['n_creep']}"


def _identification(res: Results) -> str:
    rows = []
    for axis, kinds in sorted(res["identification"]["axes"].items()):
        for summ in kinds.values():
            for name, v in summ.items():
                if isinstance(v, dict) and "validation_max_error_nm" in v:
                    rows.append(
                        f"<tr><td>{axis}</td><td>{html.escape(name)}</td>"
                        f"<td>{_f(v['validation_max_error_nm'])}</td>"
                        f"<td>{_f(v['validation_rms_error_nm'])}</td>"
                        f"<td>{_orders(summ.get('orders'))}</td>"
                        f"<td>{_f(summ.get('computing_s'), 1)}</td></tr>"
                    )
    own: list[str] = []  # the default model's (and the paper's RLS, from the same records)
    others: list[str] = []  # the comparison methods' identifications
    for axis, kinds in sorted(res["identification"]["axes"].items()):
        for kind, summ in kinds.items():
            name, uses = (
                html.escape(v, quote=False) for v in IDENTIFICATIONS.get(kind, (kind, ""))
            )
            for text in summ.get("findings", []):
                item = f"<li>{axis}, {name} ({uses}): {html.escape(text)}</li>"
                (own if kind == "sensorless" else others).append(item)
    drift = [
        f"<li>{axis}: {html.escape(line_drift_text(ld))}</li>"
        for axis, kinds in sorted(res["identification"]["axes"].items())
        if (ld := kinds.get("sensorless", {}).get("line_drift"))
    ]
    findings = (
        "<p>Drift along the line during the default model's records (estimated with the model "
        f"and taken out when it predicted the held-out heights better):</p><ul>{''.join(drift)}"
        "</ul>"
        if drift
        else ""
    )
    if own:
        findings += (
            "<p>Findings of the default model's identification (read these before using "
            f"its model):</p><ul>{''.join(own)}</ul>"
        )
    if others:
        findings += (
            "<p>Findings of the comparison methods' identifications. They do not concern the "
            "default model; a model family without creep, for example, cannot predict the "
            "held-out heights, and the advice to record again is meant for a model one would "
            f"use:</p><ul>{''.join(others)}</ul>"
        )
    return (
        "<table><tr><th>axis</th><th>model</th><th>validation max error (nm)</th>"
        "<th>rms (nm)</th><th>orders</th><th>computing (s)</th></tr>"
        + "".join(rows)
        + "</table>"
        + findings
    )


def write_report(rep: Reproduction, out: Path, *, command: str, config_source: Any) -> Path:
    """Write ``out/report.html`` (the figures must be written first: :func:`write_figures`)."""
    res = rep.results
    fails = res["failures"]
    banner = ""
    if fails:
        items = "".join(
            f"<li>{html.escape(f['experiment'])} / {html.escape(f['method'])}"
            + (f" ({html.escape(f['settings'])})" if f["settings"] else "")
            + f": {html.escape(f['error'])}</li>"
            for f in fails
        )
        banner = f"<div class=warn><b>{len(fails)} part(s) of the run failed</b>; their " \
                 f"figures are missing from the tables.<ul>{items}</ul></div>"  # fmt: skip
    methods = "".join(
        f"<tr><td>{html.escape(m)}</td><td>{html.escape(DESCRIPTIONS[m])}</td></tr>"
        for m in default_first(DESCRIPTIONS)
        if m in res["methods_compared"]
    )
    kind = "quick run" if res["quick"] else "full run"
    duration = res["timing_s"]["total_s"]
    t1s = res["table1_settings"]
    cfg_text = html.escape(config_to_toml(config_source))
    paper9 = res["paper"]["fig9"]
    f9 = res["fig9"]["methods"]
    fig9_line = ", ".join(
        f"{html.escape(m)} {_f(f9[m]['true_error_nm'])} nm "
        f"(measured {_f(f9[m]['error_nm'])})" for m in default_first(f9)
    )  # fmt: skip
    body = f"""<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">
<title>piezocomp reproduce: {html.escape(res["preset"])}</title><style>{CSS}</style></head><body>
<h1>Compensation of scanner creep and hysteresis: the paper's experiments, reproduced</h1>
<p>B. Mokaberi and A. A. G. Requicha, <i>Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation</i>, IEEE T-ASE 5(2), 2008, run end to end on the virtual AFM
<b>{html.escape(res["preset"])}</b> (sample seed {res["seed"]}, {kind}, {duration:.0f} s).
Every error is given twice: <b>true</b> (the simulator's ground truth, for scoring only) and
<b>measured</b> as the paper measured it (image cross-correlation, particle peaks).</p>
<p>Reproduce it with:</p><pre>{html.escape(command)}</pre>
{banner}
<h2>Table I: back to an area after random moves ({res["paper"]["speed_nm_per_s"]:g} nm/s)</h2>
<p class=note>Maximum error over the two areas, mean &plusmn; std over
{t1s["experiments"]} experiments per distance (nm; "n of N": measurable in n of them, the
uncompensated tip coming back to an area without the particles it saw there). Areas of
{t1s["size_nm"]:g} nm within &plusmn;{t1s["area_half_width_nm"]:.0f} nm of the working area's
centre.</p>
{_table1(res)}
{embedded_image(out, "table1.png", "Table I")}
<h2>Fig. 9: back to the start after a path</h2>
<p>Paper: {paper9["uncompensated"]} nm without, {paper9["compensated"]} nm with compensation.
This run, true (measured): {fig9_line}.</p>
{embedded_image(out, "fig9.png", "Fig. 9 images")}
<h2>Fig. 8 and Fig. 10</h2>
{_fig8_fig10(res)}
<p class=note>Fig. 8: forward and backward ramps over a line of particles; the spread of each
particle's peak over the ramps (measured: over the particles whose peak at least half the ramps
saw, when they are at least half the particles; not measurable where the tip lost most of them).
Fig. 10: ten particles pushed into two five-particle QCA cells with no image in between;
success means every particle within {res["fig10"]["success_nm"]:g} nm of its site.</p>
{embedded_image(out, "fig8.png", "Fig. 8 traces")}
{embedded_image(out, "fig10.png", "Fig. 10 assembly")}
<h2>Speed</h2>
{_speeds(res)}
<p class=note>{html.escape(_speeds_note(res))}</p>
{embedded_image(out, "speeds.png", "Errors against speed")}
{_drift(res)}{embedded_image(out, "drift.png", "Drift session") if "drift_session" in res else ""}
<h2>Methods compared</h2>
<table class=text><tr><th>method</th><th>what it is</th></tr>{methods}</table>
<h2>Identification</h2>
<p class=note>Validation: each model's prediction against the true extension on a fresh
trajectory with minor loops over the identified span (maximum error after removing the frame
offset no sensorless method can see).</p>
{_identification(res)}
<h2>Configuration</h2>
<p>Identification settings: <code>{html.escape(str(res["identification"]["settings"]))}</code></p>
<pre>{cfg_text}</pre>
</body></html>
"""
    path = out / "report.html"
    atomic_write_text(path, body)
    return path
