"""Every code block of README.md and docs/ runs, so that no documented step can rot.

The blocks are read by Sybil and run in the order of their file, one test per block, all the
blocks of a file in one namespace and one working folder (a block may write what the next
one reads, as a user following the page would):

- ``python`` blocks run as they are;
- ``bash`` blocks run through ``bash -eu`` with ``piezocomp`` the command line of the
  package under test;
- ``json`` blocks must parse; a model file (``"format": "piezocomp/scanner-model"``) must
  load, and its text is left in the namespace as ``json_text`` for the next block;
- blocks without a language (equations, layouts, printed output) are text, not run.

What a page takes from the steps before it (the model file the identification's quick
start writes, the real record beside the repository) is put in its folder first
(``PAGE_SETUP``). A page may hold hidden set-up in
``<!-- invisible-code-block: python ... -->`` comments and skip a block with
``<!-- skip: next "why" -->``: the reason shows in the test report. A block that runs after
a skipped or failed one of its page says so when it fails.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from sybil import Example, Sybil
from sybil.parsers.markdown import CodeBlockParser, PythonCodeBlockParser, SkipParser

import piezocomp

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", *(p.relative_to(ROOT).as_posix() for p in sorted(ROOT.glob("docs/**/*.md")))]
SLOW_PAGES = {
    "docs/positioning.md",
    "docs/drift.md",
    "docs/identification.md",
    "docs/examples/piezo_record.md",
    "docs/instruments.md",
}
"""Pages whose blocks drive the virtual AFM for minutes of its time (tens of seconds here)."""

_SRC = str(Path(piezocomp.__file__).resolve().parents[1])


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([_SRC, *filter(None, [env.get("PYTHONPATH")])])
    env["PIEZOCOMP_PYTHON"] = sys.executable
    return env


def _positioning_model(folder: Path, cache: Path, namespace: dict[str, Any]) -> None:
    """``results/cpr5/model.json`` for the pages that load the identification quick start's
    model: a model of its shape (both axes, the 2000 nm span and the speeds up to 2 um/s of
    ``piezocomp identify``'s defaults) fitted to the virtual ``cpr5``'s true extension in
    about a second, where the sensorless quick start takes minutes."""
    made = cache / "model.json"
    if not made.is_file():
        from piezocomp.experiments.methods import IdentificationSettings
        from piezocomp.experiments.virtual_identification import fit_on_truth
        from piezocomp.identification.config import IdentifyConfig
        from piezocomp.io.model_files import save_model
        from piezocomp.model import ScannerModel2D
        from piezocomp.virtual_afm import VirtualAFM

        st = IdentificationSettings()
        user = IdentifyConfig().acquisition  # the quick start's span and speeds
        assert (user.span_nm, user.waveform.speed_factors) == (st.span_nm, st.speed_factors)
        axes = []
        for axis in ("x", "y"):
            afm = VirtualAFM("cpr5-nodrift", seed=1)
            axes.append(fit_on_truth(afm, st.config(afm.range_nm), axis, st.oracle_orders))
        cache.mkdir(parents=True, exist_ok=True)
        save_model(made, ScannerModel2D(*axes))
    (folder / "results" / "cpr5").mkdir(parents=True)
    shutil.copy(made, folder / "results" / "cpr5" / "model.json")


def _piezo_record(folder: Path, cache: Path, namespace: dict[str, Any]) -> None:
    """The page's commands run from the repository's root: its benchmarks and its data."""
    (folder / "benchmarks").symlink_to(ROOT / "benchmarks")
    (folder / "data").symlink_to(ROOT / "data")


def _real_files(folder: Path, cache: Path, namespace: dict[str, Any]) -> None:
    """The page's commands run from the repository's root: its real files in tests/data."""
    (folder / "tests").symlink_to(ROOT / "tests")


PAGE_SETUP = {
    "docs/real_scans.md": _real_files,
    "docs/positioning.md": _positioning_model,
    "docs/drift.md": _positioning_model,
    "docs/examples/piezo_record.md": _piezo_record,
}
"""What a page takes from the steps before it, made as the docs say."""


def _run_bash(example: Example) -> None:
    env = _env()
    script = 'piezocomp() { "$PIEZOCOMP_PYTHON" -m piezocomp.cli "$@"; }\n'
    script += 'python() { "$PIEZOCOMP_PYTHON" "$@"; }\n'
    script += str(example.parsed)
    proc = subprocess.run(
        ["bash", "-eu", "-c", script], env=env, capture_output=True, text=True, timeout=600
    )
    if proc.returncode != 0:
        raise AssertionError(
            f"exit {proc.returncode}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}"
        )


def _check_json(example: Example) -> None:
    text = str(example.parsed)
    data = json.loads(text)
    if isinstance(data, dict) and data.get("format") == "piezocomp/scanner-model":
        from piezocomp.io.model_files import load_model

        path = Path(".doc_model_check.json")
        path.write_text(text)
        try:
            load_model(path)
        finally:
            path.unlink()
    example.namespace["json_text"] = text


_SYBIL = Sybil(
    parsers=[
        PythonCodeBlockParser(),
        CodeBlockParser(language="bash", evaluator=_run_bash),
        CodeBlockParser(language="json", evaluator=_check_json),
        SkipParser(),
    ]
)


@dataclass
class _Page:
    """One page's blocks and how far they have run."""

    examples: list[Example]
    folder: Path | None = None
    done: int = 0
    broken: str | None = None
    outcomes: dict[int, str] = field(default_factory=dict)


_PAGES: dict[str, _Page] = {}


def _page(name: str) -> _Page:
    if name not in _PAGES:
        _PAGES[name] = _Page(list(_SYBIL.parse(ROOT / name)))
    return _PAGES[name]


def _params() -> list[Any]:
    out = []
    for name in PAGES:
        marks = [pytest.mark.slow] if name in SLOW_PAGES else []
        for i, ex in enumerate(_page(name).examples):
            if ex.region.evaluator.__class__.__name__ == "Skipper":
                continue  # the skip directive itself: evaluated with the blocks before the next
            out.append(pytest.param(name, i, id=f"{name}:{ex.line}", marks=marks))
    return out


def _evaluate(page: _Page, i: int) -> str:
    """Run example ``i``; ``"ok"``, or ``"skip: why"``."""
    try:
        page.examples[i].evaluate()
    except pytest.skip.Exception as exc:
        return f"skip: {exc}"
    except Exception as exc:
        if type(exc).__name__ == "SkipTest":
            return f"skip: {exc}"
        if type(exc).__name__ == "NotEvaluated":
            return "skip: not evaluated"
        raise
    return "ok"


@pytest.mark.parametrize(("name", "index"), _params())
def test_doc_block(name: str, index: int, tmp_path_factory: Any, monkeypatch: Any) -> None:
    page = _page(name)
    if page.folder is None:
        page.folder = tmp_path_factory.mktemp(Path(name).stem)
        if name in PAGE_SETUP:
            cache = tmp_path_factory.getbasetemp() / "positioning-model"
            PAGE_SETUP[name](page.folder, cache, page.examples[0].namespace)
    monkeypatch.chdir(page.folder)
    while page.done < index:  # the blocks before this one, if they have not run yet
        j = page.done
        if page.broken is None:
            try:
                page.outcomes[j] = _evaluate(page, j)
            except BaseException as exc:
                page.broken = f"line {page.examples[j].line}: {type(exc).__name__}"
                page.outcomes[j] = "failed"
        page.done += 1
    if page.broken is not None:
        pytest.fail(f"an earlier block of {name} failed ({page.broken})")
    skipped = [
        page.examples[j].line
        for j, o in page.outcomes.items()
        if o.startswith("skip") and j < index
    ]
    page.done = index + 1
    try:
        outcome = _evaluate(page, index)
    except BaseException as exc:
        page.broken = f"line {page.examples[index].line}: {type(exc).__name__}"
        if skipped:
            raise AssertionError(
                f"this block failed after skipped blocks at lines {skipped} of {name}: "
                "it may need what they make"
            ) from exc
        raise
    page.outcomes[index] = outcome
    if outcome.startswith("skip"):
        pytest.skip(f"{name}:{page.examples[index].line}: {outcome[len('skip: ') :]}")
