"""The report of ``piezocomp reproduce --instrument``: the virtual run's report, measured only.

Table I, Fig. 8 and Fig. 9 as :mod:`~piezocomp.experiments.report` draws them for the virtual
AFM (the same figures, ``table1.png``, ``fig8.png``, ``fig9.png``, the default method first),
from the errors an instrument can measure: image cross-correlation and particle peaks. A real
instrument has no ground truth, so no true error appears; the timing of the streamed paths
is given, and when a rehearsal over the emulator let late paths through (``--timing flag``)
the report says how far that can explain a difference from a direct run.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments import fig9, table1
from piezocomp.experiments.contract import default_first
from piezocomp.experiments.on_instrument import InstrumentRun
from piezocomp.experiments.report import CSS, embedded_image, mean_std
from piezocomp.plotting import experiments as P

__all__ = ["timing_note", "write_instrument_figures", "write_instrument_report"]


def _as_virtual(results: dict[str, Any]) -> dict[str, Any]:
    """The fields of ``results.json`` that :func:`piezocomp.plotting.experiments.plot_table1`
    reads, from an instrument run's results (true errors ``None``)."""
    speed = results["settings"]["speed_nm_per_s"]
    rows = [
        {"d_nm": r["d_nm"], "speed_nm_per_s": speed,
         "methods": {m: {"max_error_nm": c["max_error_nm"], "true_max_error_nm": None}
                     for m, c in r["methods"].items()}}
        for r in results["table1"]
    ]  # fmt: skip
    return {
        "paper": {"speed_nm_per_s": speed,
                  "table1": {str(int(d)): v for d, v in table1.PAPER.items()}},
        "table1": rows,
        "table1_settings": {"experiments": results["settings"]["table1_experiments"]},
    }  # fmt: skip


def write_instrument_figures(run: InstrumentRun, results: dict[str, Any], out: Path) -> list[str]:
    """The figures of an instrument run as PNG files in ``out``; their names."""
    names = []
    if results["table1"]:
        methods = default_first(results["methods"])
        P.plot_table1(_as_virtual(results), out / "table1.png", methods)  # type: ignore[arg-type]
        names.append("table1.png")
    for name, plot in (("fig9", P.plot_fig9), ("fig8", P.plot_fig8)):
        got = {m: r for m, n, r in run.outcomes if n == name and not isinstance(r, str)}
        shown = {m: got[m] for m in default_first(got)}
        if name == "fig9":
            shown = {m: r for m, r in shown.items() if r.images is not None}
        if shown:
            plot(shown, out / f"{name}.png")
            names.append(f"{name}.png")
    return names


def timing_note(timing: dict[str, Any], emulator: bool) -> str:
    """What the streamed paths' timing means for the figures (empty when every path kept
    its slots): on a microscope a late path stops the run (``--timing raise``, the only
    mode there); over the emulator, whose scanner advances one sample period per set-point
    whatever the wall clock, a late set-point changes nothing it simulates, so flagged
    paths explain none of a difference from a direct run of the same model and sample."""
    late = timing.get("late_paths", 0)
    if not late:
        return ""
    head = (
        f"{late} of {timing['paths']} streamed paths had samples beyond their tolerance "
        f"(worst {timing['worst_deviation_s'] * 1e3:.3g} ms, "
        f"{timing['worst_deviation_periods']:.3g} sample periods, off their slot)"
    )
    if emulator and timing.get("mode") == "flag":
        return (
            f"{head}, flagged and used (--timing flag). Over the emulator this explains "
            "none of a difference from a direct run: the emulated scanner advances one "
            "sample period per set-point whatever the wall clock, so a late set-point "
            "changes nothing it simulates; a difference comes from what differs between "
            "the runs (the model, the sample seed, the controller's own scans)."
        )
    return f"{head}."


def _table1(results: dict[str, Any]) -> str:
    rows = results["table1"]
    if not rows:
        return "<p>Table I was not run.</p>"
    methods = default_first(results["methods"])
    n = results["settings"]["table1_experiments"]
    head = "".join(f"<th>{html.escape(m)}</th>" for m in methods)
    body = []
    for r in rows:
        p = table1.PAPER.get(float(r["d_nm"]))
        paper = "<td></td><td></td>"
        if p is not None:
            paper = "".join(
                f"<td class=paper>{p[k][0]:.2f} &plusmn; {p[k][1]:.2f}</td>"
                for k in ("uncompensated", "compensated")
            )
        stat = [r["methods"][m]["max_error_nm"] for m in methods]
        cells = "".join(f"<td>{mean_std(c, n)}</td>" for c in stat)
        body.append(f"<tr><td>{r['d_nm']:g} (measured)</td>{paper}{cells}</tr>")
    return (
        "<table><tr><th>d (nm)</th><th class=paper>paper, without</th><th class=paper>paper, "
        f"with</th>{head}</tr>{''.join(body)}</table>"
    )


