"""The package's namespace: the names docs/api.md lists, loaded on first use."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import piezocomp
from piezocomp.identification.result import Identification

ROOT = Path(__file__).resolve().parents[1]


def test_each_public_name_is_the_one_its_module_defines():
    names = [n for n in piezocomp.__all__ if n != "__version__"]
    assert sorted(names) == sorted(piezocomp._WHERE)
    for name in names:
        module = importlib.import_module(piezocomp._WHERE[name])
        assert getattr(piezocomp, name) is getattr(module, name)
        assert name in dir(piezocomp)


def test_every_public_name_is_in_the_api_page():
    page = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    missing = [n for n in piezocomp.__all__ if n != "__version__" and f"`{n}`" not in page]
    assert not missing


def test_import_piezocomp_loads_no_subsystem():
    code = (
        "import sys, piezocomp; "
        "print(sorted(m for m in sys.modules if m.startswith(('piezocomp.', 'numpy'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'identfy'"):
        piezocomp.identfy  # noqa: B018


def test_identify_refuses_bad_axes_before_anything_moves():
    afm = object()  # never reached
    for axes in ((), ("z",), ("x", "x")):
        with pytest.raises(ValueError, match="axes must be 'x' and/or 'y'"):
            piezocomp.identify(afm, axes=axes)  # type: ignore[arg-type]


class _Axis:
    def __init__(self, failures: list[str], model: str) -> None:
        self.failures, self.batch_model, self.rls_model = failures, model, model

    def validation_failures(self) -> list[str]:
        return self.failures


def test_a_model_that_fails_its_own_validation_is_refused():
    good = Identification({"x": _Axis([], "mx")})  # type: ignore[dict-item]
    assert good.model == "mx"
    bad = Identification({"x": _Axis([], "mx"), "y": _Axis(["held-out 9 nm RMS"], "my")})  # type: ignore[dict-item]
    with pytest.raises(ValueError, match="axis y: held-out 9 nm RMS"):
        bad.model  # noqa: B018
    with pytest.raises(ValueError, match="fails its own validation"):
        bad.rls_model  # noqa: B018
