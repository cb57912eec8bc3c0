"""Parts of report.html that read results.json alone."""

from __future__ import annotations

from piezocomp.experiments.report import _identification


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
    assert others < page.index("x, no_creep: the batch model predicts")
    assert "do not concern the default model" in page


def test_no_findings_no_lists():
    page = _identification({"identification": {"axes": {"x": {"sensorless": _summary([])}}}})
    assert "Findings" not in page
