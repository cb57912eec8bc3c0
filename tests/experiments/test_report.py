"""Parts of report.html that read results.json alone."""

from __future__ import annotations

from piezocomp.experiments.report import _identification, _ms, _speeds


def _summary(findings: list[str]) -> dict:
    return {
        "batch": {"validation_max_error_nm": 0.3, "validation_rms_error_nm": 0.1},
        "orders": {"n_play": 16, "n_creep": 22},
        "computing_s": 10.0,
        "findings": findings,
    }


def test_findings_of_the_default_model_are_apart_from_the_comparison_methods():
    res = {
        "identification": {
            "axes": {
                "x": {
                    "sensorless": _summary(["no length reference: scan a grating"]),
                    "no_creep": _summary(["the batch model predicts ... Record again"]),
                }
            }
        }
    }
    page = _identification(res)
    own = page.index("Findings of the default model's identification")
    others = page.index("Findings of the comparison methods' identifications")
    assert own < page.index("no length reference") < others
    assert others < page.index(
        "x, pi_no_creep's identification (pi_no_creep: its batch model): the batch model predicts"
    )  # named as the method it serves
    assert "do not concern the default model" in page


def test_no_findings_no_lists():
    page = _identification({"identification": {"axes": {"x": {"sensorless": _summary([])}}}})
    assert "Findings" not in page


def test_one_experiment_has_no_spread():
    assert _ms({"mean": 5.92, "std": 0.0, "n": 1}, 5) == "5.92 (1 of 5)"
    assert _ms({"mean": 5.92, "std": 0.5, "n": 5}, 5) == "5.92 &plusmn; 0.50"


def test_speed_rows_in_order_of_speed():
    stat = {"true_error_nm": 1.0, "error_nm": 1.0}
    res = {
        "fig9": {
            "methods": {"compensated": stat},
            "speeds": [
                {"speed_nm_per_s": v, "methods": {"compensated": stat}}
                for v in (1000.0, 250.0, 500.0, 2000.0)
            ],
        },
        "table1": [],
    }
    page = _speeds(res)
    at = [page.index(f"Fig. 9 at {v:g}<") for v in (250, 500, 1000, 2000)]
    assert at == sorted(at)
