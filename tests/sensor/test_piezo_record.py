"""Real data: a piezo micromanipulator record with a capacitive sensor (not a model's output).

Data: ``data/piezo-micromanipulator/Model_Vi_Do.dat`` in the repository, with its licence.
Origin github.com/yan9a/DiscreteBacklashOperator (commit 79fd060), MIT
licence, (c) 2019 Yan Naing Aye; Y. N. Aye and W. T. Ang, ICSTSD 2018. The test runs
``benchmarks/piezo_record.py`` (the same code that reports the figures) and compares our
model with the plain 10-operator PI baseline fitted in the same run, on the same held-out
samples.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "benchmarks" / "piezo_record.py"
DATA = REPO / "data" / "piezo-micromanipulator" / "Model_Vi_Do.dat"

pytestmark = pytest.mark.skipif(
    not DATA.is_file(), reason=f"real piezo record not present at {DATA} (an sdist without data/)"
)


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("piezo_record_bench", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def result(bench):
    return bench.run(DATA)


def test_conversion_maps_command_range_onto_output_range(bench):
    rec = bench.load_record(DATA)
    u, y = rec["u_nm"], rec["y_nm"]
    assert u.size == y.size == 8027
    assert np.isclose(np.ptp(u), np.ptp(y))
    assert rec["sign_flipped"] is False  # displacement rises with the voltage
    assert np.corrcoef(u, y)[0, 1] > 0.9


def test_our_model_beats_the_plain_pi_on_held_out_samples(result):
    base = result["baseline_plain_pi10"]
    ours = result["ours"]
    assert base["validation"]["n_samples"] == ours["validation"]["n_samples"] > 2000
    assert ours["validation"]["rms_nm"] < base["validation"]["rms_nm"]
    # ... whichever initial state the baseline is given
    for figs in base["by_initial_state"].values():
        assert ours["validation"]["rms_nm"] < figs["validation"]["rms_nm"]


def test_refinement_lowers_the_fitted_cost(result):
    for summary in result["ours"]["by_initial_state"].values():
        assert summary["refined"]["fit"]["rms_nm"] <= summary["nnls"]["fit"]["rms_nm"]


def test_orders_were_chosen_from_the_fitted_part(result):
    for table in result["ours"]["order_selection"].values():
        chosen = [row for row in table["trials"] if row["chosen"]]
        assert len(chosen) == 1
        assert (chosen[0]["n_play"], chosen[0]["n_creep"]) == (table["n_play"], table["n_creep"])
    for k, fit in result["ours"]["by_initial_state"].items():  # the fit's own orders
        selected = result["ours"]["order_selection"][k]
        assert (fit["nnls"]["n_play"], fit["nnls"]["n_creep"]) == (
            selected["n_play"], selected["n_creep"],
        )  # fmt: skip
    k = result["ours"]["initial_state"]
    kept = result["ours"]["by_initial_state"][k]
    base = kept["asymmetry"]["base"] if kept["chosen"] == "asymmetric" else kept["chosen"]
    expected = kept["reference"] if base == "reference" else kept["nnls"]
    assert (result["ours"]["n_play"], result["ours"]["n_creep"]) == (
        expected["n_play"], expected["n_creep"],
    )  # fmt: skip


TEST_DATA = DATA.with_name("Test_Vi_Do_Di.dat")


@pytest.mark.skipif(not TEST_DATA.is_file(), reason=f"the test record is not at {TEST_DATA}")
def test_the_other_record_of_the_instrument_is_predicted_better_than_by_the_plain_pi(result):
    """Fitted on one record, predicted on the instrument's other (nested minor loops and
    holds the fitting record never had), started as the fitting record starts: ours at least
    15 % below the plain PI on each part, and the reference fit (the family's plain NNLS)
    reported beside it. (Started from a state found in the first 2 s, every model with creep
    does worse; that column is reported, not asserted.)"""
    other = result["other_record"]
    assert other is not None and len(other["parts"]) == 3
    models = other["models"]
    assert set(models) == {
        "baseline_plain_pi10", "ours", "reference_plain_nnls", "ours_start_estimated",
        "ours_auto", "ours_refined",
    }  # fmt: skip
    base = models["baseline_plain_pi10"]["as fitted"]["parts"]
    for name in ("ours", "ours_auto"):
        ours = models[name]["as fitted"]["parts"]
        assert all(o["rms_nm"] < 0.85 * b["rms_nm"] for o, b in zip(ours, base, strict=True))
    assert result["ours"]["by_initial_state"]["zero"]["reference"]["n_play"] == 16


def test_the_asymmetry_probe_starts_from_the_reference(result):
    """Without dead zones the probe is the reference fit itself (the same least squares), so
    its held-out figure is the reference's; each row says how many dead zones it added."""
    rows = result["asymmetry_probe"]
    assert [r["dead_zones"] for r in rows] == [0, 2, 4, 6]
    ref = result["ours"]["by_initial_state"]["zero"]["reference"]["validation"]
    assert rows[0]["validation_percent_of_range"] == pytest.approx(
        ref["rms_percent_of_range"], rel=1e-6
    )
    assert all(len(r["other_parts_percent_of_range"]) == 3 for r in rows)


def test_the_asymmetric_model_is_kept_on_this_actuator_and_predicts_both_records_better(result):
    """Kuhnen's dead zones (eq 8') on evidence: on this actuator's record they are kept, the
    held-out error at least 30 % below the symmetric model they were added to, and the
    instrument's other record (which chose nothing) is predicted better on every part than
    by the symmetric reference."""
    kept = result["ours"]["by_initial_state"][result["ours"]["initial_state"]]
    asym = kept["asymmetry"]
    assert kept["chosen"] == "asymmetric" and asym["kept"] and kept["n_dead_zones"] == 4
    assert asym["validation"]["rms_nm"] < 0.7 * asym["base_validation_rms_nm"]
    other = result["other_record"]
    if other is None:  # pragma: no cover - an sdist without the test record
        pytest.skip("the test record is not present")
    ours = other["models"]["ours"]["as fitted"]["parts"]
    ref = other["models"]["reference_plain_nnls"]["as fitted"]["parts"]
    assert all(o["rms_nm"] < r["rms_nm"] for o, r in zip(ours, ref, strict=True))
