"""The build backend (``buildhooks/qchain_build.py``): an editable install compiles the engine
into numba's cache for the first run, best effort, and never fails the install; and the cache
(``qchain._jit``) is taken only while no compiled source of qchain has changed."""

from __future__ import annotations

import ast
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numba
import numpy as np
import pytest

from qchain._jit import COMPILED_SOURCES

ROOT = Path(__file__).resolve().parent.parent


def _backend():
    spec = importlib.util.spec_from_file_location("qchain_build", ROOT / "buildhooks" / "qchain_build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pyproject_builds_with_the_backend_which_has_every_hook():
    """pip finds the backend in the tree (``backend-path``), and it answers every PEP 517/660
    hook (setuptools' for those it does not wrap)."""
    build = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]
    assert build["build-backend"] == "qchain_build" and build["backend-path"] == ["buildhooks"]
    b = _backend()
    for hook in ("build_wheel", "build_sdist", "build_editable", "get_requires_for_build_wheel",
                 "get_requires_for_build_sdist", "get_requires_for_build_editable", "prepare_metadata_for_build_wheel",
                 "prepare_metadata_for_build_editable"):
        assert callable(getattr(b, hook)), hook
    assert "buildhooks/qchain_build.py" in (ROOT / "MANIFEST.in").read_text()  # in the sdist, or it cannot build


def test_the_warm_up_asks_for_the_runtime_dependencies_at_this_environment_s_numba_and_numpy():
    """The build environment gets numba, numpy, scipy and Pinocchio with pyproject's bounds, and
    numba and numpy at the versions the target environment has (numba takes a cache entry only
    from its own version)."""
    b = _backend()
    reqs = b.warmup_requires()
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert sorted(r.split("=")[0].split(">")[0] for r in reqs) == ["numba", "numpy", "pin", "scipy"]
    # the test runs in the environment qchain is installed in: pip would start the backend with this interpreter
    assert f"numba=={numba.__version__}" in reqs and f"numpy=={np.__version__}" in reqs
    assert next(d for d in deps if d.startswith("scipy")) in reqs and next(d for d in deps if d.startswith("pin")) in reqs


def test_the_warm_up_is_switched_off_by_the_environment_or_a_config_setting(monkeypatch):
    b = _backend()
    monkeypatch.delenv("QCHAIN_INSTALL_COMPILE", raising=False)
    assert b.enabled() and b.enabled({}) and b.enabled({"compile": "1"})
    assert not b.enabled({"compile": "0"}) and not b.enabled({"compile": "false"})
    monkeypatch.setenv("QCHAIN_INSTALL_COMPILE", "0")
    assert not b.enabled()
    assert b.enabled({"compile": "1"})  # the config setting is the more specific


def test_a_failing_warm_up_never_fails_the_install_and_says_why(tmp_path, capsys):
    """No interpreter, one that fails, one that takes too long: ``warm_up`` returns False and
    says on stderr that the first run compiles, and raises nothing."""
    b = _backend()
    failing = tmp_path / "failing-python"
    failing.write_text("#!/bin/sh\necho 'ImportError: no numba here' >&2\nexit 3\n")
    failing.chmod(0o755)
    slow = tmp_path / "slow-python"
    slow.write_text("#!/bin/sh\nexec sleep 30\n")
    slow.chmod(0o755)
    cases = ((str(tmp_path / "missing"), 60, "could not start"), (str(failing), 60, "failed (exit 3: ImportError"),
             (str(slow), 0.5, "took over 0.5 s and was stopped"))
    for python, timeout, said in cases:
        assert b.warm_up(timeout=timeout, python=python) is False
        err = capsys.readouterr().err
        assert said in err and "the first run compiles" in err, err


