"""What each part of the package may import, as its ``__init__`` docstring says: nothing that
learns from measurements reads the simulator (its ground truth) or the experiments that score
against it, the core stands alone, and no two subpackages import each other."""

import ast
from pathlib import Path

import pytest

import piezocomp

PACKAGES = ("positioning", "imaging", "drift", "identification", "sensor")
FORBIDDEN = ("piezocomp.virtual_afm", "piezocomp.experiments")

HELPERS = {"_validation", "_atomic"}
CORE = {"model", "inverse", "limits", "operators", "instrument", "tip"} | HELPERS
MAY_IMPORT = {  # a part of the package -> the parts it may import at run time, as documented
    "operators": HELPERS,
    "model": HELPERS | {"operators"},
    "inverse": HELPERS | {"operators", "model", "limits"},
    "limits": HELPERS,
    "instrument": HELPERS,
    "tip": HELPERS,
    "bench": CORE | {"testing"},
    "io": CORE,
    "identification": CORE | {"io"},
    "sensor": CORE | {"identification"},
    "imaging": CORE | {"io", "identification"},
    "positioning": CORE | {"imaging"},
    "drift": CORE | {"imaging"},
    "drivers": CORE,  # and the emulator the simulator: below
    "virtual_afm": CORE,
    "plotting": CORE | {"identification", "sensor", "imaging"},
}


def _imports(path: Path, *, typing_too: bool = True) -> list[str]:
    """The modules ``path`` imports, anywhere in it (those under ``if TYPE_CHECKING:`` only
    with ``typing_too``)."""
    names: list[str] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            if not typing_too:
                for child in node.orelse:
                    visit(child)
                return
        if isinstance(node, ast.Import):
            names.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return names


def _part(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "piezocomp" and len(parts) > 1 else None


def _parts_imported(part: str, *, skip: tuple[str, ...] = ()) -> set[str]:
    root = Path(piezocomp.__file__).parent
    files = sorted((root / part).glob("*.py")) if (root / part).is_dir() else [root / f"{part}.py"]
    assert files
    got = {_part(m) for f in files if f.name not in skip for m in _imports(f, typing_too=False)}
    return got - {None, part}


@pytest.mark.parametrize("part", sorted(MAY_IMPORT))
def test_each_part_imports_only_what_its_docstring_allows(part):
    skip = ("nanonis_emulator.py",) if part == "drivers" else ()
    assert _parts_imported(part, skip=skip) - MAY_IMPORT[part] == set()


def test_the_emulator_serves_the_simulator_and_no_backend_imports_it():
    root = Path(piezocomp.__file__).parent / "drivers"
    assert _parts_imported("drivers") - MAY_IMPORT["drivers"] == {"virtual_afm"}
    users = [f.name for f in root.glob("*.py") for m in _imports(f) if m.endswith("emulator")]
    assert users == []


def test_no_two_parts_import_each_other_at_run_time():
    root = Path(piezocomp.__file__).parent
    parts = [p.name for p in root.iterdir() if p.is_dir() and (p / "__init__.py").exists()]
    parts += [p.stem for p in root.glob("*.py") if p.stem not in ("__init__", "__main__")]
    graph = {p: _parts_imported(p) for p in parts}
    both = sorted((a, b) for a in graph for b in graph[a] if a < b and a in graph.get(b, ()))
    assert both == []


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
    f.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from piezocomp.experiments import results\n"
        "def f():\n    from piezocomp.virtual_afm import VirtualAFM\n"
    )
    assert any(m.startswith(FORBIDDEN) for m in _imports(f))
    assert _imports(f, typing_too=False) == ["typing", "piezocomp.virtual_afm"]
    assert "piezocomp.experiments" in _imports(f)
