"""What the user's software may import: nothing that learns from measurements reads the
simulator (its ground truth) or the experiments that score against it."""

import ast
from pathlib import Path

import pytest

import piezocomp

PACKAGES = ("positioning", "imaging", "drift", "identification", "sensor")
FORBIDDEN = ("piezocomp.virtual_afm", "piezocomp.experiments")


def _imports(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.append(node.module)
    return names


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_imports_the_simulator_or_the_experiments(package):
    root = Path(piezocomp.__file__).parent / package
    files = sorted(root.glob("*.py"))
    assert files
    bad = [(f.name, m) for f in files for m in _imports(f) if m.startswith(FORBIDDEN)]
    assert bad == []


def test_the_sensorless_identification_does_not_need_the_sensor_fit():
    root = Path(piezocomp.__file__).parent / "identification"
    bad = [(f.name, m) for f in sorted(root.glob("*.py")) for m in _imports(f)
           if m.startswith("piezocomp.sensor")]  # fmt: skip
    assert bad == []


def test_the_rule_finds_an_import_anywhere_in_a_module(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from piezocomp.virtual_afm import VirtualAFM\n")
    assert any(m.startswith(FORBIDDEN) for m in _imports(f))