@pytest.mark.slow
def test_after_the_install_s_warm_up_the_readme_example_compiles_nothing(tmp_path):
    """The warm-up into an empty numba cache, then the README's example and a first batch on
    threads in a new process with that cache: no part of the engine announced as compiled on
    stderr, and numba compiled nothing (every function it needed was in the cache)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), MPLBACKEND="Agg")
    env.pop("PYTHONPATH", None)
    b = _backend()
    assert b.warm_up(timeout=3000, env=env)  # (no timing here: a loaded machine takes long)
    code = ("import runpy, sys\n"
            "from numba.core import event\n"
            "compiled = []\n"
            "class L(event.Listener):\n"
            "    def on_start(self, ev): compiled.append(ev.data['dispatcher'].py_func.__qualname__)\n"
            "    def on_end(self, ev): pass\n"
            "event.register('numba:compile', L())\n"
            f"sys.argv = ['wave_arm.py', '--quick', '--out', {str(tmp_path / 'out')!r}]\n"
            f"sys.path.insert(0, {str(ROOT / 'examples')!r})\n"
            f"runpy.run_path({str(ROOT / 'examples' / 'wave_arm.py')!r}, run_name='__main__')\n"
            # a user's first batch on threads: the compiled loop of simulate_batch is cached too
            "import numpy as np\n"
            "from qchain import load_scene, simulate_batch\n"
            f"m = load_scene({str(ROOT / 'examples' / 'scenes' / 'wave_arm.toml')!r}).build()\n"
            "P = np.linspace(0.0, 2e4, 4)[:, None] * np.ones(m.chain.nu)\n"
            "b = simulate_batch(m.chain, m.q0, m.v0, (0.0, 0.02), pressure=P, t_eval=np.linspace(0, 0.02, 5), workers=2)\n"
            "assert b.meta['loop'] == 'compiled', b.meta\n"
            "print('compiled:', compiled)\n")
    p = subprocess.run([sys.executable, "-c", code], env=dict(env, PYTHONPATH=str(ROOT)), cwd=str(tmp_path),
                       capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, p.stderr
    assert "qchain: compiling" not in p.stderr, p.stderr
    assert "compiled: []" in p.stdout, p.stdout


#: a line that defines compiled code: a numba decorator of qchain's or numba's own
_COMPILED = re.compile(r"^@(jit|jit_helper|jit_inline|jit_pass|ejit|ejit_inner|inline|kernel|intrinsic|overload|"
                       r"register_jitable|numba\.\w+)\b|cached_njit\(|numba\.njit\(", re.MULTILINE)


def _qchain_imports(path: Path) -> set[Path]:
    """The qchain modules ``path`` imports (absolute or relative; a package's ``__init__``
    and, for ``from pkg import name``, the module ``pkg.name`` where it is one)."""
    package = ROOT / "qchain"

    def module(dotted: str) -> list[Path]:
        base = ROOT.joinpath(*dotted.split("."))
        return [f for f in (base.with_suffix(".py"), base / "__init__.py") if f.exists()]

    package_parts = path.relative_to(ROOT).with_suffix("").parts[:-1]  # the package the file is in
    found: set[Path] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # from . import x: this package; from .. import x: its parent
                parts = list(package_parts[: len(package_parts) - node.level + 1])
                dotted = ".".join(parts + ([node.module] if node.module else []))
            else:
                dotted = node.module or ""
            if dotted.split(".")[0] != "qchain":
                continue
            found.update(module(dotted))
            for alias in node.names:
                found.update(module(f"{dotted}.{alias.name}"))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "qchain":
                    found.update(module(alias.name))
    return {f for f in found if package in f.parents}


def test_the_cache_stamp_covers_every_module_compiled_code_is_made_of():
    """Every module with compiled functions, and every qchain module those import (their
    constants and tuple types are read when they compile), lies in ``COMPILED_SOURCES``, whose
    files stamp every cache entry of qchain (``qchain._jit.tree_stamp``)."""
    package = ROOT / "qchain"
    compiled = {f for f in package.rglob("*.py") if _COMPILED.search(f.read_text())}
    assert package / "model" / "arc.py" in compiled and package / "sim" / "engine" / "steppers.py" in compiled
    closure, todo = set(), list(compiled)
    while todo:
        f = todo.pop()
        if f not in closure:
            closure.add(f)
            todo.extend(_qchain_imports(f) - closure)
    stamped = {f for part in COMPILED_SOURCES for f in ((package / part).rglob("*.py")
                                                        if (package / part).is_dir() else [package / part])}
    missing = sorted(str(f.relative_to(package)) for f in closure - stamped)
    assert not missing, f"compiled code depends on modules outside qchain._jit.COMPILED_SOURCES: {missing}"


_MASS_COLUMN = """
import numpy as np
from qchain import Segment
seg = Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)
print(repr(seg.mass_matrix(np.array([0.105, 8.0, -2.0]))[2, 6:].tolist()))
"""


@pytest.mark.slow
def test_a_helper_changed_in_another_file_is_compiled_again_into_its_callers(tmp_path):
    """numba keeps a cached function while its own source file is unchanged, yet the function
    holds the code of the compiled functions it calls: the slice Jacobian changed in
    ``model/arc.py`` left the cached mass matrix of ``model/slices.py`` computing with the old
    one. With qchain's stamp, the next process compiles it again: the same numbers as a
    process with an empty cache, and not the old ones."""
    tree = tmp_path / "tree"
    shutil.copytree(ROOT / "qchain", tree / "qchain", ignore=shutil.ignore_patterns("__pycache__"))
    script = tmp_path / "mass_column.py"
    script.write_text(_MASS_COLUMN)

    def column(cache: str) -> list[float]:
        env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(tmp_path / cache))
        p = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600,
                           cwd=str(tmp_path))
        assert p.returncode == 0, p.stderr
        return ast.literal_eval(p.stdout.strip().splitlines()[-1])

    before = column("cache")
    arc = tree / "qchain" / "model" / "arc.py"
    text = arc.read_text()
    old = "    S = ((0.0, 0.0, alpha, "  # the slice Jacobian's axial column, d p / d l
    assert text.count(old) == 1
    arc.write_text(text.replace(old, "    S = ((0.0, 0.0, 2.0 * alpha, "))
    after = column("cache")
    fresh = column("empty-cache")
    assert after == fresh
    assert after[0] == pytest.approx(2.0 * before[0], rel=1e-12) and after[1:] == before[1:]
