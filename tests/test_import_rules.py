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


def _package_of(path: Path) -> str | None:
    """The dotted package of a module of piezocomp (``None`` for a file outside it)."""
    root = Path(piezocomp.__file__).parent
    try:
        rel = path.resolve().relative_to(root.resolve())
    except ValueError:
        return None
    return ".".join(("piezocomp", *rel.parent.parts))


def _imports(path: Path, *, typing_too: bool = True, package: str | None = None) -> list[str]:
    """The modules ``path`` imports, anywhere in it (those under ``if TYPE_CHECKING:`` only
    with ``typing_too``), relative imports resolved against ``package`` (by default the
    module's own, for a module of piezocomp)."""
    names: list[str] = []
    package = _package_of(path) if package is None else package

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            if not typing_too:
                for child in node.orelse:
                    visit(child)
                return
        if isinstance(node, ast.Import):
            names.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
        elif isinstance(node, ast.ImportFrom) and node.level > 0 and package:
            base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
            if node.module:
                names.append(".".join([*base, node.module]))
            else:  # from . import a, b: modules (or names) of the package itself
                names.extend(".".join([*base, a.name]) for a in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return names


def _part(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "piezocomp" and len(parts) > 1 else None


def _parts_imported(part: str, *, skip: tuple[str, ...] = ()) -> set[str]:
    root = Path(piezocomp.__file__).parent
    files = sorted((root / part).rglob("*.py")) if (root / part).is_dir() else [root / f"{part}.py"]
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
    files = sorted(root.rglob("*.py"))  # sub-packages too
    assert files
    bad = [(f.name, m) for f in files for m in _imports(f) if m.startswith(FORBIDDEN)]
    assert bad == []


def test_the_sensorless_identification_does_not_need_the_sensor_fit():
    root = Path(piezocomp.__file__).parent / "identification"
    bad = [(f.name, m) for f in sorted(root.rglob("*.py")) for m in _imports(f)
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


def test_the_rule_resolves_relative_imports(tmp_path):
    """``from ..virtual_afm import VirtualAFM`` in ``piezocomp.drift`` is the simulator too."""
    f = tmp_path / "m.py"
    f.write_text(
        "from ..virtual_afm import VirtualAFM\nfrom . import filter\nfrom .landmarks import x\n"
    )
    got = _imports(f, package="piezocomp.drift")
    assert got == ["piezocomp.virtual_afm", "piezocomp.drift.filter", "piezocomp.drift.landmarks"]
    assert any(m.startswith(FORBIDDEN) for m in got)
    assert _package_of(Path(piezocomp.__file__).parent / "drift" / "landmarks.py") == (
        "piezocomp.drift"
    )


SIMULATOR_NAMES = {"VirtualAFM", "AFMConfig", "GroundTruth", "load_config"}


def test_the_experiments_run_on_an_instrument_without_the_simulator():
    """What ``reproduce --instrument`` runs (``on_instrument`` and the experiments' ``run``
    functions it calls) names nothing of the simulator: the virtual lab builds its
    instruments elsewhere (each experiment's ``run_trial``)."""
    root = Path(piezocomp.__file__).parent / "experiments"
    on = root / "on_instrument.py"
    assert not [m for m in _imports(on) if m.startswith("piezocomp.virtual_afm")]
    for name in ("on_instrument", "table1", "fig9", "fig8"):
        tree = ast.parse((root / f"{name}.py").read_text(encoding="utf-8"))
        funcs = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
        used = funcs if name == "on_instrument" else [f for f in funcs if f.name == "run"]
        assert used, name
        named = {n.id for f in used for n in ast.walk(f) if isinstance(n, ast.Name)}
        assert named & SIMULATOR_NAMES == set(), name


def _definitions(root: Path) -> tuple[dict[tuple[str, str], ast.AST], dict[str, dict]]:
    """Every top-level function, class and assignment of the modules in ``root`` (by
    ``(module, name)``)
    and, per module, the names it imports from the others (``piezocomp.experiments``)."""
    defs: dict[tuple[str, str], ast.AST] = {}
    aliases: dict[str, dict[str, tuple[str, ...]]] = {}
    for f in sorted(root.glob("*.py")):
        tree = ast.parse(f.read_text(encoding="utf-8"))
        for n in tree.body:
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                defs[(f.stem, n.name)] = n
            elif isinstance(n, ast.Assign | ast.AnnAssign):  # a table of functions, ...
                targets = n.targets if isinstance(n, ast.Assign) else [n.target]
                defs.update({(f.stem, t.id): n for t in targets if isinstance(t, ast.Name)})
        al: dict[str, tuple[str, ...]] = {}
        for n in ast.walk(tree):
            if not isinstance(n, ast.ImportFrom) or not n.module:
                continue
            if n.module == "piezocomp.experiments":
                al.update({a.asname or a.name: ("module", a.name) for a in n.names})
            elif n.module.startswith("piezocomp.experiments."):
                mod = n.module.split(".")[2]
                al.update({a.asname or a.name: ("name", mod, a.name) for a in n.names})
        aliases[f.stem] = al
    return defs, aliases


def _reached(root: Path, module: str, names: list[str]) -> dict[tuple[str, str], ast.AST]:
    """The functions and classes of ``root``'s modules that ``module``'s ``names`` use,
    directly or through one another (names of the same module, names imported from another
    module of ``root``, ``other_module.name``)."""
    defs, aliases = _definitions(root)
    todo, seen = [(module, n) for n in names], set()
    while todo:
        key = todo.pop()
        if key in seen or key not in defs:
            continue
        seen.add(key)
        mod, al = key[0], aliases[key[0]]
        for n in ast.walk(defs[key]):
            if isinstance(n, ast.Name):
                todo.append((mod, n.id))
                a = al.get(n.id)
                if a and a[0] == "name":
                    todo.append((a[1], a[2]))
            elif isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name):
                a = al.get(n.value.id)
                if a and a[0] == "module":
                    todo.append((a[1], n.attr))
    return {k: defs[k] for k in seen}


def _simulator_uses(node: ast.AST) -> set[str]:
    """What ``node`` names of the simulator: its names, an import of it, ``x.truth``."""
    out = set()
    for n in ast.walk(node):
        if isinstance(n, ast.Name) and n.id in SIMULATOR_NAMES:
            out.add(n.id)
        elif isinstance(n, ast.Attribute) and n.attr == "truth":
            out.add(".truth")
        elif isinstance(n, ast.ImportFrom) and (n.module or "").startswith("piezocomp.virtual_afm"):
            out.add(n.module or "")
        elif isinstance(n, ast.Import):
            out.update(a.name for a in n.names if a.name.startswith("piezocomp.virtual_afm"))
    return out


def test_what_reproduce_on_an_instrument_runs_never_reaches_the_simulator():
    """Every function and class ``on_instrument`` uses, through any module of
    ``experiments`` (the experiments' ``run``, the methods' ``instrument_for``, ...), names
    nothing of the simulator and reads no ``.truth``: a real instrument has neither."""
    root = Path(piezocomp.__file__).parent / "experiments"
    tree = ast.parse((root / "on_instrument.py").read_text(encoding="utf-8"))
    starts = [n.name for n in tree.body if isinstance(n, ast.FunctionDef | ast.ClassDef)]
    reached = _reached(root, "on_instrument", starts)
    assert ("table1", "run") in reached and ("methods", "instrument_for") in reached
    assert ("table1", "run_trial") not in reached  # the virtual lab's side
    bad = {f"{m}.{n}": u for (m, n), node in reached.items() if (u := _simulator_uses(node))}
    assert bad == {}


def test_the_reach_rule_follows_calls_across_modules(tmp_path):
    """A simulator name two calls away, in another module, is found."""
    (tmp_path / "front.py").write_text(
        "from piezocomp.experiments import back\n"
        "from piezocomp.experiments.side import helper\n"
        "def go():\n    return back.first(), helper()\n"
    )
    (tmp_path / "back.py").write_text(
        "def first():\n    return second()\ndef second(afm):\n    return afm.truth\n"
    )
    (tmp_path / "side.py").write_text(
        "def helper():\n    from piezocomp.virtual_afm import VirtualAFM\n    return VirtualAFM\n"
        "def unused():\n    return VirtualAFM\n"
    )
    reached = _reached(tmp_path, "front", ["go"])
    assert set(reached) == {("front", "go"), ("back", "first"), ("back", "second"),
                            ("side", "helper")}  # fmt: skip
    assert _simulator_uses(reached[("back", "second")]) == {".truth"}
    assert _simulator_uses(reached[("side", "helper")]) == {"VirtualAFM", "piezocomp.virtual_afm"}


STAGES = ("acquisition", "loop", "estimation", "reference")
"""The identification's stages in their order: each a sub-package of ``identification``."""

SHARED = {"piezocomp.identification._rls_kernel"}
"""What every stage may use of the identification outside the stages: the compiled kernels
``h(y)`` and the RLS share."""


def _stage_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[:2] != ["piezocomp", "identification"] or len(parts) < 3:
        return None
    return parts[2] if parts[2] in STAGES else "pipeline"


@pytest.mark.parametrize("stage", STAGES)
def test_no_stage_imports_a_later_one_or_the_pipeline(stage):
    """A stage reads only its own configuration and the results of the stages before it: it
    imports its own modules and the earlier stages' (type-checking imports included), never
    a later stage or the pipeline above them (``config``, ``sensorless``, ``result``)."""
    root = Path(piezocomp.__file__).parent / "identification" / stage
    files = sorted(root.glob("*.py"))
    assert len(files) > 2
    allowed = set(STAGES[: STAGES.index(stage) + 1])
    bad = [
        (f.name, m)
        for f in files
        for m in _imports(f)
        if m not in SHARED and _stage_of(m) is not None and _stage_of(m) not in allowed
    ]
    assert bad == []


def test_every_identification_module_belongs_to_a_stage_or_the_pipeline():
    """The folders say which stage holds what: besides the stages, the identification's top
    level holds only the pipeline (configuration, the run of an axis, its result, the offline
    entry, the plan) and the shared kernels."""
    root = Path(piezocomp.__file__).parent / "identification"
    top = {p.stem for p in root.glob("*.py")}
    assert top == {"__init__", "_rls_kernel", "config", "offline", "planning", "result",
                   "sensorless"}  # fmt: skip
    assert {p.name for p in root.iterdir() if (p / "__init__.py").exists()} == set(STAGES)
    for stage in STAGES:
        assert (root / stage / "config.py").exists(), stage  # each stage's own settings
