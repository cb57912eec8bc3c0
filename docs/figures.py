"""The figures README.md and docs/ quote, generated from the commands behind them.

A page quotes a run's figures inside a block::

    <!-- figures: SOURCE -->
    ...the table this script renders from docs/figures/generated/SOURCE.json...
    <!-- /figures -->

or one value inline, ``<!-- figure: SOURCE KEY -->1.87<!-- /figure -->``. Each SOURCE
(:data:`SOURCES`) is a command; this script reruns it (``run``) or reads the output folder of
a run made elsewhere (``read``: the long many-seed runs), keeps the figures it quotes in
``docs/figures/generated/SOURCE.json`` (with the command and the package version) and
rewrites every block and inline value of that source in place. ``tests/test_docs_figures.py``
checks that each block and value in the pages is what the last generated output renders: a
figure typed by hand fails it.

Figures not (yet) regenerated this way are in :data:`EARLIER`, the one list of them: their
blocks must say they were measured on an earlier version, and the test knows them by name.
A source whose output is generated leaves that list.

Usage (from the repository's root)::

    python docs/figures.py list
    python docs/figures.py run quick-seed1          # reruns its command (about 3 minutes idle)
    python docs/figures.py read seeds-1-10 DIR --made-with COMMIT  # DIR: a `reproduce
                                                    # --quick --seeds 1-10` folder made by COMMIT
    python docs/figures.py write                    # the pages from the generated outputs
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "src") not in sys.path:  # this tree's package, whatever is installed
    sys.path.insert(0, str(ROOT / "src"))
GENERATED = ROOT / "docs" / "figures" / "generated"
PAGES = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("**/*.md")))

BLOCK = re.compile(r"<!-- figures: (?P<source>[\w.-]+) -->\n(?P<body>.*?)<!-- /figures -->", re.S)
INLINE = re.compile(
    r"<!-- figure: (?P<source>[\w.-]+) (?P<key>[\w.=+-]+) -->(?P<value>[^<]*)<!-- /figure -->"
)
EARLIER_LABEL = "(measured on an earlier version; `python docs/figures.py list` gives the command)"
"""What a block of :data:`EARLIER` says first."""

HEADLINE = ("both", "compensated", "uncompensated")
"""The methods of the tables over seeds, the default first (``samples.json``'s)."""


# ------------------------------------------------------------------ reading a run's outputs
def _f(v: float | None, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _pc(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.0f} %"


def one_run(folder: Path) -> dict[str, str]:
    """The quoted figures of one ``reproduce`` run (``folder/results.json``), formatted as
    the pages quote them, by ``METHOD.FIGURE``."""
    from piezocomp.experiments.contract import default_first
    from piezocomp.experiments.fig10 import outcome_text
    from piezocomp.experiments.results import session_methods

    res = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    v0 = res["paper"]["speed_nm_per_s"]
    rows = [r for r in res["table1"] if r["speed_nm_per_s"] == v0]
    inside = session_methods(res["fig10_drift"]) if "fig10_drift" in res else {}
    session = session_methods(res["drift_session"]) if "drift_session" in res else {}
    out: dict[str, str] = {"command": re.sub(r"--out \S+", "--out DIR", res.get("command", ""))}
    methods = default_first(rows[0]["methods"]) if rows else []
    out["methods"] = " ".join(methods)
    for m in methods:
        cells = [r["methods"][m] for r in rows]
        true = [c["true_max_error_nm"]["mean"] for c in cells]
        meas = [c["max_error_nm"]["mean"] for c in cells]
        out[f"{m}.table1_true_nm"] = _f(None if None in true else max(true))
        out[f"{m}.table1_measured_nm"] = _f(None if None in meas else max(meas))
        if None not in meas and cells:  # the count behind the worst measured mean
            worst = cells[int(np.argmax(meas))]
            n, of = worst["max_error_nm"].get("n"), worst["true_max_error_nm"].get("n")
            if n is not None and of is not None and n < of:
                out[f"{m}.table1_measured_nm"] += f" ({n} of {of})"
        f9 = res["fig9"]["methods"].get(m)
        out[f"{m}.fig9_true_nm"] = _f(f9 and f9["true_error_nm"])
        out[f"{m}.fig9_measured_nm"] = _f(f9 and f9["error_nm"])
        f10 = inside.get(m) if m == "both" else res["fig10"]["methods"].get(m)
        out[f"{m}.fig10"] = "not run" if f10 is None else outcome_text(f10)
        ds = session.get(m)
        ok = ds is not None and "error" not in ds
        none = "not run" if ds is None else "failed"
        out[f"{m}.session_worst_nm"] = _f(ds["true_max_error_nm"]) if ok else none
        out[f"{m}.session_final_nm"] = _f(ds["true_final_error_nm"]) if ok else none
    return out


def _seeds_header(summary: dict) -> dict[str, str]:
    """A ``reproduce --seeds`` run's command (its folder as ``DIR``), seeds, count and failed
    seeds, from its ``samples.json``."""
    return {
        "command": re.sub(r"--out \S+", "--out DIR", summary.get("command", "")),
        "seeds": f"{min(summary['seeds'])}-{max(summary['seeds'])}",
        "n": str(len(summary["seeds"])),
        "failed_seeds": ", ".join(map(str, sorted(summary["failed_seeds"]))) or "none",
    }


def over_seeds(folder: Path) -> dict[str, str]:
    """The quoted figures of a ``reproduce --seeds`` run (``folder/samples.json``): each
    headline figure's median and worst, and over how many seeds, by ``METHOD.FIGURE``."""
    summary = json.loads((folder / "samples.json").read_text(encoding="utf-8"))
    n_seeds = len(summary["seeds"])
    out = _seeds_header(summary)
    for m in HEADLINE:
        for k, st in summary["statistics"].get(m, {}).items():
            fmt = _pc if k in ("fig10_true_success", "session_measuring") else _f
            of = "" if st["n"] in (0, n_seeds) else f" ({st['n']} of {n_seeds})"
            out[f"{m}.{k}"] = (
                "n/a" if st["n"] == 0 else f"{fmt(st['median'])} / {fmt(st['worst'])}{of}"
            )
    return out


def every_method(folder: Path) -> dict[str, str]:
    """A ``reproduce --seeds`` run's figures for every method (each ``folder/seed-N/results.json``):
    Table I and Fig. 9, true and measured, median / worst over the seeds, and Fig. 10's
    assemblies that truly succeeded over all seeds, by ``METHOD.FIGURE``."""
    from piezocomp.experiments.contract import default_first
    from piezocomp.experiments.results import session_methods
    from piezocomp.experiments.samples import headline, statistics

    summary = json.loads((folder / "samples.json").read_text(encoding="utf-8"))
    runs = []
    for seed in summary["seeds"]:
        path = folder / f"seed-{seed}" / "results.json"
        if str(seed) not in summary["failed_seeds"]:
            runs.append(json.loads(path.read_text(encoding="utf-8")))
    v0 = runs[0]["paper"]["speed_nm_per_s"]
    methods = default_first([m for r in runs[0]["table1"] if r["speed_nm_per_s"] == v0
                             for m in r["methods"]])  # fmt: skip
    methods = list(dict.fromkeys(methods))
    out = {**_seeds_header(summary), "methods": " ".join(methods)}
    paper = runs[0]["paper"]  # the paper's own figures, as every results.json holds them
    rows = {
        m: [v[m][0] for v in paper["table1"].values()] for m in ("uncompensated", "compensated")
    }
    out["paper.table1"] = " / ".join(f"{min(v):.2f}-{max(v):.2f}" for v in rows.values())
    out["paper.fig9"] = " / ".join(
        f"{paper['fig9'][m]:g}" for m in ("uncompensated", "compensated")
    )
    st = statistics([headline(r, methods) for r in runs], methods)
    for m in methods:
        for k in ("table1_true_nm", "table1_measured_nm", "fig9_true_nm", "fig9_measured_nm"):
            v = st[m][k]
            of = "" if v["n"] in (0, len(runs)) else f" ({v['n']} of {len(runs)})"
            out[f"{m}.{k}"] = "n/a" if v["n"] == 0 else f"{_f(v['median'])} / {_f(v['worst'])}{of}"
        done = []
        for r in runs:
            f10 = (session_methods(r["fig10_drift"]).get("both") if m == "both" and
                   "fig10_drift" in r else r["fig10"]["methods"].get(m))  # fmt: skip
            done += [] if f10 is None else f10.get("assemblies", [])
        ok = sum(a["true_success"] for a in done)
        out[f"{m}.fig10"] = f"{ok} of {len(done)}" if done else "n/a"
    return out


def fig9_speed(folder: Path) -> dict[str, str]:
    """``benchmarks/fig9_speed_drift.py --json`` (``folder/fig9_speed.json``): Fig. 9's true
    error by scanner, method and speed."""
    data = json.loads((folder / "fig9_speed.json").read_text(encoding="utf-8"))
    out = {"command": data["command"]}
    for row in data["rows"]:
        key = f"{row['preset']}.{row['method']}.{row['speed_nm_per_s']:g}"
        out[key] = f"{row['true_error_nm']:.2f}"
    return out


def floor_families(folder: Path) -> dict[str, str]:
    """``benchmarks/model_floor.py --json`` (``folder/floor.json``): each preset's floor of
    the paper's family and of the extended one, and the coupling found."""
    data = json.loads((folder / "floor.json").read_text(encoding="utf-8"))
    out = {"command": data["command"]}
    for row in data["rows"]:
        for key, value in row.items():
            if "/" in key:
                name = f"{row['preset']}.{row['variant']}.{key}"
                out[name] = f"{value:.2f}" if isinstance(value, float) else str(value)
    return out


def fit_on_truth(folder: Path) -> dict[str, str]:
    """``benchmarks/model_floor.py --fit --json`` (``folder/floor.json``), one row: the
    family's floor and ``piezocomp fit``'s own pipeline on the same TRUE record (``/`` of the
    benchmark's keys read as ``.``)."""
    data = json.loads((folder / "floor.json").read_text(encoding="utf-8"))
    (row,) = data["rows"]
    out = {"command": data["command"], "preset": row["preset"], "variant": row["variant"]}
    for key, value in row.items():
        if "/" in key:
            name = key.replace("/", ".").replace("@", "at").replace("+", ".")
            out[name] = f"{value:.2f}" if isinstance(value, float) else str(value)
    return out


def table_fit_on_truth(fig: dict[str, str]) -> str:
    """``piezocomp fit``'s pipeline against the family's floor on one TRUE record."""
    lines = [
        "| fitted by | paper's family (nm) | `--creep-coupling fit` (nm) |",
        "|---|---|---|",
        "| plain NNLS, true start, 16 plays, 19 time constants 0.05-2000 s (the floor) | "
        f"{fig['16.19at0.05-2000s']} | {fig['16.19at0.05-2000s.coupling']} |",
    ]
    for state in ("rest", "estimate", "auto"):
        for orders, label in (("8x2", "8 x 2"), ("selected", "--select-orders")):
            lines.append(
                f"| `fit --initial-state {state}`, {label}: model kept "
                f"({fig[f'fit.{state}.{orders}.chosen']}) | {fig[f'fit.{state}.{orders}']} | "
                f"{fig[f'fit.{state}.{orders}.coupling']} |"
            )
    if "fit.auto.8x2.tau0.05" in fig:
        lines.append(
            "| `fit --min-time-constant-s 0.05` (the floor's shortest), 8 x 2: model kept "
            f"({fig['fit.auto.8x2.tau0.05.chosen']}) | {fig['fit.auto.8x2.tau0.05']} | "
            f"{fig['fit.auto.8x2.tau0.05.coupling']} |"
        )
    return (
        "\n".join(lines)
        + f"\n\nMax error on the validation path, offset removed; `{fig['preset']}`, one "
        + f"record. `{fig['command']}`\n"
    )


def _without_json(command: str) -> str:
    """A benchmark's command without its ``--json PATH`` (the folder it wrote to is gone) and
    with ``--runs DIR`` for the ``reproduce --seeds`` folder it read."""
    return re.sub(r" --runs \S+", " --runs DIR", re.sub(r" --json \S+", "", command))


def session_limits(folder: Path, file: str = "limits.json") -> dict[str, str]:
    """``benchmarks/drift_filter.py --variants ... --json`` (``folder/limits.json``): each
    variant's worst image, time measuring and sighting spread (median / worst)."""
    data = json.loads((folder / file).read_text(encoding="utf-8"))
    out = {"command": _without_json(data["command"]), "variants": " ".join(data["variants"])}
    for name, v in data["variants"].items():
        for key, scale, fmt in (("worst_image_nm", 1.0, ".2f"), ("measuring", 100.0, ".0f"),
                                ("sighting_spread_nm", 1.0, ".2f"),
                                ("measurement_sigma_nm", 1.0, ".2f")):  # fmt: skip
            pair = v.get(key)  # the sigma: not in outputs made before it was written
            out[f"{name}.{key}"] = (
                "n/a" if pair is None else " / ".join(f"{scale * x:{fmt}}" for x in pair)
            )
        out[f"{name}.n"] = f"{v['images_from']} of {len(v['seeds'])}"
    return out


def error_budget(folder: Path) -> dict[str, str]:
    """``benchmarks/error_budget.py --json`` (``folder/budget.json``): each row's median and
    worst over the seeds, and how many seeds."""
    data = json.loads((folder / "budget.json").read_text(encoding="utf-8"))
    out = {"command": _without_json(data["command"]), "rows": " ".join(data["rows"]),
           "n": str(len(data["seeds"]))}  # fmt: skip
    for key, (med, worst) in data["rows"].items():
        if key == "truth_orders_differ":  # a count: axes of every seed
            out[key] = f"{med:.0f} of {worst:.0f}"
            continue
        digits = 3 if key == "scale_error_percent" else 2
        out[key] = f"{med:.{digits}f} / {worst:.{digits}f}"
    return out


def order_choice(folder: Path) -> dict[str, str]:
    """``benchmarks/order_choice.py --json`` (``folder/orders.json``): each way of choosing
    the orders, the truth's validation error of the candidate it picks (median / worst over
    the axes) and on how many axes that candidate is the truth's best."""
    data = json.loads((folder / "orders.json").read_text(encoding="utf-8"))
    axes = data["axes"]
    keys = sorted({k for r in axes for k in r["validation_nm"]},
                  key=lambda k: tuple(int(n) for n in k.split("x")))  # fmt: skip
    ways = {"early": lambda r: r["chosen"], "final": lambda r: r["final_choice"],
            "truth": lambda r: r["truth_choice"]}  # fmt: skip
    ways.update({f"always.{k}": (lambda r, k=k: k) for k in keys})
    out = {"command": _without_json(data["command"]), "n": str(len(axes)),
           "candidates": " ".join(keys)}  # fmt: skip
    for name, pick in ways.items():
        vals = [r["validation_nm"][pick(r)] for r in axes if pick(r) in r["validation_nm"]]
        best = sum(pick(r) == r["truth_choice"] for r in axes)
        out[name] = f"{np.median(vals):.2f} / {max(vals):.2f}" if vals else "-"
        out[f"{name}.best"] = f"{best} of {len(axes)}"
    return out


def grating_scale(folder: Path) -> dict[str, str]:
    """``benchmarks/grating_scale.py --json`` (``folder/grating.json``): each row's median and
    worst per grating path, and how many seeds."""
    data = json.loads((folder / "grating.json").read_text(encoding="utf-8"))
    paths = next(iter(data["rows"].values()))
    out = {"command": _without_json(data["command"]), "rows": " ".join(data["rows"]),
           "paths": " ".join(paths), "n": str(len(data["seeds"]))}  # fmt: skip
    for key, by_path in data["rows"].items():
        digits = {"validation_max_error_nm": 2, "duration_s": 0}.get(key, 3)
        for path, (med, worst) in by_path.items():
            out[f"{key}.{path}"] = f"{med:.{digits}f} / {worst:.{digits}f}"
    return out


def instrument_budget(folder: Path) -> dict[str, str]:
    """``benchmarks/instrument_budget.py --json`` (``folder/instrument_budget.json``): its
    printed table, the default protocol's minutes by stage and axis (median over the
    seeds), and each protocol's minutes, failed seeds and paired differences to the
    default (median, range)."""
    import statistics

    data = json.loads((folder / "instrument_budget.json").read_text(encoding="utf-8"))
    out = {"command": _without_json(data["command"]), "summary": "\n".join(data["summary"]),
           "n": str(len(data["seeds"]))}  # fmt: skip
    rows = data["rows"]
    default = {r["seed"]: r for r in rows if r["protocol"] == "default"}
    for axis in ("x", "y"):
        stages = [r["stages_min"][axis] for r in default.values() if "stages_min" in r]
        for name in stages[0] if stages else ():
            out[f"stage.{axis}.{name}"] = f"{statistics.median(s[name] for s in stages):.1f}"
    for p in dict.fromkeys(r["protocol"] for r in rows):
        mine = [r for r in rows if r["protocol"] == p]
        mins = [r["minutes"] for r in mine if "minutes" in r]
        out[f"{p}.minutes"] = f"{statistics.median(mins):.0f}" if mins else "n/a"
        out[f"{p}.failed"] = f"{sum(1 for r in mine if r['problems'])} of {len(mine)}"
        for key in ("valid_nm", "table1_nm"):
            d = [r[key] - default[r["seed"]][key] for r in mine
                 if r.get(key) is not None and default[r["seed"]].get(key) is not None
                 and not r["problems"] and not default[r["seed"]]["problems"]]  # fmt: skip
            out[f"{p}.paired_{key}"] = (
                f"{statistics.median(d):+.2f} ({min(d):+.2f} to {max(d):+.2f})" if d else "n/a"
            )
    return out


def scanner_runs(folder: Path) -> dict[str, str]:
    """``benchmarks/reproduce_scanners.py --json`` (``folder/scanners.json``): per scanner,
    each headline figure's median and worst over its seeds, and its runs that exited 0."""
    from piezocomp.experiments.samples import statistics

    data = json.loads((folder / "scanners.json").read_text(encoding="utf-8"))
    runs = data["runs"] if isinstance(data, dict) else data  # older files: the list
    names = list(dict.fromkeys(r["scanner"] for r in runs))
    seeds = sorted({int(r["seed"]) for r in runs})
    command = data["command"] if isinstance(data, dict) else shlex.join(
        ["python", "benchmarks/reproduce_scanners.py", "--only", *names,
         "--seeds", *map(str, seeds)]
    )  # fmt: skip
    out = {"command": _without_json(command), "scanners": "|".join(names),
           "seeds": " ".join(map(str, seeds))}  # fmt: skip
    for i, name in enumerate(names):
        mine = [r for r in runs if r["scanner"] == name]
        out[f"{i}.n"] = str(len(mine))
        out[f"{i}.exit0"] = str(sum(r["exit_status"] == 0 for r in mine))
        for m, by in statistics([r["headline"] for r in mine]).items():
            for k, st in by.items():
                fmt = _pc if k in ("fig10_true_success", "session_measuring") else _f
                out[f"{i}.{m}.{k}"] = (
                    "n/a" if st["n"] == 0 else f"{fmt(st['median'])} / {fmt(st['worst'])}"
                )
    return out


# ------------------------------------------------------------------ rendering the blocks
def _pair(a: str, b: str) -> str:
    return a if a == b and a in ("not run", "failed") else f"{a} / {b}"


def table_one_run(fig: dict[str, str]) -> str:
    """One sample's figures, every method, the default first."""
    lines = [
        "| method | Table I, worst distance (true / measured, nm) | Fig. 9 (true / measured, nm) "
        "| Fig. 10 | drift session, worst / last image (true, nm) |",
        "|---|---|---|---|---|",
    ]
    for m in fig["methods"].split():
        session = _pair(fig[f"{m}.session_worst_nm"], fig[f"{m}.session_final_nm"])
        lines.append(
            f"| `{m}` | {fig[f'{m}.table1_true_nm']} / {fig[f'{m}.table1_measured_nm']} "
            f"| {fig[f'{m}.fig9_true_nm']} / {fig[f'{m}.fig9_measured_nm']} "
            f"| {fig[f'{m}.fig10']} | {session} |"
        )
    note = (
        "Table I: each method's worst distance, true and measured each on its own (they can "
        "be different distances); a measured mean is over the experiments whose images could "
        "be registered (`table1.png` and the report say how many). "
    )
    return "\n".join(lines) + f"\n\n{note}`{fig['command']}`\n"


def table_over_seeds(fig: dict[str, str]) -> str:
    """The headline figures over seeds, median / worst, the default first."""
    cols = (
        ("table1_true_nm", "Table I, true (nm)"),
        ("table1_measured_nm", "Table I, measured (nm)"),
        ("fig9_true_nm", "Fig. 9, true (nm)"),
        ("fig10_true_success", "Fig. 10 success"),
        ("session_true_worst_nm", "session, worst image (nm)"),
        ("session_true_final_nm", "session, last image (nm)"),
        ("session_measuring", "time measuring"),
    )
    lines = [
        "| method | " + " | ".join(c for _, c in cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    for m in HEADLINE:
        if f"{m}.table1_true_nm" in fig:
            lines.append(f"| `{m}` | " + " | ".join(fig[f"{m}.{k}"] for k, _ in cols) + " |")
    return (
        "\n".join(lines)
        + f"\n\nMedian / worst over seeds {fig['seeds']} ({fig['n']} runs; failed: "
        + f"{fig['failed_seeds']}): `{fig['command']}`\n"
    )


def table_every_method(fig: dict[str, str]) -> str:
    """Every method's figures over seeds, median / worst, the default first, below the
    paper's."""
    cols = ("table1_true_nm", "table1_measured_nm", "fig9_true_nm", "fig9_measured_nm")
    lines = [
        "| method | Table I, true (nm) | Table I, measured (nm) | Fig. 9, true (nm) | "
        "Fig. 9, measured (nm) | Fig. 10, assemblies truly placed |",
        "|---|---|---|---|---|---|",
        f"| the paper, without / with its compensation (a drift-compensated AFM) | "
        f"{fig['paper.table1']} | | {fig['paper.fig9']} | | fails / succeeds |",
    ]
    for m in fig["methods"].split():
        cells = [fig[f"{m}.{k}"] for k in cols]
        name = f"**`{m}`**" if m == "both" else f"`{m}`"
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {fig[f'{m}.fig10']} |")
    return (
        "\n".join(lines)
        + f"\n\nMedian / worst over seeds {fig['seeds']} ({fig['n']} runs; failed: "
        + f"{fig['failed_seeds']}); Fig. 10 over every seed's assemblies. `{fig['command']}`\n"
    )


def table_floor_families(fig: dict[str, str]) -> str:
    """The floor of both families fitted to the truth, by preset and setting."""
    lines = [
        "| scanner | setting | paper's family (nm) | extended family (nm) | beta found |",
        "|---|---|---|---|---|",
    ]
    for key in sorted(k for k in fig if k.count(".") >= 2 and "+" not in k and k.count("/") == 1
                      and not k.endswith(("/beta", "/family"))):  # fmt: skip
        preset, variant, setting = key.split(".", 2)
        scanner = preset if variant == "base" else f"{preset} ({variant})"
        lines.append(
            f"| `{scanner}` | {setting} | {fig[key]} | {fig.get(key + '+coupling', 'n/a')} "
            f"| {fig.get(key + '/beta', 'n/a')} |"
        )
    return "\n".join(lines) + f"\n\n`{fig['command']}`\n"


def table_floor_asymmetry(fig: dict[str, str]) -> str:
    """The extended family's floor with and without Kuhnen's dead zones, by scanner variant."""
    lines = [
        "| scanner | setting | extended family (nm) | with 4 dead zones (nm) | the record's "
        "held-out part prefers them |",
        "|---|---|---|---|---|",
    ]
    for key in sorted(k for k in fig if k.endswith("+coupling+asymmetry")):
        base = key[: -len("+asymmetry")]
        preset, variant, setting = key[: -len("+coupling+asymmetry")].split(".", 2)
        scanner = preset if variant == "base" else f"{preset} ({variant})"
        lines.append(
            f"| `{scanner}` | {setting} | {fig[base]} | {fig[key]} | {fig[key + '/kept']} |"
        )
    return (
        "\n".join(lines)
        + "\n\nMax error on the validation path, offset removed; one record each. "
        + f"`{fig['command']}`\n"
    )


SESSION_VARIANTS = {
    "identified": "the default model (identified without a sensor)",
    "oracle": "the model family fitted to the true extension in its place (diagnosis)",
    "ideal": "no creep or hysteresis in the scanner, no compensator (diagnosis)",
}


def session_label(name: str) -> str:
    """A ``drift_filter.py`` variant in words (its parts joined by ``+``)."""
    parts = name.split("+")
    base = next((p for p in parts if p in SESSION_VARIANTS), "identified")
    words = [SESSION_VARIANTS[base] if base != "identified" or parts == [base]
             else "the default model"]  # fmt: skip
    for p in parts:
        nm = p.split("=")[-1]
        if p == "areas":
            words.append("the session's images of its areas drift sightings too")
        elif p == "fixed-order":
            words.append("the drift's order not learnt (`learn_order=False`)")
        elif p == "joint-fit":
            words.append(
                "its noise fitted with a measurement noise of its own (`learn_given_sigma=False`)"
            )
        elif p.startswith("approach="):
            words.append(f"every window entered from {nm} nm before it")
        elif p.startswith("tolerance="):
            words.append(f"measuring at a drift tolerance of {nm} nm")
    return ", ".join(words)


def table_session_limits(fig: dict[str, str]) -> str:
    """The drift session's worst image, time measuring and sighting spread by variant."""
    keys = ["worst_image_nm", "measuring", "sighting_spread_nm", "n"]
    head = ("| session | worst image (true, nm) | measuring (%) | sightings' spread about each "
            "landmark's mean (nm) | seeds with images |")  # fmt: skip
    first = fig["variants"].split()[0]
    if fig.get(f"{first}.measurement_sigma_nm", "n/a") != "n/a":
        keys.insert(3, "measurement_sigma_nm")
        head = head.replace(" | seeds", " | a sighting's noise as learnt (nm) | seeds")
    lines = [head, "|---" * (len(keys) + 1) + "|"]
    for name in fig["variants"].split():
        cells = [session_label(name)] + [fig[f"{name}.{k}"] for k in keys]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + f"\n\nMedian / worst over the seeds. `{fig['command']}`\n"


BUDGET_ROWS = {
    "identified": "identified without a sensor (the default model)",
    "identified_true_scale": "the same, its scale error removed",
    "identified_rls": "the RLS estimate of the same identification (the estimation stage's RLS)",
    "identified_truth_orders": "the same, its orders chosen on the truth (the orders replaced)",
    "true_loop": "identified from the true loop and `h(y)` (the loop stage replaced)",
    "fit_record_paper": "the paper's family fitted to the true extension of the waveform",
    "fit_record_extended": "the extended family fitted likewise",
    "fit_oracle": "the extended family fitted with 12 minutes more record (the `oracle`)",
    "identified_no_drift": "identified on the drift-free twin of each sample",
}


def table_error_budget(fig: dict[str, str]) -> str:
    """The identification's validation error with one stage replaced at a time."""
    lines = ["| model | validation max error (nm) |", "|---|---|"]
    for key in fig["rows"].split():
        if key in BUDGET_ROWS:
            lines.append(f"| {BUDGET_ROWS[key]} | {fig[key]} |")
    lines.append(f"| the grating's scale error, every axis (%) | {fig['scale_error_percent']} |")
    if "truth_orders_differ" in fig:
        lines.append(f"| axes where the truth chose other orders | {fig['truth_orders_differ']} |")
    return (
        "\n".join(lines)
        + f"\n\nMedian / worst over {fig['n']} seeds of each seed's worse axis. "
        + f"`{fig['command']}`\n"
    )


def table_order_choice(fig: dict[str, str]) -> str:
    """Each way of choosing the orders against the truth."""
    rows = [
        ("on the held-out heights at the choice (the default's orders)", "early"),
        ("on the held-out heights of the final models, the same rule", "final"),
        *((f"always {k}", f"always.{k}") for k in fig["candidates"].split()),
        ("on the truth (diagnosis)", "truth"),
    ]
    lines = [
        "| orders chosen | validation max error of the model (nm) | axes where it is the "
        "truth's best |",
        "|---|---|---|",
    ]
    lines += [f"| {label} | {fig[key]} | {fig[key + '.best']} |" for label, key in rows]
    return (
        "\n".join(lines)
        + "\n\nEach candidate run alone through the whole chain; median / worst over "
        + f"{fig['n']} axes. `{fig['command']}`\n"
    )


GRATING_ROWS = {
    "read_on_truth_percent": "the grating's fit on the true extension, off 1 (%)",
    "own_path_percent": "the scaled model on the grating's own passes, off 1 (%)",
    "validation_percent": "the scaled model on the validation trajectory, off 1 (%)",
    "validation_max_error_nm": "validation max error, each seed's worse axis (nm)",
    "duration_s": "the grating's scan, one axis (s)",
}
"""The grating-scale table's row labels, by the benchmark's keys."""


def table_grating_scale(fig: dict[str, str]) -> str:
    """The grating's scale on each path: its precision, and where it is used."""
    paths = fig["paths"].split()
    lines = ["| | " + " | ".join(f"`{p}`" for p in paths) + " |", "|---|" + "---|" * len(paths)]
    for key in fig["rows"].split():
        cells = " | ".join(fig[f"{key}.{p}"] for p in paths)
        lines.append(f"| {GRATING_ROWS.get(key, key)} | {cells} |")
    return (
        "\n".join(lines)
        + f"\n\nMedian / worst over {fig['n']} seeds (every axis, magnitudes; the error: each "
        + f"seed's worse axis). `{fig['command']}`\n"
    )


def table_fig9_speed(fig: dict[str, str]) -> str:
    """Fig. 9's true error against the speed, with and without drift."""
    speeds = sorted({float(k.split(".", 2)[2]) for k in fig if k != "command"})
    presets = sorted({k.split(".", 1)[0] for k in fig if k != "command"})
    methods = ("compensated", "uncompensated")
    lines = [
        "| scanner | method | " + " | ".join(f"{v:g} nm/s" for v in speeds) + " |",
        "|---|---|" + "---|" * len(speeds),
    ]
    for p in presets:
        for m in methods:
            cells = [fig.get(f"{p}.{m}.{v:g}", "n/a") for v in speeds]
            lines.append(f"| `{p}` | `{m}` | " + " | ".join(cells) + " |")
    return "\n".join(lines) + f"\n\n`{fig['command']}`\n"


def table_instrument_budget(fig: dict[str, str]) -> str:
    """The instrument budget's printed table, as the command printed it."""
    return f"```\n$ {fig['command']}\n{fig['summary']}\n```\n"


STAGES = {
    "overview": "overview (128 lines over 2 um at the waveform's 250 nm/s)",
    "line search": "line search",
    "settling": "settling on the line",
    "record and check": "record and its check",
    "calibration cycles": "calibration cycles",
    "extra lines": "the second line (its own overview, search, settling and record)",
    "grating": "grating",
}
"""The instrument-time table's rows, by the stages of ``instrument_s``."""


def _seed_list(seeds: list[int]) -> str:
    """``1-10`` for consecutive seeds, else the seeds listed."""
    s = sorted(seeds)
    if s == list(range(s[0], s[-1] + 1)):
        return f"{s[0]}-{s[-1]}"
    return ", ".join(str(v) for v in s)


def identification_over_seeds(folder: Path) -> dict[str, str]:
    """Each axis' sensorless identification in a ``reproduce --seeds`` run (each
    ``folder/seed-N/results.json``'s ``identification``): the batch (default) and RLS models'
    validation against the true extension, the batch's with the scale removed, its held-out
    heights with the drift along the line taken out and not, median / worst over the seeds,
    by ``AXIS.FIGURE``; the seeds whose line drift was kept."""
    summary = json.loads((folder / "samples.json").read_text(encoding="utf-8"))
    axes: dict[str, dict[str, list[float]]] = {}
    kept = read = failed = 0
    seeds = [s for s in summary["seeds"] if str(s) not in summary["failed_seeds"]]
    for seed in seeds:
        res = json.loads((folder / f"seed-{seed}" / "results.json").read_text(encoding="utf-8"))
        for axis, a in res["identification"]["axes"].items():
            sl = a["sensorless"]
            if "compensated" not in sl:  # every line failed: no model of this axis
                failed += 1
                continue
            row = axes.setdefault(axis, {})
            for key, value in (
                ("batch_max", sl["compensated"]["validation_max_error_nm"]),
                ("batch_rms", sl["compensated"]["validation_rms_error_nm"]),
                ("batch_max_scaled", sl["compensated"]["validation_max_error_after_scale_nm"]),
                ("rls_max", sl["rls"]["validation_max_error_nm"]),
            ):
                row.setdefault(key, []).append(float(value))
            drift = sl.get("line_drift") or {}
            for key in ("heldout_without", "heldout_with"):
                v = drift.get(f"heldout_rms_{key.split('_')[1]}_nm")
                if v is not None:
                    row.setdefault(key, []).append(float(v))
            kept += bool(drift.get("kept"))
            read += 1
    out = {**_seeds_header(summary), "line_drift_kept": f"{kept} of {read}",
           "axes_failed": str(failed)}  # fmt: skip
    for axis, row in axes.items():
        for key, v in row.items():
            out[f"{axis}.{key}"] = f"{_f(float(np.median(v)))} / {_f(max(v))}"
    return out


def table_identification(fig: dict[str, str]) -> str:
    """Each axis' identification against the truth, median / worst over the seeds."""
    lines = [
        "| axis | batch (the default model), max | RMS | max, the scale removed | RLS, max "
        "| held-out heights, drift along the line not taken out / taken out |",
        "|---|---|---|---|---|---|",
    ]
    for axis in ("x", "y"):
        if f"{axis}.batch_max" in fig:
            held = (f"{fig[f'{axis}.heldout_without']} against {fig[f'{axis}.heldout_with']}"
                    if f"{axis}.heldout_with" in fig else "n/a")  # fmt: skip
            lines.append(
                f"| {axis} | {fig[f'{axis}.batch_max']} | {fig[f'{axis}.batch_rms']} | "
                f"{fig[f'{axis}.batch_max_scaled']} | {fig[f'{axis}.rls_max']} | {held} |"
            )
    return (
        "\n".join(lines)
        + f"\n\nnm, median / worst over seeds {fig['seeds']}; the drift along the line was kept "
        + f"on {fig['line_drift_kept']} axes"
        + (
            f"; {fig['axes_failed']} axes gave no model on any line"
            if fig.get("axes_failed", "0") != "0"
            else ""
        )
        + f". `{fig['command']}`\n"
    )


def oracle_in_drift(folder: Path) -> dict[str, str]:
    """``benchmarks/oracle_in_drift.py --json`` (``folder/oracle.json``): the headline figures
    with the model family fitted to the truth, median / worst over the seeds, by
    ``METHOD.FIGURE``."""
    from piezocomp.experiments.samples import statistics

    data = json.loads((folder / "oracle.json").read_text(encoding="utf-8"))
    seeds = [int(r["seed"]) for r in data]
    stats = statistics([r["headline"] for r in data], ("compensated", "both"))
    out = {"seeds": _seed_list(seeds), "n": str(len(seeds))}
    for m, figs in stats.items():
        for k, st in figs.items():
            fmt = _pc if k in ("fig10_true_success", "session_measuring") else _f
            out[f"{m}.{k}"] = "n/a" if st["n"] == 0 else f"{fmt(st['median'])} / {fmt(st['worst'])}"
    runs = [folder / f"seed-{seed}" / "results.json" for seed in seeds]
    if all(r.is_file() for r in runs):  # the default's run of the same seeds beside it
        from piezocomp.experiments.samples import headline

        for key in ("table1_true_nm", "session_true_worst_nm"):
            mine = [headline(json.loads(r.read_text(encoding="utf-8")))["both"][key]
                    for r in runs]  # fmt: skip
            pairs = [(a, o["headline"]["both"][key]) for a, o in zip(mine, data, strict=True)]
            d = [a - b for a, b in pairs if a is not None and b is not None]
            if d:
                out[f"default_minus.{key}"] = (
                    f"{np.median(d):.2f} ({min(d):.2f} to {max(d):.2f}, {len(d)} seeds)"
                )
    return out


def table_oracle_in_drift(fig: dict[str, str], source: str = "oracle-in-drift") -> str:
    """The oracle's headline figures, inside the drift compensator and outside it."""
    title = "the model family fitted to the truth"
    if source == "oracle-record-only":
        title = "the family fitted to the truth of the identification's record alone"
    lines = [
        f"| {title} (`oracle`) | Table I | Table I, measured | Fig. 9 "
        "| Fig. 10 success | 5-minute session, worst image | time measuring |",
        "|---|---|---|---|---|---|---|",
    ]
    for m, name in (("both", "inside the drift compensator"), ("compensated", "alone")):
        cells = [fig[f"{m}.{k}"] for k in ("table1_true_nm", "table1_measured_nm",
                 "fig9_true_nm", "fig10_true_success", "session_true_worst_nm",
                 "session_measuring")]  # fmt: skip
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    paired = ""
    if "default_minus.table1_true_nm" in fig:
        paired = (
            "Each seed's identified default (`both`, its `reproduce --quick` run of the same "
            f"seed) minus this: Table I {fig['default_minus.table1_true_nm']} nm, the session's "
            f"worst image {fig.get('default_minus.session_true_worst_nm', 'n/a')} nm (median, "
            "range). "
        )
    return (
        "\n".join(lines)
        + f"\n\n{paired}True errors (Table I also measured), median / worst over seeds "
        + f"{fig['seeds']} ({fig['n']} a scanner); Fig. 10: the seeds' success rates. "
        + f"`{_without_json(SOURCES[source].command)}`\n"
    )


def table1_budget(folder: Path) -> dict[str, str]:
    """``benchmarks/table1_budget.py --json`` (``folder/table1_budget.json``): Table I inside
    the drift compensator split into the scanner's part and the drift estimate's, median /
    worst over the seeds."""
    d = json.loads((folder / "table1_budget.json").read_text(encoding="utf-8"))
    out = {"command": _without_json(d["command"]), "n": str(len(d["seeds"]))}
    for key, (median, worst) in d["statistics"].items():
        out[key] = f"{median:.2f} / {worst:.2f}"
    return out


TABLE1_PARTS = {
    "true": "Table I, true (the headline's)",
    "sum_of_parts": "the sum of the two parts (a check: the same)",
    "scanner_alone": "the scanner's part alone (what a perfect drift estimate would leave)",
    "drift_alone": "the drift estimate's part alone (the scanner's taken as zero)",
    "scanner_rms": "the scanner's part, RMS change between two visits",
    "drift_rms": "the drift estimate's part, RMS change between two visits",
    "correlation": "uncentred correlation of the two parts' changes (median / largest)",
}


def table_table1_budget(fig: dict[str, str]) -> str:
    """Table I's parts, median / worst over the seeds."""
    lines = ["| figure (nm; the correlation: no unit) | median / worst (largest) |", "|---|---|"]
    lines += [f"| {name} | {fig[key]} |" for key, name in TABLE1_PARTS.items() if key in fig]
    return "\n".join(lines) + f"\n\nOver {fig['n']} seeds. `{fig['command']}`\n"


def run_timing(folder: Path) -> dict[str, str]:
    """A ``reproduce --seeds`` run's computing time (each ``folder/seed-N/results.json``'s
    ``timing_s`` and ``stages_s``): a sample's wall-clock time, median / worst, and each
    stage's processor time (median over the seeds) and share."""
    summary = json.loads((folder / "samples.json").read_text(encoding="utf-8"))
    seeds = [s for s in summary["seeds"] if str(s) not in summary["failed_seeds"]]
    runs = [json.loads((folder / f"seed-{s}" / "results.json").read_text(encoding="utf-8"))
            for s in seeds]  # fmt: skip
    runs = [r for r in runs if "stages_s" in r and "timing_s" in r]  # older runs: neither
    total = [r["timing_s"]["total_s"] for r in runs]
    stages = list(dict.fromkeys(k for r in runs for k in r["stages_s"]))
    cpu = [sum(st["cpu_s"] for st in r["stages_s"].values()) for r in runs]
    out = {**_seeds_header(summary), "total_s": f"{np.median(total):.0f} / {max(total):.0f}",
           "cpu_s": f"{np.median(cpu):.0f} / {max(cpu):.0f}",
           "stages": "|".join(stages)}  # fmt: skip
    for stage in stages:
        c = [r["stages_s"].get(stage, {}).get("cpu_s", 0.0) for r in runs]
        share = [v / t for v, t in zip(c, cpu, strict=True)]
        key = stage.replace(": ", ".").replace(" ", "_")
        out[f"{key}.jobs"] = str(max(r["stages_s"].get(stage, {}).get("n", 0) for r in runs))
        out[f"{key}.cpu_s"] = f"{np.median(c):.0f}"
        out[f"{key}.share"] = f"{100 * np.median(share):.0f} %"
    return out


def table_run_timing(fig: dict[str, str]) -> str:
    """A sample's computing time and where it goes."""
    lines = [
        f"A sample of `{fig['command']}` took {fig['total_s']} s on the clock (median / worst "
        f"over seeds {fig['seeds']}) on the development machine (two cores, x86_64, Python "
        f"3.11; the run's libraries and processor are in docs/figures/generated/timing.json, "
        f"and other jobs ran beside it at times), {fig['cpu_s']} s of processor time over its "
        "jobs; on an idle machine it is faster, with another heavy job on the cores up to "
        "twice as long. Where the processor time went (`stages_s`, median over the seeds):",
        "",
        "| stage (`stages_s`) | jobs | processor time | share |",
        "|---|---|---|---|",
    ]
    for stage in fig["stages"].split("|"):
        key = stage.replace(": ", ".").replace(" ", "_")
        lines.append(f"| `{stage}` | {fig[key + '.jobs']} | {fig[key + '.cpu_s']} s | "
                     f"{fig[key + '.share']} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def fig10_runs(folder: Path) -> dict[str, str]:
    """``benchmarks/fig10_failures.py --json`` (``folder/fig10.json``): the assemblies truly
    placed and each kind of failure, over its seeds."""
    d = json.loads((folder / "fig10.json").read_text(encoding="utf-8"))
    rows = [r for r in d["rows"] if r.get("model", "sensorless") == "sensorless"]
    out = {"command": _without_json(d["command"]), "seeds": _seed_list(d["seeds"]),
           "placed": f"{sum(r['kind'] == 'placed' for r in rows)} of {len(rows)}"}  # fmt: skip
    for kind in ("unseen", "seen", "lost", "stopped"):
        out[kind] = str(sum(r["kind"] == kind for r in rows))
    return out


def table_fig10_runs(fig: dict[str, str]) -> str:
    """The assemblies placed, and the failures by kind."""
    return (
        f"{fig['placed']} assemblies truly placed over seeds {fig['seeds']} (failed: unseen "
        f"{fig['unseen']}, seen {fig['seen']}, lost {fig['lost']}, stopped {fig['stopped']}). "
        f"`{fig['command']}`\n"
    )


def core_speed(folder: Path) -> dict[str, str]:
    """``benchmarks/bench_core.py --json`` (``folder/bench.json``): the kernels' throughput."""
    d = json.loads((folder / "bench.json").read_text(encoding="utf-8"))
    return {
        "command": _without_json(d["command"]),
        "orders": f"N_H = {d['n_play']}, N_c = {d['n_creep']}, {d['n_samples']:.0e} samples",
        "machine": f"{d['machine']}, Python {d['python']}",
        "inverse": f"{d['inverse_samples_per_s'] / 1e6:.0f}",
        "forward": f"{d['forward_samples_per_s'] / 1e6:.0f}",
        "reference": f"{d['reference_inverse_samples_per_s'] / 1e6:.2f}",
        "speedup": f"{d['inverse_speedup_over_reference']:.0f}",
        "step_us": f"{d['stream_step_us']:.2f}",
        "asym_zones": f"{d['asymmetric_dead_zones']}",
        "asym_forward": f"{d['asymmetric_forward_samples_per_s'] / 1e6:.0f}",
        "asym_inverse": f"{d['asymmetric_inverse_samples_per_s'] / 1e6:.0f}",
    }


PIEZO_MODELS = {
    "baseline_plain_pi10": "plain PI, 10 operators (baseline)",
    "ours": "ours (the model `fit` writes)",
    "ours_refined": "ours, the refined model of the selected orders",
    "reference_plain_nnls": "the same family by plain NNLS (reference)",
    "ours_start_estimated": "ours, its rest command estimated (`--initial-state estimate`)",
    "ours_auto": "ours, the state the held-out part chose (`--initial-state auto`, the default)",
}
"""The models of ``benchmarks/piezo_record.py``'s prediction of the other record."""


def piezo_record(folder: Path) -> dict[str, str]:
    """``benchmarks/piezo_record.py --json`` (``folder/piezo.json``): the held-out figures on
    the fitting record and each model's prediction of the instrument's other record."""
    d = json.loads((folder / "piezo.json").read_text(encoding="utf-8"))
    out = {"command": _without_json(d["command"])}
    out["ours.orders"] = f"N_H={d['ours']['n_play']}, N_c={d['ours']['n_creep']}"
    out["ours.validation"] = f"{d['ours']['validation']['rms_percent_of_range']:.3f}"
    out["baseline.validation"] = (
        f"{d['baseline_plain_pi10']['validation']['rms_percent_of_range']:.3f}"
    )
    for kind, fit in d["ours"]["by_initial_state"].items():
        kept = {"linear": fit["nnls"], "refined": fit["refined"], "reference": fit["reference"],
                "asymmetric": fit["asymmetry"]}  # fmt: skip
        val = kept[fit["chosen"]]["validation"]["rms_percent_of_range"]
        out[f"ours.{kind}.validation"] = f"{val:.3f}"
        out[f"ours.{kind}.chosen"] = fit["chosen"]
        if fit["asymmetry"] is not None:
            sym = 100 * fit["asymmetry"]["base_validation_rms_nm"] / fit["output_range_nm"]
            out[f"ours.{kind}.symmetric_validation"] = f"{sym:.3f}"
            out[f"ours.{kind}.asymmetric_base"] = fit["asymmetry"]["base"]
        ref = fit["reference"]["validation"]["rms_percent_of_range"]
        out[f"reference.{kind}.validation"] = f"{ref:.3f}"
        out[f"ours.{kind}.rest_command_nm"] = f"{fit['rest_command_nm']:.0f}"
        out[f"ours.{kind}.state"] = fit["initial_state"]
        out[f"ours.{kind}.orders"] = f"N_H={fit['n_play']}, N_c={fit['n_creep']}"
    other = d["other_record"]
    out["other.parts"] = str(len(other["parts"]))
    for name, starts in other["models"].items():
        for start, pred in starts.items():
            cells = [f"{p['rms_percent_of_range']:.2f}" for p in pred["parts"]]
            out[f"other.{name}.{start.replace(' ', '_')}"] = " / ".join(cells)
    for row in d.get("asymmetry_probe", []):
        k = row["dead_zones"]
        out[f"asym.{k}.validation"] = f"{row['validation_percent_of_range']:.3f}"
        out[f"asym.{k}.other"] = " / ".join(f"{x:.2f}" for x in row["other_parts_percent_of_range"])
    out["asym.rows"] = " ".join(str(r["dead_zones"]) for r in d.get("asymmetry_probe", []))
    base = other["models"]["baseline_plain_pi10"]["as fitted"]["parts"]
    ours = other["models"]["ours"]["as fitted"]["parts"]
    out["other.ours_below_baseline"] = " / ".join(
        f"{100 * (1 - o['rms_nm'] / b['rms_nm']):.0f}" for o, b in zip(ours, base, strict=True)
    )
    return out


def table_piezo_record(fig: dict[str, str]) -> str:
    """Each model's prediction of the instrument's other record, part by part."""
    lines = [
        "| model | started as its fit assumed the fitting record started | state from its first "
        "2 s |",
        "|---|---|---|",
    ]
    for name, label in PIEZO_MODELS.items():
        cells = f"{fig[f'other.{name}.as_fitted']} | {fig[f'other.{name}.estimate']}"
        lines.append(f"| {label} | {cells} |")
    return (
        "\n".join(lines)
        + f"\n\nRms error, % of the other record's output range, on its {fig['other.parts']} "
        + "parts (after its first 2 s, from which its sensor offset is found). Ours is "
        + f"{fig['other.ours_below_baseline']} % below the baseline. `{fig['command']}`\n"
    )


def table_piezo_asymmetry(fig: dict[str, str]) -> str:
    """The asymmetry probe of ``benchmarks/piezo_record.py``: dead zones on the reference."""
    lines = [
        "| one-sided dead zones added | held out (% of range) | the other record's parts "
        "(% of range) |",
        "|---|---|---|",
    ]
    for k in fig["asym.rows"].split():
        label = "none (the reference)" if k == "0" else k
        lines.append(f"| {label} | {fig[f'asym.{k}.validation']} | {fig[f'asym.{k}.other']} |")
    return "\n".join(lines) + f"\n\nRms error. `{fig['command']}`\n"


def table_core_speed(fig: dict[str, str]) -> str:
    """The kernels' throughput against the targets."""
    return (
        "| figure | measured | target |\n|---|---|---|\n"
        f"| inverse | {fig['inverse']} M samples/s | >= 20 M |\n"
        f"| forward | {fig['forward']} M samples/s | |\n"
        f"| plain-Python reference inverse | {fig['reference']} M samples/s | |\n"
        f"| inverse / reference | {fig['speedup']}x | >= 100x |\n"
        f"| streaming step (one sample) | {fig['step_us']} us | <= 5 us |\n"
        f"| forward, creep coupling and {fig['asym_zones']} dead zones (eq 8') | "
        f"{fig['asym_forward']} M samples/s | |\n"
        f"| inverse, creep coupling and {fig['asym_zones']} dead zones (eq 8') | "
        f"{fig['asym_inverse']} M samples/s | >= 20 M |\n\n"
        f"{fig['orders']}, {fig['machine']}: `{fig['command']}`\n"
    )


def table_instrument_time(fig: dict[str, str]) -> str:
    """The default identification's instrument time by stage and axis."""
    lines = ["| stage | x (min) | y (min) |", "|---|---|---|"]
    for key, label in STAGES.items():
        lines.append(f"| {label} | {fig[f'stage.x.{key}']} | {fig[f'stage.y.{key}']} |")
    lines.append(f"| **total** | **{fig['stage.x.total']}** | **{fig['stage.y.total']}** |")
    return (
        "\n".join(lines)
        + f"\n\nMedian over {fig['n']} seeds of the `default` protocol of `{fig['command']}`.\n"
    )


def table_scanner_runs(fig: dict[str, str]) -> str:
    """The experiments on benchmark scanners: per scanner, the median of each method and the
    default's median / worst."""

    def med(key: str) -> str:
        return fig[key].split(" / ")[0]

    lines = [
        "| scanner | Table I worst d (nm) | Fig. 9 (nm) | Fig. 10, both | session, both "
        "(measuring) | exit status 0 |",
        "|---|---|---|---|---|---|",
    ]
    for i, name in enumerate(fig["scanners"].split("|")):
        cells = []
        for k in ("table1_true_nm", "fig9_true_nm"):
            cells.append(f"{med(f'{i}.uncompensated.{k}')} / {med(f'{i}.compensated.{k}')} / "
                         f"**{fig[f'{i}.both.{k}']}**")  # fmt: skip
        cells.append(fig[f"{i}.both.fig10_true_success"])
        cells.append(f"{fig[f'{i}.both.session_true_worst_nm']} nm "
                     f"({fig[f'{i}.both.session_measuring']})")  # fmt: skip
        cells.append(f"{fig[f'{i}.exit0']} of {fig[f'{i}.n']}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    seeds = fig["seeds"].split()
    return (
        "\n".join(lines)
        + "\n\nTrue errors: the uncompensated and compensated medians, then **`both`'s "
        + "median / worst**; Fig. 10 and the session with `both`, median / worst; over seeds "
        + f"{seeds[0]}-{seeds[-1]} ({len(seeds)} a scanner). `{fig['command']}`\n"
    )


@dataclass(frozen=True)
class Source:
    """A command whose figures the pages quote.

    Attributes
    ----------
    command : str
        The command that makes its output folder (``{out}``: the folder), from the root.
    read : callable
        The quoted figures from that folder.
    render : callable
        A block's text from the figures.
    minutes : float
        About how long ``command`` takes on an idle two-core machine.
    """

    command: str
    read: Callable[[Path], dict[str, str]]
    render: Callable[[dict[str, str]], str]
    minutes: float


SOURCES: dict[str, Source] = {
    "quick-seed1": Source(
        "piezocomp reproduce --quick --seed 1 --no-progress --out {out}", one_run,
        table_one_run, 3.0,
    ),
    "seeds-1-10": Source(
        "piezocomp reproduce --quick --seeds 1-10 --no-progress --out {out}", over_seeds,
        table_over_seeds, 25.0,
    ),
    "seeds-61-70": Source(
        "piezocomp reproduce --quick --seeds 61-70 --no-progress --out {out}", over_seeds,
        table_over_seeds, 25.0,
    ),
    "methods-1-10": Source(
        "piezocomp reproduce --quick --seeds 1-10 --no-progress --out {out}", every_method,
        table_every_method, 25.0,
    ),
    "methods-61-70": Source(
        "piezocomp reproduce --quick --seeds 61-70 --no-progress --out {out}", every_method,
        table_every_method, 25.0,
    ),
    "fig9-speed": Source(
        "python benchmarks/fig9_speed_drift.py --seeds 1 2 --json {out}/fig9_speed.json",
        fig9_speed, table_fig9_speed, 1.0,
    ),
    "session-limits": Source(
        "python benchmarks/drift_filter.py --runs DIR --seeds 1-10 --variants identified "
        "fixed-order+joint-fit tolerance=0.35 tolerance=0.75 tolerance=1.0 areas approach=400 "
        "oracle ideal --json {out}/limits.json",
        session_limits, table_session_limits, 5.0,
    ),
    "session-20": Source(
        "python benchmarks/drift_filter.py --runs DIR --seeds 1-10 --minutes 20 --variants "
        "identified fixed-order+joint-fit tolerance=0.75 areas --json {out}/session20.json",
        lambda folder: session_limits(folder, "session20.json"), table_session_limits, 4.0,
    ),
    "error-budget": Source(
        "python benchmarks/error_budget.py --seeds 1-10 --json {out}/budget.json",
        error_budget, table_error_budget, 45.0,
    ),
    "order-choice": Source(
        "python benchmarks/order_choice.py --seeds 1-10 --json {out}/orders.json",
        order_choice, table_order_choice, 32.0,
    ),
    "grating-scale": Source(
        "python benchmarks/grating_scale.py --seeds 1-10 --json {out}/grating.json",
        grating_scale, table_grating_scale, 30.0,
    ),
    "floor-asymmetry": Source(
        "python benchmarks/model_floor.py --variants base quiet symmetric --n-play 16 "
        "--spectra 19@0.05-2000s --asymmetry --json {out}/floor.json",
        floor_families, table_floor_asymmetry, 3.0,
    ),
    "floor-families": Source(
        "python benchmarks/model_floor.py --preset cpr5 cpr5-slowdomains --variants base "
        "--n-play 32 --spectra 19@0.05-2000s --json {out}/floor.json",
        floor_families, table_floor_families, 3.0,
    ),
    "identify-budget": Source(
        "python benchmarks/instrument_budget.py --seeds 1-6 --table1 "
        "--json {out}/instrument_budget.json",
        instrument_budget, table_instrument_budget, 130.0,
    ),
    "instrument-time": Source(
        "python benchmarks/instrument_budget.py --seeds 1-6 --protocols default "
        "--json {out}/instrument_budget.json",
        instrument_budget, table_instrument_time, 10.0,
    ),
    "identification-1-10": Source(
        "piezocomp reproduce --quick --seeds 1-10 --no-progress --out {out}",
        identification_over_seeds, table_identification, 25.0,
    ),
    "timing": Source(
        "piezocomp reproduce --quick --seeds 1-10 --no-progress --out {out}", run_timing,
        table_run_timing, 25.0,
    ),
    "oracle-in-drift": Source(
        "python benchmarks/oracle_in_drift.py --seeds 1-10 --runs DIR --json {out}/oracle.json",
        oracle_in_drift, table_oracle_in_drift, 6.0,
    ),
    "table1-budget": Source(
        "python benchmarks/table1_budget.py --runs DIR --seeds 1-10 --json "
        "{out}/table1_budget.json",
        table1_budget, table_table1_budget, 8.0,
    ),
    "oracle-record-only": Source(
        "python benchmarks/oracle_in_drift.py --seeds 1-10 --runs DIR --record-only "
        "--json {out}/oracle.json",
        oracle_in_drift, lambda fig: table_oracle_in_drift(fig, "oracle-record-only"), 6.0,
    ),
    "fig10-runs": Source(
        "python benchmarks/fig10_failures.py --seeds 1-10 --runs DIR --json {out}/fig10.json",
        fig10_runs, table_fig10_runs, 3.0,
    ),
    "fig10-runs-61-70": Source(
        "python benchmarks/fig10_failures.py --seeds 61-70 --json {out}/fig10.json",
        fig10_runs, table_fig10_runs, 20.0,
    ),
    "fit-on-truth": Source(
        "python benchmarks/model_floor.py --variants base --n-play 16 --spectra 19@0.05-2000s "
        "--fit --json {out}/floor.json",
        fit_on_truth, table_fit_on_truth, 1.0,
    ),
    "piezo-record": Source(
        "python benchmarks/piezo_record.py --json {out}/piezo.json", piezo_record,
        table_piezo_record, 0.2,
    ),
    "piezo-asymmetry": Source(
        "python benchmarks/piezo_record.py --json {out}/piezo.json", piezo_record,
        table_piezo_asymmetry, 0.2,
    ),
    "core-speed": Source(
        "python benchmarks/bench_core.py --json {out}/bench.json", core_speed, table_core_speed,
        0.5,
    ),
    "scanner-shapes": Source(
        "python benchmarks/reproduce_scanners.py --only 'domains 60 % of the creep' "
        "'no domain creep' 'domains from 10 s' 'creep 0.01-300 s' "
        "'blunt wide tip (20 nm, 35 deg)' --seeds 51 52 53 --json {out}/scanners.json",
        scanner_runs, table_scanner_runs, 45.0,
    ),
}  # fmt: skip
"""Every source whose output the pages quote in generated blocks."""

DRAWINGS: dict[str, tuple[str, ...]] = {"session-limits": ("docs/figures/drift_trade.py",)}
"""The scripts that draw a page's figure from a source's generated output, run again when
it is generated."""

EARLIER: dict[str, str] = {
    "model-floor": "python benchmarks/model_floor.py --variants base --spectra 19@0.05-2000s "
    "19@0.01-2000s --seed 2 (then --seed 3)",
    "drift-results": "piezocomp reproduce --quick --seeds 1-10 (and 1-30); python "
    "benchmarks/oracle_in_drift.py --seeds 1-10; benchmarks/drift_filter.py, "
    "benchmarks/identify_presets.py --only 'untuned drift' --seeds 1 2 3 4 and "
    "benchmarks/drift_only.py --minutes 20 --seeds 1 2 3, as each paragraph names",
    "experiments-results": "piezocomp reproduce --quick --seeds 1-10 (and 1-30); piezocomp "
    "reproduce --preset cpr5-nodrift --quick --seeds 1-10; python "
    "benchmarks/oracle_in_drift.py --seeds 1-10",
    "reproduce-scanners": "python benchmarks/reproduce_scanners.py",
    "identification-design": "the benchmarks each paragraph names (benchmarks/identify_*.py, "
    "benchmarks/model_floor.py)",
    "identification-results": "piezocomp identify on the presets and seeds each paragraph "
    "names; python benchmarks/identify_drift.py",
    "identify-budget": "python benchmarks/instrument_budget.py --seeds 1-6 --table1",
    "identify-budget-reading": "the reading of identify-budget's table (prose): rewrite it, with "
    "inline figures, once that table is regenerated",
    "instrument-rehearsal": "python benchmarks/nanonis_loopback.py",
    "real-scans": "piezocomp loop --scan FILE on the files its paragraphs name",
    "virtual-afm-calibration": "python benchmarks/calibrate_cpr5.py",
    "afm-speed": "python benchmarks/bench_afm_speed.py (one core: taskset -c 0)",
    "paper-start": "python benchmarks/paper_start.py --seeds 1 2 3 --starts 0.01,2000 0.3,30 "
    "1,100 0.1,10; --seeds 4 5 6 7 8 --starts 0.1,10 1,100; --floor --seeds 1 2 3",
}
"""The sources quoted in blocks that this script has not regenerated: what would regenerate
each. Their blocks say they were measured on an earlier version; a source leaves this list
once its output is generated (``run`` or ``read``), and its blocks are then rendered."""


# ------------------------------------------------------------------ the pages
def generated(source: str) -> dict[str, str] | None:
    """The last generated figures of ``source`` (``None``: never generated)."""
    path = GENERATED / f"{source}.json"
    if not path.is_file():
        return None
    return json.loads(path.read_text(encoding="utf-8"))["figures"]


def render_page(text: str) -> str:
    """``text`` with every block and inline value of a generated source rewritten."""

    def block(m: re.Match[str]) -> str:
        fig = generated(m["source"])
        if fig is None:
            return m[0]
        body = SOURCES[m["source"]].render(fig)
        return f"<!-- figures: {m['source']} -->\n{body}<!-- /figures -->"

    def inline(m: re.Match[str]) -> str:
        fig = generated(m["source"])
        if fig is None:
            return m[0]
        return f"<!-- figure: {m['source']} {m['key']} -->{fig[m['key']]}<!-- /figure -->"

    return INLINE.sub(inline, BLOCK.sub(block, text))


def write_pages() -> list[str]:
    """Rewrite every page from the generated outputs; the pages changed."""
    from piezocomp._atomic import atomic_write_text

    changed = []
    for page in PAGES:
        path = ROOT / page
        text = path.read_text(encoding="utf-8")
        new = render_page(text)
        if new != text:
            atomic_write_text(path, new)
            changed.append(page)
    return changed


def this_commit() -> str:
    """The commit of this tree (``+changes`` when it has uncommitted ones), or ``unknown``."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()

    try:
        head, dirty = git("rev-parse", "--short", "HEAD"), git("status", "--porcelain", "-uno")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if dirty else "")


def recorded_environment(folder: Path) -> dict[str, Any] | None:
    """The software and processor a run folder's figures were computed with (the
    ``environment`` of its ``samples.json`` or first ``results.json``), ``None`` if it names
    none (runs before it was recorded)."""
    for path in [folder / "samples.json", *sorted(folder.glob("**/results.json"))]:
        if path.is_file():
            env = json.loads(path.read_text(encoding="utf-8")).get("environment")
            if env is not None:
                return dict(env)
    return None


def keep(
    source: str, folder: Path, made_with: str, environment: dict[str, Any] | None = None
) -> Path:
    """Read ``source``'s figures from ``folder`` into ``docs/figures/generated``, with the
    code that made them (``made_with``: a commit) and the environment they were computed in
    (``environment``, else the folder's own record, :func:`recorded_environment`)."""
    from piezocomp import __version__
    from piezocomp._atomic import atomic_write_text

    figures = SOURCES[source].read(folder)
    env = recorded_environment(folder) if environment is None else environment
    data = {"source": source, "version": __version__, "made_with": made_with,
            "environment": env, "figures": figures}  # fmt: skip
    GENERATED.mkdir(parents=True, exist_ok=True)
    path = GENERATED / f"{source}.json"
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")
    return path


def draw(source: str) -> None:
    """Redraw the figures drawn from ``source``'s generated output (:data:`DRAWINGS`)."""
    env = dict(os.environ)  # this tree's package, whatever is installed
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), *filter(None, [env.get("PYTHONPATH")])])
    for script in DRAWINGS.get(source, ()):
        subprocess.run([sys.executable, script], cwd=ROOT, check=True, env=env)
        print(f"docs/figures.py: drew {script}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    sub.add_parser("list", help="the sources, generated or not, and their commands")
    r = sub.add_parser("run", help="rerun sources' commands, keep their figures, write the pages")
    r.add_argument("sources", nargs="+", choices=sorted(SOURCES))
    d = sub.add_parser("read", help="keep a source's figures from a folder, write the pages")
    d.add_argument("source", choices=sorted(SOURCES))
    d.add_argument("folder", type=Path)
    d.add_argument("--made-with", required=True, metavar="COMMIT",
                   help="the commit of the code that made the folder")  # fmt: skip
    sub.add_parser("write", help="the pages from the generated outputs")
    a = ap.parse_args(argv)
    if a.what == "list":
        for name, s in SOURCES.items():
            if generated(name) is None and name in EARLIER:
                continue  # below, with the command that regenerates it
            state = "generated" if generated(name) is not None else "not generated"
            print(f"{name}: {state}; {s.command} (about {s.minutes:g} min)")
        for name, cmd in EARLIER.items():
            if name in SOURCES:
                cmd = f"{SOURCES[name].command} (about {SOURCES[name].minutes:g} min)"
            print(f"{name}: measured on an earlier version; {cmd}")
        return 0
    if a.what == "run":
        for name in a.sources:  # every source checked before any runs
            if " DIR " in SOURCES[name].command:
                cmd = SOURCES[name].command.format(out="FOLDER")
                ap.error(
                    f"{name} reads a `piezocomp reproduce --quick --seeds` folder (DIR): run "
                    f"`{cmd}` with it, then `python docs/figures.py read {name} FOLDER "
                    "--made-with COMMIT`."
                )
        for name in a.sources:
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "out"
                cmd = SOURCES[name].command.format(out=out)
                print(f"docs/figures.py: {cmd}", file=sys.stderr)
                argv_ = shlex.split(cmd)
                if argv_[0] == "piezocomp":
                    argv_ = [sys.executable, "-m", "piezocomp", *argv_[1:]]
                else:
                    argv_[0] = sys.executable
                    out.mkdir(parents=True)
                env = dict(os.environ)  # this tree's package, whatever is installed
                env["PYTHONPATH"] = os.pathsep.join(
                    [str(ROOT / "src"), *filter(None, [env.get("PYTHONPATH")])]
                )
                made_with = this_commit()
                subprocess.run(argv_, cwd=ROOT, check=True, env=env)
                from piezocomp.environment import environment

                made = keep(name, out, made_with, recorded_environment(out) or environment())
                print(f"docs/figures.py: wrote {made}", file=sys.stderr)
                draw(name)
    elif a.what == "read":
        made = keep(a.source, a.folder, a.made_with)
        print(f"docs/figures.py: wrote {made}", file=sys.stderr)
        draw(a.source)
    for page in write_pages():
        print(f"docs/figures.py: rewrote {page}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
