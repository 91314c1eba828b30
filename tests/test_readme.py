"""The README works as written: every ```python block runs, every ``qchain SUBCOMMAND`` it
names is a real subcommand, every path of the repository it names exists."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
VENV_BIN = Path(sys.executable).parent  # the venv the suite runs in (scripts/test.sh: .venv)
#: top-level folders and files of the repository whose paths the README may name; a path
#: under ``out/`` or ``runs/`` is an output the commands make, not checked here
REPO_PARTS = ("docs", "examples", "benchmarks", "scripts", "tests", "qchain", ".ci")
REPO_FILES = ("README.md", "LICENSE", "CITATION.cff", "pyproject.toml")


def blocks(language: str) -> list[str]:
    """The fenced blocks of ``language`` in the README, in order."""
    return re.findall(rf"^```{language}\n(.*?)^```", README, flags=re.MULTILINE | re.DOTALL)


PYTHON = blocks("python")


def test_the_readme_has_code():
    assert len(PYTHON) >= 4 and blocks("bash")


@pytest.mark.parametrize("k", range(len(PYTHON)), ids=lambda k: f"block{k}")
def test_every_python_block_runs(k, tmp_path):
    """Each block as a script of its own, with the venv's python, in an empty folder where
    ``examples`` is the repository's (the README says to run those from the repository's
    folder); outputs land in the temporary folder."""
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    script = tmp_path / f"readme_block{k}.py"
    script.write_text(PYTHON[k], encoding="utf-8")
    r = subprocess.run([sys.executable, script.name], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, f"README block {k}:\n{PYTHON[k]}\n--- stderr:\n{r.stderr[-3000:]}"


def subcommands() -> set[str]:
    """Every ``qchain WORD`` the README names as a command (``qchain run``, ``qchain info``,
    ...), in code blocks and inline code, with or without ``.venv/bin/``."""
    code = "\n".join(blocks("bash")) + "\n" + "\n".join(re.findall(r"`([^`\n]+)`", README))
    return set(re.findall(r"(?:^|[\s/`(])qchain ([a-z][a-z-]*)\b", code, flags=re.MULTILINE))


def test_every_named_subcommand_exists():
    names = subcommands()
    assert {"run", "info", "replay", "sweep"} <= names, names
    exe = VENV_BIN / "qchain"
    assert exe.is_file(), f"{exe}: the qchain command of the venv"
    for name in sorted(names):
        r = subprocess.run([str(exe), name, "--help"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, f"`qchain {name}` named in the README: {r.stderr[-500:]}"


def named_paths() -> set[str]:
    """Paths of the repository the README names: in link targets, inline code and code blocks."""
    found = set()
    for target in re.findall(r"\]\(([^)\s#]+)", README):  # [text](path) and ![alt](path)
        if not re.match(r"[a-z]+:", target):
            found.add(target)
    parts = "|".join(re.escape(p) for p in REPO_PARTS)
    for m in re.finditer(rf"(?<![\w./-])((?:{parts})/[\w./-]*[\w/])", README):
        found.add(m.group(1))
    for name in REPO_FILES:
        if re.search(rf"(?<![\w/.]){re.escape(name)}\b", README):
            found.add(name)
    return {p for p in found if "<" not in p and "*" not in p}


def test_every_named_path_exists():
    paths = named_paths()
    assert {"examples/wave_arm.py", "scripts/test.sh", "docs/architecture.md"} <= paths, sorted(paths)
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"the README names paths that do not exist: {missing}"


def test_the_set_up_commands_come_first():
    """Exactly two commands, before anything else: install and run the example, run the suite."""
    first = blocks("bash")[0].strip().splitlines()
    assert first == ["python3 -m venv .venv && .venv/bin/pip install -q -e . && .venv/bin/python examples/wave_arm.py",
                     "bash scripts/test.sh"]
    assert README.index("```bash") < README.index("```python")
