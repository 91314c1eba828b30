"""The package's shape (docs/architecture.md): layers that import one way, checked with
import-linter; no import cycle; small modules and functions; the public API as users expect."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "qchain"
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def test_the_layer_contract_holds():
    """import-linter's contracts in pyproject.toml: each layer imports only the layers below
    it (the engine no scene module, no library module the command line), no cycles."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert exe, "import-linter is part of the test extra (pip install -e '.[test]')"
    r = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "BROKEN" not in r.stdout and r.stdout.count("KEPT") == 2


def test_no_import_cycle_between_any_two_modules():
    """Every module-level or function-level import counted (TYPE_CHECKING imports aside)."""
    import grimp

    graph = grimp.build_graph("qchain", exclude_type_checking_imports=True)
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            if imported != module and not module.startswith(imported + "."):
                chain = graph.find_shortest_chain(importer=imported, imported=module)
                assert chain is None, f"import cycle: {module} -> {' -> '.join(chain)}"


def test_modules_and_functions_stay_small():
    top = [p for p in MODULES if p.parent == PACKAGE]
    assert len(top) <= 12, sorted(p.name for p in top)
    for path in MODULES:
        text = path.read_text()
        assert text.count("\n") <= 900, f"{path.relative_to(ROOT)}: {text.count(chr(10))} lines"
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                assert n <= 150, f"{path.relative_to(ROOT)}:{node.lineno} {node.name} has {n} lines"


def test_the_public_api_is_what_users_expect():
    """``qchain.simulate`` is the function (as ``simulate_batch``), every listed name resolves,
    nothing else is imported implicitly."""
    import qchain

    assert callable(qchain.simulate) and qchain.simulate.__module__ == "qchain.sim.simulation"
    assert callable(qchain.simulate_batch) and isinstance(qchain.Trajectory, type)
    for name in qchain.__all__:
        assert getattr(qchain, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'engine'"):
        qchain.engine  # noqa: B018 (a submodule is not an attribute until imported)
    assert "simulate" in qchain.__doc__ and "Chain" in qchain.__doc__


def test_importing_qchain_changes_no_global_state():
    """Warning filters and sys.path stay as the libraries qchain uses left them, and ``import
    qchain`` loads nothing heavy until a name is used."""
    code = ("import sys, warnings, numpy, numba, pinocchio, scipy.linalg, scipy.integrate; "  # their own filters
            "before = (list(warnings.filters), list(sys.path)); "
            "import qchain, qchain.sim.engine.steppers, qchain.arm.chain; "
            "print(before == (list(warnings.filters), list(sys.path)))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.stdout.strip() == "True", r.stdout + r.stderr
    r = subprocess.run([sys.executable, "-c", "import sys, qchain; print(sorted(m for m in ('numpy', 'numba', "
                        "'pinocchio', 'scipy') if m in sys.modules))"], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "[]", r.stdout + r.stderr