def _figures_line(results: dict[str, Any]) -> str:
    parts = []
    if results.get("fig9"):
        f9 = results["fig9"]
        errors = [f"{html.escape(m)} {_f(f9[m]['error_nm'])} nm" for m in default_first(f9)]
        parts.append("Fig. 9 (measured): " + ", ".join(errors))
        parts[-1] += (f" (paper: {fig9.PAPER['uncompensated']} nm without, "
                      f"{fig9.PAPER['compensated']} nm with)")  # fmt: skip
    if results.get("fig8"):
        f8 = results["fig8"]
        spreads = [f"{html.escape(m)} {_f(f8[m]['spread_nm'])} nm" for m in default_first(f8)]
        parts.append("Fig. 8 worst peak spread (measured): " + ", ".join(spreads))
    return "".join(f"<p>{p}.</p>" for p in parts)


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def write_instrument_report(
    results: dict[str, Any], out: Path, *, command: str, emulator: bool
) -> Path:
    """Write ``out/report.html`` (the figures first: :func:`write_instrument_figures`)."""
    fails = results["failures"]
    banner = ""
    if fails or results["stopped"]:
        items = "".join(
            f"<li>{html.escape(f['experiment'])} / {html.escape(f['method'])}: "
            f"{html.escape(f['error'])}</li>"
            for f in fails
        )
        stopped = (f"<p>The instrument stopped the run: {html.escape(results['stopped'])}</p>"
                   if results["stopped"] else "")  # fmt: skip
        banner = (f"<div class=warn><b>{len(fails)} trial(s) failed</b>; their figures are "
                  f"missing from the tables.<ul>{items}</ul>{stopped}</div>")  # fmt: skip
    timing = results.get("timing") or {}
    note = timing_note(timing, emulator)
    summary = (
        f"{timing.get('paths', 0)} streamed paths, {timing.get('samples', 0)} samples, worst "
        f"{1e3 * timing.get('worst_deviation_s', 0.0):.3g} ms off their slot"
    )
    speed = results["settings"]["speed_nm_per_s"]
    model = (
        "uncompensated only (no model given)"
        if results["model"] is None
        else f"with the model <code>{html.escape(str(results['model']))}</code>"
    )
    truth = html.escape(results["true_errors"])
    body = f"""<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">
<title>piezocomp reproduce: {html.escape(results["source"])}</title><style>{CSS}</style></head>
<body><h1>The paper's experiments on an instrument</h1>
<p>B. Mokaberi and A. A. G. Requicha, <i>Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation</i>, IEEE T-ASE 5(2), 2008: Table I, Fig. 8 and Fig. 9 on
<b>{html.escape(results["source"])}</b> ({html.escape(results["controller"])}), {model}.
Errors are <b>measured</b> as the paper measured them (image cross-correlation, particle
peaks); true errors: {truth}.</p>
<p>Reproduce it with:</p><pre>{html.escape(command)}</pre>
{banner}
<h2>Table I: back to an area after random moves ({speed:g} nm/s)</h2>
<p class=note>Maximum error over the two areas, mean &plusmn; std over the experiments per
distance that cross-correlation could measure ("n of N" where fewer than all). Areas within
&plusmn;{results["table1_area_half_width_nm"]:.0f} nm of the working area's centre.</p>
{_table1(results)}
{embedded_image(out, "table1.png", "Table I")}
<h2>Fig. 9 and Fig. 8</h2>
{_figures_line(results)}
{embedded_image(out, "fig9.png", "Fig. 9 images")}
{embedded_image(out, "fig8.png", "Fig. 8 traces")}
<h2>Timing of the streamed paths</h2>
<p>{html.escape(summary)}.</p>{f"<p>{html.escape(note)}</p>" if note else ""}
</body></html>
"""
    path = out / "report.html"
    atomic_write_text(path, body)
    return path
