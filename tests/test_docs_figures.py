"""The figures README.md and docs/ quote are generated, not typed (``docs/figures.py``).

Every block of quoted figures is either what the last generated output of its source
renders, to the character (a figure typed by hand, or a stale one, fails), or one of the
sources the script has not regenerated, which the pages label as measured on an earlier
version and :data:`EARLIER` lists by name. A line that reads like a measured figure (a
``median / worst`` pair, or a decimal beside "median", "worst" or "seed") outside any block
fails too, unless :data:`NOT_FIGURES` says why it is not one. And the same seed gives the
same figures: a short job run twice gives the same ``results.json``, timings aside.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _figures_module():
    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "docs" / "figures.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["docs_figures"] = module
    spec.loader.exec_module(module)
    return module


F = _figures_module()

EARLIER = F.EARLIER
"""The one list of the sources quoted as measured on an earlier version (docs/figures.py)."""

NOT_FIGURES = (
    "(a median of 0.3 and a factor of",  # virtual_afm.md: a parameter of the simulator
    "| `sample.tip_radius_spread` | 0.3 |",  # the configuration table
    "| `sample.tip_friction` | 0.3 |",
)
"""Lines that read like a measured figure and are not one (and why)."""

PAIR = re.compile(r"\d\.\d+ / \d+\.\d")
DECIMAL = re.compile(r"\d\.\d")
WORD = re.compile(r"median|worst|seed", re.I)


def _pages():
    return {page: (ROOT / page).read_text(encoding="utf-8") for page in F.PAGES}


def test_each_block_is_its_last_generated_output_or_an_earlier_one_so_labelled():
    seen = set()
    for page, text in _pages().items():
        for m in F.BLOCK.finditer(text):
            source, body = m["source"], m["body"]
            seen.add(source)
            fig = F.generated(source)
            if fig is not None:
                assert source not in EARLIER, f"{source}: generated, so not earlier any more"
                want = F.SOURCES[source].render(fig)
                assert body == want, f"{page}: the {source} block differs from its output"
            else:
                assert source in EARLIER, f"{page}: {source} is neither generated nor earlier"
                assert body.lstrip().startswith(F.EARLIER_LABEL.join("__")), (
                    f"{page}: a block of {source} must first say it was {F.EARLIER_LABEL}"
                )
        for m in F.INLINE.finditer(text):
            fig = F.generated(m["source"])
            assert fig is not None, f"{page}: inline {m['source']} was never generated"
            assert m["value"] == fig[m["key"]], f"{page}: {m['source']} {m['key']}"
    assert seen >= set(EARLIER), f"listed as earlier but quoted nowhere: {set(EARLIER) - seen}"


def test_no_figure_is_quoted_outside_a_block():
    loose = []
    for page, text in _pages().items():
        masked = F.BLOCK.sub(lambda m: "\n" * m[0].count("\n"), text)
        masked = F.INLINE.sub("", masked)  # an inline value is checked as a block is
        lang = None
        for i, line in enumerate(masked.split("\n"), 1):
            if line.strip().startswith("```"):
                lang = None if lang is not None else line.strip()[3:]
                continue
            if lang not in (None, "", "text"):
                continue  # code: python, bash, json
            looks = PAIR.search(line) or (DECIMAL.search(line) and WORD.search(line))
            if looks and not any(s in line for s in NOT_FIGURES):
                loose.append(f"{page}:{i}: {line.strip()[:80]}")
    assert not loose, "figures outside a generated block:\n" + "\n".join(loose)


def test_the_renderers_write_what_they_read(tmp_path):
    """A block of a source rendered from figures read from a folder: one run's results and
    a run over seeds (the lead's long runs go through ``read``)."""
    import json

    stat = {"median": 1.5, "worst": 2.25, "n": 2}
    rate = {"median": 0.5, "worst": 0.25, "n": 2}
    both = {"table1_true_nm": stat, "fig10_true_success": rate}
    samples = {"seeds": [1, 2, 3], "command": "piezocomp reproduce --seeds 1-3",
               "failed_seeds": {"3": "RuntimeError: x"}, "statistics": {"both": both}}  # fmt: skip
    (tmp_path / "samples.json").write_text(json.dumps(samples))
    fig = F.over_seeds(tmp_path)
    assert fig["both.table1_true_nm"] == "1.50 / 2.25 (2 of 3)"
    assert fig["both.fig10_true_success"] == "50 % / 25 % (2 of 3)"
    text = F.table_over_seeds({**fig, **{f"both.{k}": "x" for k in (
        "table1_measured_nm", "fig9_true_nm", "session_true_worst_nm",
        "session_true_final_nm", "session_measuring")}})  # fmt: skip
    assert "| `both` | 1.50 / 2.25 (2 of 3) |" in text and "failed: 3" in text


def test_the_scanner_table_gives_each_scanners_median_and_worst(tmp_path):
    """``benchmarks/reproduce_scanners.py``'s runs, per scanner over its seeds."""
    import json

    def run(scanner, seed, t1, f10, status=0):
        fig = {"table1_true_nm": t1, "table1_measured_nm": t1, "fig9_true_nm": 1.0,
               "fig9_measured_nm": 1.0, "fig10_true_success": f10,
               "session_true_worst_nm": 2.0, "session_true_final_nm": 1.0,
               "session_measuring": 0.25}  # fmt: skip
        return {"scanner": scanner, "seed": seed, "exit_status": status,
                "headline": {m: fig for m in ("uncompensated", "compensated", "both")}}  # fmt: skip

    runs = [run("a (1 %)", 51, 0.5, 1.0), run("a (1 %)", 52, 1.5, 0.5, 1), run("b", 51, 0.7, 1.0)]
    data = {"command": "python benchmarks/reproduce_scanners.py --seeds 51 52 --json x.json",
            "runs": runs}  # fmt: skip
    (tmp_path / "scanners.json").write_text(json.dumps(data))
    fig = F.scanner_runs(tmp_path)
    assert fig["0.both.table1_true_nm"] == "1.00 / 1.50"
    assert fig["0.both.fig10_true_success"] == "75 % / 50 %"
    assert (fig["0.exit0"], fig["0.n"], fig["1.n"]) == ("1", "2", "1")
    text = F.table_scanner_runs(fig)
    assert "| a (1 %) | 1.00 / 1.00 / **1.00 / 1.50** |" in text
    assert "--json" not in text and "seeds 51-52" in text
    (tmp_path / "scanners.json").write_text(json.dumps(runs))  # an older file: the list
    assert "--only 'a (1 %)' b --seeds 51 52" in F.scanner_runs(tmp_path)["command"]


def test_the_every_method_table_reads_each_seeds_results(tmp_path):
    """Every method over seeds, from each ``seed-N/results.json``; a failed seed left out."""
    import json

    def cell(v):
        return {"true_max_error_nm": {"mean": v}, "max_error_nm": {"mean": v + 0.5}}

    def results(v, placed):
        asm = [
            {"true_success": placed, "true_max_error_nm": 1.0},
            {"true_success": True, "true_max_error_nm": 1.0},
        ]
        f10 = {"true_success_rate": 0.5, "assemblies": asm}
        return {
            "paper": {"speed_nm_per_s": 1000.0, "fig9": {"uncompensated": 14.3,
                                                         "compensated": 1.0},
                      "table1": {
                          "645": {"uncompensated": [6.45, 0.1], "compensated": [0.76, 0.2]},
                          "951": {"uncompensated": [9.53, 0.1], "compensated": [1.01, 0.2]}}},
            "table1": [{"speed_nm_per_s": 1000.0, "methods": {"static": cell(v), "both": cell(v)}},
                       {"speed_nm_per_s": 500.0, "methods": {"static": cell(99.0)}}],
            "fig9": {"methods": {"static": {"true_error_nm": v, "error_nm": v}}},
            "fig10": {"methods": {"static": f10}},
            "fig10_drift": {"methods": {"both": f10}},
        }  # fmt: skip

    for seed, v, placed in ((1, 1.0, True), (2, 3.0, False)):
        (tmp_path / f"seed-{seed}").mkdir()
        (tmp_path / f"seed-{seed}" / "results.json").write_text(json.dumps(results(v, placed)))
    samples = {"seeds": [1, 2, 3], "command": "piezocomp reproduce --seeds 1-3 --out runs",
               "failed_seeds": {"3": "RuntimeError: x"}}  # fmt: skip
    (tmp_path / "samples.json").write_text(json.dumps(samples))
    fig = F.every_method(tmp_path)
    assert fig["methods"] == "both static"
    assert fig["static.table1_true_nm"] == "2.00 / 3.00"
    assert fig["both.table1_measured_nm"] == "2.50 / 3.50"
    assert (fig["static.fig10"], fig["both.fig9_true_nm"]) == ("3 of 4", "n/a")
    text = F.table_every_method(fig)
    assert "| 6.45-9.53 / 0.76-1.01 | | 14.3 / 1 |" in text
    assert "| **`both`** | 2.00 / 3.00 |" in text and "failed: 3" in text and "--out DIR" in text


def _no_timings(d):
    """``results.json`` without what the clock measured."""
    if isinstance(d, dict):
        return {k: _no_timings(v) for k, v in d.items()
                if k not in ("timing_s", "stages_s", "computing_s", "cpu_s")}  # fmt: skip
    if isinstance(d, list):
        return [_no_timings(v) for v in d]
    return d


@pytest.mark.slow
def test_the_same_seed_gives_the_same_figures(oracle_models):
    """A short job twice: ``results.json`` key by key, timings aside (Table I, Fig. 8 and
    Fig. 9, uncompensated, compensated and inside the drift compensator on the drifting
    cpr5, through two process workers; Fig. 10 left out for time)."""
    from piezocomp.experiments.methods import MethodModels
    from piezocomp.experiments.reproduce import PAPER_SPEED_NM_PER_S, ReproduceSettings, reproduce
    from piezocomp.virtual_afm import load_config

    s = ReproduceSettings(
        config=load_config("cpr5"), distances_nm=(645.0,), table1_experiments=1,
        speeds_nm_per_s=(PAPER_SPEED_NM_PER_S,), fig10_trials=0, drift_minutes=0.0,
        methods=("uncompensated", "compensated"), workers=2,
    )  # fmt: skip
    models = MethodModels({"compensated": oracle_models})
    first, second = (_no_timings(reproduce(s, progress=False, models=models).results)
                     for _ in range(2))  # fmt: skip
    assert first.keys() == second.keys()
    for key in first:
        assert first[key] == second[key], key


def test_the_diagnosis_readers_give_median_and_worst(tmp_path):
    """The readers of the identification over seeds, the oracle inside the drift compensator
    and Table I's split, from small made-up outputs: median / worst of what they read."""
    import json

    def axis(batch: float, kept: bool) -> dict:
        err = {"validation_max_error_nm": batch, "validation_rms_error_nm": batch / 2,
               "validation_max_error_after_scale_nm": batch - 0.5}  # fmt: skip
        return {"sensorless": {
            "compensated": err, "rls": {**err, "validation_max_error_nm": 2 * batch},
            "line_drift": {"kept": kept, "heldout_rms_without_nm": 1.0,
                           "heldout_rms_with_nm": 0.5},
        }}  # fmt: skip

    samples = {"seeds": [1, 2, 3], "command": "piezocomp reproduce --seeds 1-3 --out /x",
               "failed_seeds": {"3": "RuntimeError: x"}, "statistics": {}}  # fmt: skip
    (tmp_path / "samples.json").write_text(json.dumps(samples))
    for seed, (b, kept) in {1: (1.0, True), 2: (3.0, False)}.items():
        (tmp_path / f"seed-{seed}").mkdir()
        res = {"identification": {"axes": {"x": axis(b, kept), "y": axis(b / 2, True)}}}
        (tmp_path / f"seed-{seed}" / "results.json").write_text(json.dumps(res))
    fig = F.identification_over_seeds(tmp_path)
    assert fig["x.batch_max"] == "2.00 / 3.00" and fig["x.rls_max"] == "4.00 / 6.00"
    assert fig["line_drift_kept"] == "3 of 4" and fig["command"].endswith("--out DIR")
    assert "| x | 2.00 / 3.00 | 1.00 / 1.50 |" in F.table_identification(fig)

    def head(t1: float, f10: float) -> dict:
        one = {k: None for k in ("table1_measured_nm", "fig9_true_nm", "fig9_measured_nm",
                                 "session_true_worst_nm", "session_true_final_nm",
                                 "session_measuring")}  # fmt: skip
        return {**one, "table1_true_nm": t1, "fig10_true_success": f10}

    runs = [{"seed": s, "headline": {"compensated": head(4.0, 0.0), "both": head(t, r)},
             "failures": []} for s, t, r in ((1, 0.5, 1.0), (2, 1.5, 0.5))]  # fmt: skip
    (tmp_path / "oracle").mkdir()  # no default run beside it: no paired differences
    (tmp_path / "oracle" / "oracle.json").write_text(json.dumps(runs))
    fig = F.oracle_in_drift(tmp_path / "oracle")
    assert not any(k.startswith("default_minus") for k in fig)
    assert fig["both.table1_true_nm"] == "1.00 / 1.50" and fig["seeds"] == "1-2"
    assert fig["both.fig10_true_success"] == "75 % / 50 %" and fig["both.fig9_true_nm"] == "n/a"
    assert "| inside the drift compensator | 1.00 / 1.50 |" in F.table_oracle_in_drift(fig)

    budget = {"command": "python benchmarks/table1_budget.py --runs /tmp/r --seeds 1-2 "
              "--json /tmp/b.json", "seeds": [1, 2],
              "statistics": {"true": [0.6, 1.5], "correlation": [-0.8, -0.6]}}  # fmt: skip
    (tmp_path / "table1_budget.json").write_text(json.dumps(budget))
    fig = F.table1_budget(tmp_path)
    assert fig["command"] == "python benchmarks/table1_budget.py --runs DIR --seeds 1-2"
    text = F.table_table1_budget(fig)
    assert "| Table I, true (the headline's) | 0.60 / 1.50 |" in text and "-0.80 / -0.60" in text


def test_the_environment_is_recorded_with_the_figures(tmp_path):
    """What a figure was computed with (libraries, processor) is read from the run folder,
    from its samples.json first, and is what piezocomp.environment reports."""
    import json

    import numpy as np

    from piezocomp.environment import environment

    env = environment()
    assert env["versions"]["numpy"] == np.__version__ and env["cpu"]
    assert F.recorded_environment(tmp_path) is None  # a folder from before the record
    (tmp_path / "seed-1").mkdir()
    (tmp_path / "seed-1" / "results.json").write_text(json.dumps({"environment": {"cpu": "a"}}))
    assert F.recorded_environment(tmp_path) == {"cpu": "a"}
    (tmp_path / "samples.json").write_text(json.dumps({"environment": {"cpu": "b"}}))
    assert F.recorded_environment(tmp_path) == {"cpu": "b"}


def test_a_session_variant_is_named_by_its_parts():
    label = _figures_module().session_label
    assert label("identified") == "the default model (identified without a sensor)"
    assert label("areas+tolerance=0.75") == (
        "the default model, the session's images of its areas drift sightings too, "
        "measuring at a drift tolerance of 0.75 nm"
    )
    assert label("oracle+areas").startswith("the model family fitted to the true extension")
